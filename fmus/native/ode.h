/* ode.h: an embedded Runge-Kutta integrator, Dormand-Prince 8(5,3) (DOP853), for
 * autonomous systems x' = f(x) over one segment of time (the input u is held constant,
 * so it lives in the caller's context). Standalone: needs only the C library and libm,
 * allocates nothing (the caller hands it ode_work_size(n) doubles). See ode.c and
 * fmus/native/README.md ("ode.c: the integrator"). */
#ifndef DELAYCOMP_ODE_H
#define DELAYCOMP_ODE_H

#include <stddef.h>

/* The linkage of the three functions: empty (external) for the FMUs; `delaycomp export-c`
 * defines it `static` and puts this file and ode.c into the controller's own C file, so
 * two exported controllers link into one program. */
#ifndef ODE_API
#define ODE_API
#endif

/* The right-hand side: dx = f(x). Returns 0 on success, non-zero if f failed. x and dx
 * are n doubles each and never alias. */
typedef int (*ode_rhs)(void *ctx, const double *x, double *dx);

/* Return codes of ode_solve (those of Hairer's DOP853 where it has one). */
enum {
    ODE_OK = 0,
    ODE_BAD_INPUT = -1,    /* "input is not consistent" */
    ODE_MAX_STEPS = -2,    /* "larger nsteps is needed" */
    ODE_STEP_TOO_SMALL = -3, /* "step size becomes too small" */
    ODE_STIFF = -4,        /* "problem is probably stiff (interrupted)" */
    ODE_NOT_FINITE = -5,   /* "the state is not finite" */
    ODE_RHS_FAILED = -6    /* "the model's f failed" */
};

/* States and inputs all below this (in absolute value, and not all zero) are solved
 * scaled by a power of two (see ode_solve). */
#define ODE_TINY 1e-100

typedef struct {
    int code;            /* the return code */
    const char *reason;  /* "" on success, else a constant string naming the failure */
    long steps;          /* steps tried (accepted + rejected) */
    long accepted;       /* accepted steps */
    long rejected;       /* rejected steps (all of them, including before the first accept) */
    long evaluations;    /* calls of f */
    double t;            /* time reached from the start of the segment */
    double h;            /* the last step size tried (on success: the next one proposed) */
    double scale;        /* the power of two the state was divided by (1: none) */
} OdeReport;

/* Doubles of work memory that ode_solve needs for n states. */
ODE_API size_t ode_work_size(size_t n);

/* The message of a return code ("" for ODE_OK). */
ODE_API const char *ode_reason(int code);

/* Solve x' = f(x) from x over [0, duration] with DOP853 (rtol, atol: the scaled error
 * sk_i = atol + rtol max(|x_i|, |x_new_i|) of each step is held to 1 in the RMS norm),
 * at most max_steps + 1 steps tried (as DOP853 counts nmax). u_size is the largest
 * |u| of the input held over the segment (0 if none): it only decides the scaling of
 * tiny states. On success (ODE_OK) x holds the state at the end; on failure x is left
 * unchanged. duration <= 0 is a no-op (ODE_OK, f not called). work: ode_work_size(n)
 * doubles, not aliasing x. report may be NULL. */
ODE_API int ode_solve(ode_rhs f, void *ctx, size_t n, double *x, double duration, double rtol,
              double atol, long max_steps, double u_size, double *work, OdeReport *report);

#endif
