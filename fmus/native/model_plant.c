/* DelaycompPlant_<model>, native: x' = f(x, u) of a user model, u held over each step. The
 * twin of fmus/plant/delaycomp_model_plant.py: same variables, checks and messages. f (and
 * the model's exact step, when it translates) come from model.c, generated from the model
 * file by delaycomp.translate; without an exact step the flow is solved by ode.c (DOP853,
 * rtol = atol = tolerance, at most 100 000 steps, as delaycomp.predictors.integrate). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "native.h"
#include "model.h"
#include "model_config.h"
#include "ode.h"

#define MAX_ODE_STEPS 100000L  /* delaycomp.predictors._MAX_STEPS */

/* The model's numeric parameters in the order of gen_*'s p (T last: not a plant
 * parameter, NaN here). */
static void parameters(const Instance *c, double *p) {
    for (size_t i = 0; i < MODEL_NP; i++)
        p[i] = PARAM_VR[i] >= 0 ? c->d.real[PARAM_VR[i]] : NAN;
}

#if NCHOICE > 0
/* Apply each nonzero <name>_index to its String (resolve_choice_index). */
static int resolve_choice_twins(Instance *c) {
    for (size_t s = 0; s < NCHOICE; s++)
        if (resolve_choice_index(c, CHOICE_NAME[s], CHOICE_VR[s], CHOICE_INDEX_VR[s],
                                 CHOICE_VALUES[s], CHOICE_COUNT[s]) != 0)
            return -1;
    return 0;
}

/* The branch of model.c for the String parameters' values (the order of
 * delaycomp.translate: itertools.product over the names in sorted order, the first name
 * most significant); -1 and the Python FMU's message for a value not among the choices. */
static int branch_of(Instance *c, int *branch) {
    int b = 0;
    for (size_t s = 0; s < NCHOICE; s++) {
        const char *value = c->d.string[STRING_SLOT[CHOICE_VR[s]]];
        int pos = -1;
        for (int j = 0; j < CHOICE_COUNT[s]; j++)
            if (strcmp(value, CHOICE_VALUES[s][j]) == 0) pos = j;
        if (pos < 0) {
            char listed[STRING_MAX * 4];
            join_choices(CHOICE_VALUES[s], CHOICE_COUNT[s], listed, sizeof listed);
            log_error(c, "%s = '%s' is not allowed: must be one of %s", CHOICE_NAME[s], value,
                      listed);
            return -1;
        }
        b = b * CHOICE_COUNT[s] + pos;
    }
    *branch = b;
    return 0;
}
#else
static int resolve_choice_twins(Instance *c) {
    (void)c;
    return 0;
}

static int branch_of(Instance *c, int *branch) {
    (void)c;
    *branch = 0;
    return 0;
}
#endif

int model_setup(Instance *c) {
    Data *d = &c->d;
    if (resolve_choice_twins(c) != 0) return -1;
    /* the Python FMU's order: x0, tolerance, then the model's parameters */
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
    for (size_t i = 0; i < MODEL_NP; i++) {
        if (PARAM_VR[i] < 0) continue;
        double v = d->real[PARAM_VR[i]];
        if (!isfinite(v)) {
            log_error(c, "%s = %s is not allowed: must be a finite number",
                      VAR_NAME[PARAM_VR[i]], num(v).s);
            return -1;
        }
    }
    if (branch_of(c, &d->m.branch) != 0) return -1;
    memcpy(&d->real[VR_X], &d->real[VR_X0], NX * sizeof(double));
    return alloc_buf(c, ode_work_size(NX) + NX);
}

int model_output(Instance *c, fmi2ValueReference vr, double *value) {
    *value = c->d.real[vr];
    return 0;
}

void model_input_set(Instance *c) { (void)c; }

#if !MODEL_HAS_STEP
typedef struct {
    int branch;
    const double *u;
    const double *p;
} Rhs;

static int rhs(void *ctx, const double *x, double *dx) {
    const Rhs *r = ctx;
    return gen_f(r->branch, x, r->u, r->p, dx);
}
#endif

int model_step(Instance *c, double t, double h) {
    Data *d = &c->d;
    if (check_step(c, t, h) != 0) return -1;
    if (check_inputs_finite(c, VR_U, NU, t) != 0) return -1;
    const double *u = &d->real[VR_U];
    double p[MODEL_NP > 0 ? MODEL_NP : 1];
    parameters(c, p);
    double *x = c->buf + ode_work_size(NX);  /* the new state, committed when finite */
#if MODEL_HAS_STEP
    int failed = gen_step(d->m.branch, &d->real[VR_X], u, h, p, x) != 0;
    const char *reason = failed ? "the model's step failed" : "";
#else
    memcpy(x, &d->real[VR_X], NX * sizeof(double));  /* the solver starts from x(t) */
    Rhs ctx = {d->m.branch, u, p};
    double u_size = 0.0;
    for (size_t j = 0; j < NU; j++) u_size = fmax(u_size, fabs(u[j]));
    OdeReport rep;
    int failed = ode_solve(rhs, &ctx, NX, x, h, d->real[VR_TOL], d->real[VR_TOL],
                           MAX_ODE_STEPS, u_size, c->buf, &rep) != ODE_OK;
    const char *reason = rep.reason;
#endif
    if (failed) {
        char *text = vector_text(u, NU);
        log_error(c, "plant step at t = %s failed: ODE solve failed 0 s into a window "
                  "(input %s): %s", num(t).s, text ? text : "[...]", reason);
        free(text);
        return -1;
    }
    int bad = 0;
    for (size_t i = 0; i < NX; i++) bad |= !isfinite(x[i]);
    if (bad) {
        char *text = vector_text(u, NU);
        log_error(c, "state %s at t = %s is not allowed: must be finite (the plant "
                  "diverged: the state is not finite after the step (input %s))",
                  OUTPUT_NAMES, num(t + h).s, text ? text : "[...]");
        free(text);
        return -1;
    }
    memcpy(&d->real[VR_X], x, NX * sizeof(double));
    return 0;
}
