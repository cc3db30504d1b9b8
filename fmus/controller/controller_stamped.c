/* DelaycompControllerStamped, native: the time-stamp predictor-controller of an LTI plant.
 * At each sampling instant t_i = t0 + i T it reads the sample y = x(s)
 * and its stamp s (a network channel's outputs) and keeps the estimate z_i of x(t_i):
 *
 *   a new sample (s later than the last one used), no older than age_max: z_i = y carried
 *   from max(s, t0) to t_i through the plant's exact flow with the inputs the plant
 *   received meanwhile; otherwise (lost, repeated, too old): z_{i-1} carried over
 *   [t_{i-1}, t_i]; the first instant always uses its sample;
 *
 * and outputs u_i = K x_hat, x_hat = z_i carried over [t_i, t_i + tau] (compensated), or
 * u_i = K y (uncompensated), held over [t_i, t_{i+1}). The plant receives u_j over
 * [t_j + tau, t_{j+1} + tau) (u0 before t0 + tau). The twin of
 * fmus/controller/delaycomp_controller_stamped.py (delaycomp.maths.stamped.
 * StampedController): same variables, checks, messages and timing, held_sample (the sample
 * and its stamp held) included; the same piece walk (StampedController.advance, its SNAP
 * rule). Each piece's flow is computed when it is needed (linalg.c's flow, no cache: the
 * results cannot depend on one), in work memory allocated at initialization. */
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>

#include "native.h"
#include "held.h"    /* held_sample and the proposal, as the other controllers */
#include "linalg.h"  /* flow, with the caller's work memory */

#define SNAP 1e-9  /* delaycomp.maths.stamped.SNAP: a time this close (in T) to a breakpoint */

static const char *mode_of(const Instance *c) { return c->d.string[STRING_SLOT[VR_MODE]]; }

static int compensated(const Instance *c) { return strcmp(mode_of(c), "compensated") == 0; }

/* The Integer twin of mode: k = 1, 2 selects compensated, uncompensated. */
static int resolve_mode_index(Instance *c) {
    static const char *const choices[] = {"compensated", "uncompensated"};
    return resolve_choice_index(c, "mode", VR_MODE, VR_MODE_INDEX, choices, 2);
}

/* "name = value is not allowed: must be a finite number > 0" (StampedController's). */
static int check_number(Instance *c, const char *name, double value, int positive) {
    if (isfinite(value) && (positive ? value > 0 : value >= 0)) return 0;
    log_error(c, "%s = %s is not allowed: must be a finite number %s", name, num(value).s,
              positive ? "> 0" : ">= 0.0");
    return -1;
}

/* The checks of fmi2ExitInitializationMode (the Python FMU's order) and the number of
 * outputs stored (*out, a long): 0, or -1 with the refusal logged. */
static int configure(Instance *c, void *out) {
    long *L = out;
    const Data *d = &c->d;
    double T = d->real[VR_T], tau = d->real[VR_TAU], age_max = d->real[VR_AGE_MAX];
    if (resolve_mode_index(c) != 0 || check_real_parameters_finite(c) != 0) return -1;
    if (check_number(c, "T", T, 1) != 0 || check_number(c, "tau", tau, 0) != 0 ||
        check_number(c, "age_max", age_max, 0) != 0)
        return -1;
    if (strcmp(mode_of(c), "compensated") != 0 && strcmp(mode_of(c), "uncompensated") != 0) {
        log_error(c, "mode = '%s' is not allowed: must be one of compensated, uncompensated",
                  mode_of(c));
        return -1;
    }
    double steps = (age_max + tau) / T;
    if (!(steps <= MAX_STEPS)) {  /* delaycomp.maths.grid.check_steps */
        log_error(c, "age_max + tau = %s is not allowed: must be at most %.0f sampling "
                  "periods of T = %s (it needs %.6g)", num(age_max + tau).s, MAX_STEPS,
                  num(T).s, steps);
        return -1;
    }
    *L = (long)floor(steps) + 2;
    return 0;
}

/* The model buffer: the output history (L x NU, a ring), then the work memory of a piece:
 * flow's, E (NX x NX), G (NX x NU) and two states. */
static size_t work_size(void) {
    return flow_work_size(NX, NU) + (size_t)NX * NX + (size_t)NX * NU + 2 * (size_t)NX;
}

static size_t buffer_size(long L) { return (size_t)L * NU + work_size(); }

int model_setup(Instance *c) {
    Data *d = &c->d;
    ModelData *m = &d->m;
    m->built = 0;
    long L = 0;
    if (alloc_buf(c, 0) != 0 || configure(c, &L) != 0) return -1;
    if (alloc_buf(c, buffer_size(L)) != 0) return -1;
    for (long p = 0; p < L; p++)
        memcpy(c->buf + (size_t)p * NU, &d->real[VR_U0], NU * sizeof(double));
    memcpy(m->held, &d->real[VR_U0], NU * sizeof(double));
    m->L = L;
    m->hist_head = 0;
    m->next = 0;
    m->at_sample = 1;
    m->proposal_valid = 0;
    m->y_held_valid = 0;
    m->stamp_held = 0.0;
    memset(m->z, 0, sizeof m->z);
    m->stamp = 0.0;
    m->built = 1;
    return 0;
}

/* the current sampling instant t_i = t0 + i T */
static double instant(const Instance *c) {
    return c->d.t0 + (double)c->d.m.next * c->d.real[VR_T];
}

/* u_j, the output held over [t_j, t_{j+1}) (u0 for j < 0); -1 (logged) if not stored.
 * j is an integer held in a double (exact below 2^53; no conversion of a crafted state's
 * huge index can overflow a long). */
static int input_of(Instance *c, double j, const double **u) {
    const ModelData *m = &c->d.m;
    if (j < 0) {
        *u = &c->d.real[VR_U0];
        return 0;
    }
    double back = (double)m->next - 1 - j;
    if (!(back >= 0 && back < (double)m->L)) {  /* never beyond age_max + tau */
        log_error(c, "output %.0f is not stored (instant %ld, %ld kept)", j, m->next, m->L);
        return -1;
    }
    *u = c->buf + (size_t)((m->hist_head + (long)back) % m->L) * NU;
    return 0;
}

/* The output j the plant receives just after time w: t_j + tau <= w < t_{j+1} + tau (a
 * time within round-off of a breakpoint is on it). */
static double piece(const Instance *c, double w) {
    double x = (w - c->d.t0 - c->d.real[VR_TAU]) / c->d.real[VR_T];
    double j = floor(x);
    return x - j > 1.0 - SNAP ? j + 1 : j;
}

/* x (NX, in place): the plant's state at b from x at a <= b, with the inputs it receives
 * over [a, b] (an exact flow per piece). 0, or -1 (logged) for an output not stored. */
static int advance(Instance *c, double *x, double a, double b) {
    const Data *d = &c->d;
    double T = d->real[VR_T], tau = d->real[VR_TAU], tol = SNAP * T;
    double *work = c->buf + (size_t)d->m.L * NU;
    double *E = work + flow_work_size(NX, NU), *G = E + (size_t)NX * NX,
           *xn = G + (size_t)NX * NU;
    const double *A = &d->real[VR_A], *B = &d->real[VR_B];
    while (b - a > tol) {
        double j = piece(c, a);
        double end = fmin(d->t0 + (j + 1) * T + tau, b);
        const double *u;
        if (!(end > a)) {  /* T below the round-off of the time: no piece would end */
            log_error(c, "time %s is not allowed: the sampling period T = %s is below its "
                      "round-off", num(a).s, num(T).s);
            return -1;
        }
        if (input_of(c, j, &u) != 0) return -1;
        flow(A, B, NX, NU, end - a, E, G, work);
        for (size_t i = 0; i < NX; i++) {
            double s = 0.0, g = 0.0;
            for (size_t k = 0; k < NX; k++) s += E[i * NX + k] * x[k];
            for (size_t k = 0; k < NU; k++) g += G[i * NU + k] * u[k];
            xn[i] = s + g;
        }
        memcpy(x, xn, NX * sizeof(double));
        a = end;
    }
    return 0;
}

/* The stamp shown at the instant: finite, <= t (up to the snap). */
static int stamp_fine(const Instance *c, double stamp) {
    return isfinite(stamp) && stamp <= instant(c) + SNAP * c->d.real[VR_T];
}

/* stamp_fine, else -1 with the Python twin's message logged */
static int stamp_ok(Instance *c, double stamp) {
    double t = instant(c);
    if (stamp_fine(c, stamp)) return 0;
    log_error(c, "stamp = %s at t = %s is not allowed: must be a finite time <= t (the send "
              "time of the sample shown)", num(stamp).s, num(t).s);
    return -1;
}

/* z_i (z, NX) from the sample y taken at stamp (*fresh = 1: the sample is used) or, where
 * it is not new or too old, from z_{i-1}. 0, or -1 (logged). */
static int estimate(Instance *c, const double *y, double stamp, double *z, int *fresh) {
    const ModelData *m = &c->d.m;
    if (stamp_ok(c, stamp) != 0) return -1;
    double t = instant(c), t0 = c->d.t0;
    double s = t0 > stamp ? t0 : stamp;  /* before t0: the history x0, the state at t0 */
    *fresh = m->next == 0 ||
             (stamp > m->stamp && t - s <= c->d.real[VR_AGE_MAX] + SNAP * c->d.real[VR_T]);
    if (*fresh) {
        memcpy(z, y, NX * sizeof(double));
        return advance(c, z, s, t);
    }
    memcpy(z, m->z, NX * sizeof(double));
    return advance(c, z, t - c->d.real[VR_T], t);
}

/* u = K x_hat (compensated: x_hat the estimate carried over tau) or K y. 0, or -1
 * (logged: the stamp). */
static int propose(Instance *c, const double *y, double stamp, double *u) {
    const double *K = &c->d.real[VR_K];
    double x[NX];
    if (compensated(c)) {
        int fresh;
        double t = instant(c);
        if (estimate(c, y, stamp, x, &fresh) != 0 ||
            advance(c, x, t, t + c->d.real[VR_TAU]) != 0)
            return -1;
        y = x;
    }
    for (size_t j = 0; j < NU; j++) {
        double s = 0.0;
        for (size_t k = 0; k < NX; k++) s += K[j * NX + k] * y[k];
        u[j] = s;
    }
    return 0;
}

/* The sample read now and its stamp (held_sample: those held over the step that ended). */
static const double *sampled(const Instance *c, double *stamp) {
    const ModelData *m = &c->d.m;
    const double *y = held_sample(c->d.boolean[VR_HELD_SAMPLE], m->y_held_valid, m->y_held,
                                  &c->d.real[VR_Y]);
    *stamp = y == m->y_held ? m->stamp_held : c->d.real[VR_STAMP];  /* held with it */
    return y;
}

/* A sample and its stamp, as proposal_once hands them to propose_sample. */
typedef struct {
    const double *y;
    double stamp;
} Sample;

static int propose_sample(Instance *c, const void *ctx, double *u) {
    const Sample *s = ctx;
    return propose(c, s->y, s->stamp, u);
}

/* The current output; -1 (logged) for a stamp from the future or an overflow. After a
 * fault a refused stamp is not logged again (the Python FMU logs its first error). */
static int output(Instance *c, const double **u) {
    ModelData *m = &c->d.m;
    if (!m->built) { *u = &c->d.real[VR_U0]; return 0; }
    if (!m->at_sample) { *u = m->held; return 0; }
    Sample s = {NULL, 0.0};
    if (!m->proposal_valid) {
        s.y = sampled(c, &s.stamp);
        if (compensated(c) && c->d.state == StateError && !stamp_fine(c, s.stamp)) {
            *u = m->held;
            return 0;
        }
    }
    return proposal_once(c, propose_sample, &s, &m->proposal_valid, m->proposal, s.y,
                         instant(c), m->held, u);
}

int model_output(Instance *c, ValueRef vr, double *value) {
    const double *u;
    int rc = output(c, &u);
    *value = u[vr - VR_UOUT];
    return rc;
}

void model_input_set(Instance *c) { c->d.m.proposal_valid = 0; }

int model_step(Instance *c, double t, double h) {
    ModelData *m = &c->d.m;
    if (check_step(c, t, h) != 0) return -1;
    if (check_inputs_finite(c, VR_Y, NX + 1, t) != 0) return -1;  /* y and the stamp */
    if (m->at_sample) {  /* commit u_i (unchecked, as the Python FMU), z_i, the stamp */
        double stamp, u[NU], z[NX];
        const double *y = sampled(c, &stamp);
        int fresh;
        if (m->proposal_valid)
            memcpy(u, m->proposal, sizeof u);
        else if (propose(c, y, stamp, u) != 0)
            return -1;
        if (estimate(c, y, stamp, z, &fresh) != 0) return -1;
        if (fresh) m->stamp = stamp;  /* newer than the last (or the first) */
        memcpy(m->z, z, sizeof z);
        memcpy(m->held, u, sizeof u);
        m->hist_head = (m->hist_head + m->L - 1) % m->L;
        memcpy(c->buf + (size_t)m->hist_head * NU, u, sizeof u);
        m->next += 1;
        m->proposal_valid = 0;
    }
    if (ends_on_sample(c, t, h, c->d.real[VR_T], m->next, &m->at_sample) != 0) return -1;
    if (held_keep(c->d.boolean[VR_HELD_SAMPLE], &c->d.real[VR_Y], NX, m->y_held,
                  &m->y_held_valid)) {
        m->stamp_held = c->d.real[VR_STAMP];  /* the stamp is held with its sample */
        m->proposal_valid = 0;
    }
    return 0;
}

/* ---- a restored state ------------------------------------------------------------------ */

/* An unbuilt controller (before initialization, or refused there) holds nothing: no
 * buffer, every field 0. */
static int unbuilt_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    const char *why = "an unbuilt controller: built = 0";
    if (state_in(v, StateStepComplete))
        return state_refuse(v, "built = 0: must be 1 in state 'step complete' (the controller "
                            "is built at " FMI_FN("ExitInitializationMode") ")");
    return state_nbuf(v, 0, "no output history: built = 0") &&
           state_long_is(v, "L", m->L, 0, why) && state_long_is(v, "next", m->next, 0, why) &&
           state_long_is(v, "hist_head", m->hist_head, 0, why) &&
           state_long_is(v, "at_sample", m->at_sample, 0, why) &&
           state_long_is(v, "proposal_valid", m->proposal_valid, 0, why) &&
           state_long_is(v, "y_held_valid", m->y_held_valid, 0, why) &&
           state_double_is(v, "stamp_held", m->stamp_held, 0.0, why) &&
           state_double_is(v, "stamp", m->stamp, 0.0, why) &&
           state_zeros(v, "proposal", m->proposal, NU, why) &&
           state_zeros(v, "y_held", m->y_held, NX, why) &&
           state_zeros(v, "held", m->held, NU, why) && state_zeros(v, "z", m->z, NX, why);
}

/* proposal_valid = 1: the proposal is u_i of the current sample (recomputed on a copy:
 * the same arithmetic gives the same bits). */
static int proposal_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!m->proposal_valid) return 1;
    Instance *s = state_scratch(v, 1);
    if (s == NULL) return 0;
    double stamp, u[NU];
    const double *y = sampled(s, &stamp);
    int rc = propose(s, y, stamp, u);
    state_scratch_free(s);
    if (rc != 0)
        return state_refuse(v, "proposal_valid = 1: must be 0 where the sample's stamp %s is "
                            "refused", num(stamp).s);
    return proposal_same(v, m->proposal, u);
}

static int sample_time_ok(const StateView *v) {
    return state_sampling_time(v, v->d->real[VR_T], v->d->m.next, v->d->m.at_sample);
}

/* The estimate and the last stamp: present from the first instant on (zeros before), z
 * finite, the stamp a finite time before the next instant. */
static int estimate_ok(const StateView *v) {
    const Data *d = v->d;
    const ModelData *m = &d->m;
    if (m->next == 0)
        return state_zeros(v, "z", m->z, NX, "next = 0, no estimate yet") &&
               state_double_is(v, "stamp", m->stamp, 0.0, "next = 0, no sample used yet");
    double t_next = d->t0 + (double)m->next * d->real[VR_T];
    if (!state_finite(v, "z", m->z, NX)) return 0;
    if (isfinite(m->stamp) && m->stamp <= t_next) return 1;
    return state_refuse(v, "stamp = %s: must be a finite time <= t0 + next T = %s (the last "
                        "sample used)", num(m->stamp).s, num(t_next).s);
}

/* A built controller: its size that of its parameters (which initialization accepted), its
 * buffer of that size, the flags consistent, the numbers it steps with finite. */
static int built_ok(const StateView *v) {
    const Data *d = v->d;
    const ModelData *m = &d->m;
    long L = 0;
    if (!state_parameters(v, configure, &L, "built = 1") ||
        !state_long_is(v, "L", m->L, L, "floor((age_max + tau) / T) + 2") ||
        !state_nbuf(v, buffer_size(m->L), "L outputs and the work memory of flow: built = 1") ||
        !state_index(v, "hist_head", m->hist_head, m->L) ||
        !state_range(v, "next", m->next, 0, LONG_MAX - 1))
        return 0;
    if (!proposal_flag_ok(v, m->proposal_valid, m->at_sample) ||
        !held_state_ok(v, d->boolean[VR_HELD_SAMPLE], m->y_held_valid, m->y_held, NX) ||
        !(m->y_held_valid ? state_finite(v, "stamp_held", &m->stamp_held, 1)
                          : state_double_is(v, "stamp_held", m->stamp_held, 0.0,
                                            "y_held_valid = 0")))
        return 0;
    /* held and the history may be any numbers (a step commits u unchecked, as the Python
     * FMU's); the proposal is checked by recomputing it, with the estimate it starts from */
    return estimate_ok(v) && (!state_in(v, StateStepComplete) || sample_time_ok(v)) &&
           proposal_ok(v);
}

int model_state_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!state_flag(v, "built", m->built) || !state_flag(v, "at_sample", m->at_sample) ||
        !state_flag(v, "proposal_valid", m->proposal_valid) ||
        !state_flag(v, "y_held_valid", m->y_held_valid))
        return 0;
    return m->built ? built_ok(v) : unbuilt_ok(v);
}
