/* Right-hand sides for tests/test_native_ode.py, and solve(): ode_solve on one of them
 * with work memory of exactly ode_work_size(n) doubles from malloc (so that valgrind sees
 * any access past it). */
#include <math.h>
#include <stdlib.h>

#include "ode.h"
#include "rhs.h"

typedef struct {
    int which;
    size_t n;
    const double *p;
    long calls;
} Ctx;

static int rhs(void *vctx, const double *x, double *dx) {
    Ctx *c = vctx;
    size_t n = c->n;
    const double *p = c->p;
    c->calls++;
    switch (c->which) {
    case RHS_LINEAR: /* x' = A x + b, A = p[0 .. n^2) row-major, b = p[n^2 .. n^2 + n) */
        for (size_t i = 0; i < n; i++) {
            double s = p[n * n + i];
            for (size_t j = 0; j < n; j++) s += p[i * n + j] * x[j];
            dx[i] = s;
        }
        return 0;
    case RHS_SQUARE: /* x' = x^2 */
        dx[0] = x[0] * x[0];
        return 0;
    case RHS_CUBE: /* x' = -x^3 */
        dx[0] = -x[0] * x[0] * x[0];
        return 0;
    case RHS_PENDULUM: /* angle, rate: x0' = x1, x1' = -p0 sin x0 */
        dx[0] = x[1];
        dx[1] = -p[0] * sin(x[0]);
        return 0;
    case RHS_VAN_DER_POL: /* x0' = x1, x1' = p0 (1 - x0^2) x1 - x0 */
        dx[0] = x[1];
        dx[1] = p[0] * (1.0 - x[0] * x[0]) * x[1] - x[0];
        return 0;
    case RHS_FAILS: /* x' = -x, but f fails from its call number p0 on */
        if ((double)c->calls >= p[0]) return 1;
        for (size_t i = 0; i < n; i++) dx[i] = -x[i];
        return 0;
    case RHS_NAN: /* x' = 1 while x < p0, NaN from there on */
        dx[0] = x[0] < p[0] ? 1.0 : NAN;
        return 0;
    default:
        return 1;
    }
}

int solve(int which, size_t n, const double *p, double *x, double duration, double rtol,
          double atol, long max_steps, double u_size, OdeReport *report, long *calls) {
    size_t size = ode_work_size(n);
    double *work = malloc(size > 0 ? size * sizeof *work : 1);
    if (work == NULL) return -100;
    Ctx c = {which, n, p, 0};
    int code = ode_solve(rhs, &c, n, x, duration, rtol, atol, max_steps, u_size, work,
                         report);
    free(work);
    if (calls != NULL) *calls = c.calls;
    return code;
}
