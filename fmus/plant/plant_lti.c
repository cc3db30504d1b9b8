/* DelaycompPlantLTI, native: x' = A x + B u, u held over each step, exactly discretized:
 * x_{k+1} = Ad x_k + Bd u_k, [Ad Bd; 0 I] = expm([A B; 0 0] h), recomputed only for a
 * step that is not the cached one up to GRID_RTOL and the round-off of the host's times
 * (same_step). Nothing is allocated after initialization. The twin of
 * fmus/plant/delaycomp_plant_lti.py: same variables, checks and messages. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "native.h"
#include "linalg.h"  /* flow: the exact discretization, with the caller's work memory */

/* The model buffer: Ad, Bd and the work memory of flow() */
static size_t buffer_size(void) {
    return (size_t)NX * NX + (size_t)NX * NU + flow_work_size(NX, NU);
}

int model_setup(Instance *c) {
    if (check_real_parameters_finite(c) != 0) return -1;
    memcpy(&c->d.real[VR_X], &c->d.real[VR_X0], NX * sizeof(double));
    c->d.m.has_h = 0;
    c->d.m.h = 0.0;
    /* allocated here, once (nothing while stepping) */
    return alloc_buf(c, buffer_size());
}

int model_output(Instance *c, ValueRef vr, double *value) {
    *value = c->d.real[vr];
    return 0;
}

void model_input_set(Instance *c) { (void)c; }

static int parameters_ok(Instance *c, void *out) {
    (void)out;
    return check_real_parameters_finite(c);
}

/* The buffer exists from fmi2ExitInitializationMode on (none after a refused one); Ad, Bd
 * are computed (has_h) for the step h at the first step. */
int model_state_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    const char *built = "Ad, Bd and the work memory of flow, from " FMI_FN("ExitInitializationMode") " on";
    if (!state_flag(v, "has_h", m->has_h)) return 0;
    if ((v->nbuf != 0 || state_in(v, StateStepComplete) || m->has_h) &&
        !state_nbuf(v, buffer_size(), built))
        return 0;
    if (m->has_h ? !state_positive(v, "h", m->h)
                 : !state_double_is(v, "h", m->h, 0.0, "no step yet: has_h = 0"))
        return 0;
    return v->nbuf == 0 || state_parameters(v, parameters_ok, NULL, "the model buffer present");
}

int model_step(Instance *c, double t, double h) {
    ModelData *m = &c->d.m;
    if (check_step(c, t, h) != 0) return -1;
    if (check_inputs_finite(c, VR_U, NU, t) != 0) return -1;
    double *Ad = c->buf, *Bd = c->buf + NX * NX;
    /* a step within GRID_RTOL and the round-off of the times of the cached one is that
     * step (same_step, the rule of delaycomp.maths.grid.same_step): a host's exact grid t0 + k h
     * passes steps that differ in the last bits, and each would otherwise cost a matrix
     * exponential */
    if (!m->has_h || !same_step(h, m->h, t)) {
        /* another step: discretized (bounded work, no allocation), the new key */
        flow(&c->d.real[VR_A], &c->d.real[VR_B], NX, NU, h, Ad, Bd, Bd + (size_t)NX * NU);
        m->h = h;
        m->has_h = 1;
    }
    double x[NX];
    int bad = 0;
    const double *xs = &c->d.real[VR_X], *u = &c->d.real[VR_U];
    for (size_t i = 0; i < NX; i++) {
        double a = 0.0, b = 0.0;
        for (size_t j = 0; j < NX; j++) a += Ad[i * NX + j] * xs[j];
        for (size_t j = 0; j < NU; j++) b += Bd[i * NU + j] * u[j];
        x[i] = a + b;
        bad |= !isfinite(x[i]);
    }
    if (bad) {
        log_error(c, "state %s = %s at t = %s is not allowed: must be finite (the plant "
                  "diverged: overflow)", OUTPUT_NAMES, vector_text(x, NX).s, num(t + h).s);
        return -1;
    }
    memcpy(&c->d.real[VR_X], x, NX * sizeof(double));
    return 0;
}
