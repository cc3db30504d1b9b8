/* DelaycompDelay, native: y_k = u_{k-D} on n channels, u_j = u0 for j < 0.
 * The twin of fmus/delay/delaycomp_delay.py (delaycomp.maths.delayline.DelayLine): same
 * variables, checks and messages. The buffer is a ring of D values per channel. */
#include <math.h>
#include <string.h>

#include "native.h"
#include "grid.h"  /* nearest_multiple: the grid's rule */

/* The checks of fmi2ExitInitializationMode: 0, or -1 with the refusal logged. */
static int parameters_ok(Instance *c) {
    double delay = c->d.real[VR_DELAY];  /* checked in the Python slave's order */
    if (!isfinite(delay)) {
        log_error(c, "delay = %s is not allowed: must be a finite number", num(delay).s);
        return -1;
    }
    if (delay < 0) {
        log_error(c, "delay = %s is not allowed: must be >= 0", num(delay).s);
        return -1;
    }
    return check_real_parameters_finite(c);  /* u0 */
}

int model_setup(Instance *c) {
    if (parameters_ok(c) != 0) return -1;
    c->d.m.has_line = 0;
    c->d.m.D = 0;
    c->d.m.h = 0.0;
    c->d.m.head = 0;
    return alloc_buf(c, 0);
}

int model_output(Instance *c, ValueRef vr, double *value) {
    size_t i = vr - VR_Y;
    const ModelData *m = &c->d.m;
    if (m->has_line)
        *value = m->D == 0 ? c->d.real[VR_U + i] : c->buf[(size_t)m->head * NX + i];
    else
        *value = c->d.real[VR_DELAY] == 0.0 ? c->d.real[VR_U + i] : c->d.real[VR_U0 + i];
    return 0;
}

void model_input_set(Instance *c) { (void)c; }

static long steps_of(Instance *c, double delay, double h);

/* A restored line's checks: the parameters', then D = steps_of(delay, h) (*D, a long). */
static int line_of(Instance *c, void *D) {
    if (parameters_ok(c) != 0) return -1;
    *(long *)D = steps_of(c, c->d.real[VR_DELAY], c->d.m.h);
    return *(long *)D < 0 ? -1 : 0;
}

static int no_line_ok(Instance *c, void *out) {
    (void)out;
    return parameters_ok(c);
}

/* The line (D values per channel, a ring from head) exists from the first step on
 * (has_line), its length D = delay / h of that step's h. */
int model_state_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!state_flag(v, "has_line", m->has_line)) return 0;
    if (!m->has_line) {
        const char *why = "no delay line before the first step: has_line = 0";
        return state_long_is(v, "D", m->D, 0, why) && state_long_is(v, "head", m->head, 0, why) &&
               state_double_is(v, "h", m->h, 0.0, why) && state_nbuf(v, 0, why) &&
               (!state_in(v, StateStepComplete) ||
                state_parameters(v, no_line_ok, NULL, "state 'step complete'"));
    }
    if (state_in(v, StateInstantiated | StateInitializationMode))
        return state_refuse(v, "has_line = 1: must be 0 before " FMI_FN("ExitInitializationMode"));
    if (!state_positive(v, "h", m->h) || !state_range(v, "D", m->D, 0, (long)MAX_STEPS))
        return 0;
    long D = -1;
    return state_nbuf(v, (size_t)m->D * NX, "D values of each channel") &&
           state_index(v, "head", m->head, m->D) &&
           state_parameters(v, line_of, &D, "has_line = 1") &&
           state_long_is(v, "D", m->D, D, "delay / h");
}

/* delaycomp.maths.delayline.steps_of (delaycomp.maths.grid.steps_of): D with delay = D h, or -1
 * with a logged error */
static long steps_of(Instance *c, double delay, double h) {
    double ratio = delay / h;
    if (!(ratio <= MAX_STEPS)) {
        log_error(c, "delay = %s is not allowed: must be at most %.0f steps of the "
                  "communication step %s (it needs %.6g)", num(delay).s, MAX_STEPS, num(h).s,
                  ratio);
        return -1;
    }
    double D;
    if (!nearest_multiple(delay, h, &D)) {
        log_error(c, "delay = %s is not allowed: must be a multiple of the communication "
                  "step %s", num(delay).s, num(h).s);
        return -1;
    }
    return (long)D;
}

int model_step(Instance *c, double t, double h) {
    ModelData *m = &c->d.m;
    if (check_step(c, t, h) != 0) return -1;
    if (!m->has_line) {
        long D = steps_of(c, c->d.real[VR_DELAY], h);
        if (D < 0) return -1;
        if (alloc_buf(c, (size_t)D * NX) != 0) return -1;
        for (long k = 0; k < D; k++)
            memcpy(c->buf + (size_t)k * NX, &c->d.real[VR_U0], NX * sizeof(double));
        m->D = D;
        m->head = 0;
        m->h = h;
        m->has_line = 1;
    } else if (h <= ROUNDOFF_STEP_FRACTION * m->h) {
        return 0;  /* the master's round-off (delaycomp.fmu.slave.is_roundoff_step): nothing moves */
    } else if (!same_step(h, m->h, t) && !grid_step(t, h, m->h, c->d.t0)) {
        /* round-off is not another step size; a host whose clock drifts (t += h) ends its
         * last step on the stop time (grid_step) */
        log_error(c, "step size %s is not allowed: this delay runs on a fixed communication "
                  "step, %s", num(h).s, num(m->h).s);
        return -1;
    }
    if (check_inputs_finite(c, VR_U, NX, t) != 0) return -1;
    if (m->D > 0) {  /* the oldest value leaves, u_k takes its place */
        memcpy(c->buf + (size_t)m->head * NX, &c->d.real[VR_U], NX * sizeof(double));
        m->head = (m->head + 1) % m->D;
    }
    return 0;
}
