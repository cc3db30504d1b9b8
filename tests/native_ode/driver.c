/* A standalone driver of ode.c for valgrind (tests/test_native_ode.py): solves, fails and
 * no-ops with work memory of exactly ode_work_size(n) doubles from malloc. Exits 1 if a
 * result is wrong. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ode.h"
#include "rhs.h"

static int failures = 0;

static void expect(int ok, const char *what) {
    if (!ok) {
        fprintf(stderr, "FAILED: %s\n", what);
        failures++;
    }
}

int main(void) {
    OdeReport rep;
    double x[40], p[40 * 40 + 40];
    /* x' = -x, n = 40: x(1) = x(0) / e */
    size_t n = 40;
    memset(p, 0, sizeof p);
    for (size_t i = 0; i < n; i++) {
        p[i * n + i] = -1.0;
        x[i] = (double)i + 1.0;
    }
    expect(solve(RHS_LINEAR, n, p, x, 1.0, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) == ODE_OK,
           "linear n = 40 succeeds");
    for (size_t i = 0; i < n; i++)
        expect(fabs(x[i] - ((double)i + 1.0) * exp(-1.0)) < 1e-8, "linear n = 40 value");
    /* x' = x^2 from 1: x(t) = 1 / (1 - t), blows up at t = 1 */
    x[0] = 1.0;
    expect(solve(RHS_SQUARE, 1, p, x, 0.5, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) == ODE_OK &&
               fabs(x[0] - 2.0) < 1e-8, "x' = x^2 to t = 0.5");
    x[0] = 1.0;
    expect(solve(RHS_SQUARE, 1, p, x, 2.0, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) ==
                   ODE_STEP_TOO_SMALL && x[0] == 1.0, "x' = x^2 past the blow-up");
    /* Van der Pol, mu = 1, with too few steps */
    double vdp[1] = {1.0};
    x[0] = 2.0;
    x[1] = 0.0;
    expect(solve(RHS_VAN_DER_POL, 2, vdp, x, 20.0, 1e-10, 1e-10, 10, 0.0, &rep, NULL) ==
                   ODE_MAX_STEPS && rep.steps == 11, "Van der Pol, 10 steps");
    expect(solve(RHS_VAN_DER_POL, 2, vdp, x, 20.0, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) ==
                   ODE_OK, "Van der Pol");
    /* f fails at its 30th call; NaN from x = 0.5 */
    double at[1] = {30.0};
    x[0] = 1.0;
    expect(solve(RHS_FAILS, 1, at, x, 5.0, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) ==
                   ODE_RHS_FAILED && x[0] == 1.0 && rep.evaluations == 30, "f fails");
    double half[1] = {0.5};
    x[0] = 0.0;
    expect(solve(RHS_NAN, 1, half, x, 1.0, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) < 0 &&
                   x[0] == 0.0, "f gives NaN");
    /* a tiny state: solved scaled */
    p[0] = -1.0;
    p[1] = 0.0;
    x[0] = 1e-150;
    expect(solve(RHS_LINEAR, 1, p, x, 1.0, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) == ODE_OK &&
               rep.scale != 1.0 && fabs(x[0] - 1e-150 * exp(-1.0)) < 1e-159, "tiny state");
    /* no-ops and bad input */
    x[0] = 3.0;
    expect(solve(RHS_LINEAR, 1, p, x, 0.0, 1e-10, 1e-10, 100000, 0.0, &rep, NULL) == ODE_OK &&
               x[0] == 3.0 && rep.evaluations == 0, "zero duration");
    expect(solve(RHS_LINEAR, 1, p, x, 1.0, 0.0, 1e-10, 100000, 0.0, &rep, NULL) ==
                   ODE_BAD_INPUT, "rtol = 0");
    expect(ode_solve(NULL, NULL, 0, NULL, 1.0, 1e-6, 1e-6, 10, 0.0, NULL, NULL) ==
                   ODE_BAD_INPUT, "no f, no report");
    printf("%d failures\n", failures);
    return failures > 0;
}
