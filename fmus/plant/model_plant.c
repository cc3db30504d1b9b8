/* DelaycompPlant_<model>, native: x' = f(x, u) of a user model, u held over each step. The
 * twin of fmus/plant/delaycomp_model_plant.py: same variables, checks and messages. f (and
 * the model's exact step, when it translates) come from model.c, generated from the model
 * file by delaycomp.fmu.translate; without an exact step the flow is solved by ode.c (DOP853,
 * rtol = atol = tolerance, at most 100 000 steps, as delaycomp.maths.predictors.integrate). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "native.h"
#include "model.h"
#include "ode.h"
#include "model_common.h"

/* The checks of fmi2ExitInitializationMode (the Python FMU's order: the _index twins, x0,
 * tolerance, then the model's parameters); *branch (an int) the String parameters' branch
 * of model.c. 0, or -1 with the refusal logged. */
static int configure(Instance *c, void *branch) {
    Data *d = &c->d;
    if (model_resolve_choices(c) != 0) return -1;
    for (size_t i = 0; i < NX; i++) {
        double v = d->real[VR_X0 + i];
        if (!isfinite(v)) {
            log_error(c, "x0[%lu] = %s is not allowed: must be a finite number",
                      (unsigned long)(i + 1), num(v).s);
            return -1;
        }
    }
    double tol = d->real[VR_TOL];
    if (!isfinite(tol)) {
        log_error(c, "tolerance = %s is not allowed: must be a finite number", num(tol).s);
        return -1;
    }
    if (!(tol > 0 && tol < 1)) {
        log_error(c, "tolerance = %s is not allowed: must be in (0, 1)", num(tol).s);
        return -1;
    }
    if (model_check_numbers(c) != 0) return -1;
    return model_branch(c, branch);
}

/* The model buffer: ode.c's work memory and the new state */
static size_t buffer_size(void) { return ode_work_size(NX) + NX; }

int model_setup(Instance *c) {
    int branch;
    if (configure(c, &branch) != 0) return -1;
    c->d.m.branch = branch;
    memcpy(&c->d.real[VR_X], &c->d.real[VR_X0], NX * sizeof(double));
    return alloc_buf(c, buffer_size());
}

int model_output(Instance *c, ValueRef vr, double *value) {
    *value = c->d.real[vr];
    return 0;
}

void model_input_set(Instance *c) { (void)c; }

/* The buffer exists from fmi2ExitInitializationMode on (none after a refused one), with
 * the branch of the String parameters. */
int model_state_ok(const StateView *v) {
    int branch = v->d->m.branch;
    if (!state_range(v, "branch", branch, 0, MODEL_NBRANCH - 1)) return 0;
    if ((v->nbuf != 0 || state_in(v, StateStepComplete)) &&
        !state_nbuf(v, buffer_size(), "the work memory of the ODE solver, from "
                    FMI_FN("ExitInitializationMode") " on"))
        return 0;
    if (v->nbuf == 0) return 1;
    int expected = 0;
    return state_parameters(v, configure, &expected, "the model buffer present") &&
           state_long_is(v, "branch", branch, expected, "the branch of its String parameters");
}

int model_step(Instance *c, double t, double h) {
    Data *d = &c->d;
    if (check_step(c, t, h) != 0) return -1;
    if (check_inputs_finite(c, VR_U, NU, t) != 0) return -1;
    const double *u = &d->real[VR_U];
    double p[MODEL_NP > 0 ? MODEL_NP : 1];
    model_parameters(c, p);
    double *x = c->buf + ode_work_size(NX);  /* the new state, committed when finite */
#if MODEL_HAS_STEP
    int failed = gen_step(d->m.branch, &d->real[VR_X], u, h, p, x) != 0;
    const char *reason = failed ? "the model's step failed" : "";
#else
    memcpy(x, &d->real[VR_X], NX * sizeof(double));  /* the solver starts from x(t) */
    ModelRhs ctx = {d->m.branch, u, p};
    double u_size = 0.0;
    for (size_t j = 0; j < NU; j++) u_size = fmax(u_size, fabs(u[j]));
    OdeReport rep;
    int failed = ode_solve(model_rhs, &ctx, NX, x, h, d->real[VR_TOL], d->real[VR_TOL],
                           MAX_ODE_STEPS, u_size, c->buf, &rep) != ODE_OK;
    const char *reason = rep.reason;
#endif
    if (failed) {
        log_error(c, "plant step at t = %s failed: ODE solve failed 0 s into a window "
                  "(input %s): %s", num(t).s, vector_text(u, NU).s, reason);
        return -1;
    }
    int bad = 0;
    for (size_t i = 0; i < NX; i++) bad |= !isfinite(x[i]);
    if (bad) {
        log_error(c, "state %s at t = %s is not allowed: must be finite (the plant "
                  "diverged: the state is not finite after the step (input %s))",
                  OUTPUT_NAMES, num(t + h).s, vector_text(u, NU).s);
        return -1;
    }
    memcpy(&d->real[VR_X], x, NX * sizeof(double));
    return 0;
}
