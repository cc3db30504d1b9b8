/* tests/native_ode: the right-hand sides of rhs.c, by number */
#ifndef NATIVE_ODE_RHS_H
#define NATIVE_ODE_RHS_H

#include <stddef.h>

#include "ode.h"

enum { RHS_LINEAR, RHS_SQUARE, RHS_CUBE, RHS_PENDULUM, RHS_VAN_DER_POL, RHS_FAILS, RHS_NAN };

int solve(int which, size_t n, const double *p, double *x, double duration, double rtol,
          double atol, long max_steps, double u_size, OdeReport *report, long *calls);

#endif
