/* DelaycompControllerLTI, native: the zero-order-hold predictor-controller of Theorem 3.2
 * with the LTI predictor of Corollary 3.4, (3.15)-(3.16):
 *
 *   u_i = K Phi_i,  Phi_i = e^{A(r+tau)} y_i + sum_{p=1}^{l+q+1} Q_p B u_{i-p}
 *   Q_p B = e^{A(p-1)T} G(T)        (p = 1 .. l+q),   G(s) = int_0^s e^{Aw} dw B
 *   Q_{l+q+1} B = e^{A(l+q)T} G(r~)
 *
 * (compensated), or u_i = K y_i (uncompensated), held over [t_i, t_{i+1}). With pad = true
 * a tau that is no multiple of T is padded up to tau_eff = ceil(tau / T) T (Remark 3.3(b)):
 * Phi predicts over tau_eff and u_i reaches the output at t_i + (tau_eff - tau), the
 * output held before it shown until then (pad_line). The twin of
 * fmus/controller/delaycomp_controller_lti.py (delaycomp.maths.zoh.ZOHController and
 * delaycomp.maths.lti.LTIPredictor): same variables, checks, messages and timing, held_sample
 * included. Matrices are computed once, at fmi2ExitInitializationMode. */
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>

#include "native.h"
#include "grid.h"    /* split: the grid's rule for a delay in periods */
#include "held.h"    /* held_sample and the proposal, as the other controllers */
#include "linalg.h"  /* expm, flow, matmul, with the caller's work memory */


static const char *mode_of(const Instance *c) { return c->d.string[STRING_SLOT[VR_MODE]]; }

static int compensated(const Instance *c) { return strcmp(mode_of(c), "compensated") == 0; }

/* delaycomp.maths.lti.split_delay (delaycomp.maths.grid.split): q = [r/T] and r~ = r - qT,
 * integer up to round-off; r >= 0 with r / T at most MAX_STEPS (configure checks both) */
static void split_delay(double r, double T, long *q, double *rest) {
    double whole;
    split(r, T, &whole, rest);
    *q = (long)whole;
}

/* The Integer twin of mode (delaycomp.fmu.slave, item 9): k = 1, 2 selects compensated,
 * uncompensated (resolve_choice_index). */
static int resolve_mode_index(Instance *c) {
    static const char *const choices[] = {"compensated", "uncompensated"};
    return resolve_choice_index(c, "mode", VR_MODE, VR_MODE_INDEX, choices, 2);
}

/* What initialization derives from the parameters: tau_eff = l T (tau padded up with pad),
 * q = [r/T], L = l + q + 1, the padding tau_eff - tau. */
typedef struct {
    long l, q, L;
    double r_tilde, tau_eff, padding;
} Sizes;

/* The checks of fmi2ExitInitializationMode (the Python FMU's order) and the sizes they give
 * (*out, a Sizes): 0, or -1 with the refusal logged. */
static int configure(Instance *c, void *out) {
    Sizes *z = out;
    const Data *d = &c->d;
    double T = d->real[VR_T], r = d->real[VR_R], tau = d->real[VR_TAU];
    if (resolve_mode_index(c) != 0 || check_real_parameters_finite(c) != 0) return -1;
    if (!(T > 0)) {
        log_error(c, "T = %s is not allowed: must be > 0", num(T).s);
        return -1;
    }
    if (r < 0) {
        log_error(c, "r = %s is not allowed: must be >= 0", num(r).s);
        return -1;
    }
    double steps = (r + tau) / T;
    if (!(steps <= MAX_STEPS)) {
        log_error(c, "r + tau = %s is not allowed: must be at most %.0f sampling periods of "
                  "T = %s (it needs %.6g)", num(r + tau).s, MAX_STEPS, num(T).s, steps);
        return -1;
    }
    double tau_rest = 0.0;
    z->l = 0;
    z->tau_eff = tau;
    z->padding = 0.0;
    if (tau >= 0) split_delay(tau, T, &z->l, &tau_rest);
    if (tau < 0) {
        log_error(c, "tau = %s is not allowed: zero-order hold needs a multiple l*T (l >= 0) "
                  "of T = %s", num(tau).s, num(T).s);  /* delaycomp.maths.grid.periods */
        return -1;
    }
    if (tau_rest != 0.0) {
        double padded = (double)(z->l + 1) * T;  /* delaycomp.maths.grid.padded_delay */
        if (!d->boolean[VR_PAD]) {
            log_error(c, "tau = %s is not allowed: zero-order hold needs a multiple l*T "
                      "(l >= 0) of T = %s; pad = true pads it up to %s (Remark 3.3(b))",
                      num(tau).s, num(T).s, num(padded).s);  /* delaycomp.maths.grid.periods */
            return -1;
        }
        z->l += 1;
        z->tau_eff = padded;
        z->padding = padded - tau;
    }
    if (strcmp(mode_of(c), "compensated") != 0 && strcmp(mode_of(c), "uncompensated") != 0) {
        log_error(c, "mode = '%s' is not allowed: must be one of compensated, uncompensated",
                  mode_of(c));
        return -1;
    }
    split_delay(r, T, &z->q, &z->r_tilde);
    z->L = z->l + z->q + 1;
    return 0;
}

/* The model buffer: E (NX x NX), [Q_1 B .. Q_L B] (NX x NU L), the input history (L x NU) */
static size_t buffer_size(long L) {
    return (size_t)NX * NX + (size_t)NX * NU * (size_t)L + (size_t)L * NU;
}

/* E = e^{A(r+tau)} and the Q_p B into the buffer (sized for z->L). 0, or -1 (logged) when
 * out of memory. */
static int predictor_matrices(Instance *c, const Sizes *z) {
    const Data *d = &c->d;
    double T = d->real[VR_T], r = d->real[VR_R], tau = z->tau_eff;
    long L = z->L;
    size_t nE = (size_t)NX * NX;
    double *E = c->buf, *QB = c->buf + nE;
    const double *A = &d->real[VR_A], *B = &d->real[VR_B];
    /* initialization's own work memory, freed below (nothing is allocated while stepping) */
    size_t nwork = flow_work_size(NX, NU);
    double *work = calloc(3 * nE + 2 * (size_t)NX * NU + nwork, sizeof(double));
    if (work == NULL) {
        log_error(c, "out of memory computing the predictor");
        return -1;
    }
    double *ET = work, *power = work + nE, *GT = work + 2 * nE, *G = GT + (size_t)NX * NU,
           *tmp = G + (size_t)NX * NU, *scratch = tmp + nE;
    double *As = tmp;  /* A (r + tau), then scratch */
    for (size_t k = 0; k < nE; k++) As[k] = A[k] * (r + tau);
    expm(As, NX, E, scratch);  /* expm_work_size(n) <= flow_work_size(n, m) */
    flow(A, B, NX, NU, T, ET, GT, scratch);
    for (size_t i = 0; i < NX; i++)
        for (size_t j = 0; j < NX; j++) power[i * NX + j] = i == j ? 1.0 : 0.0;
    size_t stride = (size_t)NU * (size_t)L;  /* QB is NX x (NU L), [Q_1 B, Q_2 B, ...] */
    for (long p = 0; p < L; p++) {
        if (p == L - 1) flow(A, B, NX, NU, z->r_tilde, tmp, G, scratch);  /* tmp: unused */
        const double *Gp = p == L - 1 ? G : GT;
        for (size_t i = 0; i < NX; i++) {
            for (size_t j = 0; j < NU; j++) {
                double s = 0.0;
                for (size_t k = 0; k < NX; k++) s += power[i * NX + k] * Gp[k * NU + j];
                QB[i * stride + (size_t)p * NU + j] = s;
            }
        }
        if (p < L - 1) {
            matmul(power, ET, NX, NX, NX, tmp);
            memcpy(power, tmp, nE * sizeof(double));
        }
    }
    free(work);
    return 0;
}

int model_setup(Instance *c) {
    Data *d = &c->d;
    ModelData *m = &d->m;
    m->built = 0;
    Sizes z;
    if (alloc_buf(c, 0) != 0 || configure(c, &z) != 0) return -1;
    if (alloc_buf(c, buffer_size(z.L)) != 0) return -1;
    if (predictor_matrices(c, &z) != 0) {
        alloc_buf(c, 0);
        return -1;
    }
    if (z.padding > 0)
        log_info(c, "input delay padded from tau = %s to %s: the controller delays its "
                 "output by %s s", num(d->real[VR_TAU]).s, num(z.tau_eff).s, num(z.padding).s);
    size_t nEQ = (size_t)NX * NX + (size_t)NX * NU * (size_t)z.L;
    if (compensated(c)) {
        int finite = 1;
        for (size_t k = 0; k < nEQ; k++) finite &= isfinite(c->buf[k]) != 0;
        if (!finite) {
            const double *A = &d->real[VR_A];
            char *text = matrix_text(A, NX, NX);
            log_error(c, "A = %s is not allowed: must keep the predictor e^(A (r + tau)) "
                      "finite for r + tau = %s (it overflows)", text ? text : "[...]",
                      num(d->real[VR_R] + d->real[VR_TAU]).s);
            free(text);
            alloc_buf(c, 0);  /* refused: no predictor, no buffer (an unbuilt controller) */
            return -1;
        }
    }
    double *hist = c->buf + nEQ;
    for (long p = 0; p < z.L; p++)
        memcpy(hist + (size_t)p * NU, &d->real[VR_U0], NU * sizeof(double));
    memcpy(m->held, &d->real[VR_U0], NU * sizeof(double));
    if (z.padding > 0) memcpy(m->pad_line, &d->real[VR_U0], NU * sizeof(double));
    else memset(m->pad_line, 0, sizeof m->pad_line);
    m->padding = z.padding;
    m->released = 1;
    m->l = z.l;
    m->q = z.q;
    m->L = z.L;
    m->r_tilde = z.r_tilde;
    m->hist_head = 0;
    m->next = 0;
    m->at_sample = 1;
    m->proposal_valid = 0;
    m->y_held_valid = 0;
    m->built = 1;
    return 0;
}

/* u = K Phi(y, history) or K y, from the sampled measurement */
static void propose(Instance *c, const double *y, double *u) {
    const ModelData *m = &c->d.m;
    const double *K = &c->d.real[VR_K];
    double phi[NX];
    if (compensated(c)) {
        size_t nE = (size_t)NX * NX, stride = (size_t)NU * (size_t)m->L;
        const double *E = c->buf, *QB = c->buf + nE, *hist = QB + (size_t)NX * stride;
        for (size_t i = 0; i < NX; i++) {
            double a = 0.0, b = 0.0;
            for (size_t k = 0; k < NX; k++) a += E[i * NX + k] * y[k];
            for (long p = 0; p < m->L; p++) {  /* u_{i-p-1}, newest first */
                const double *up = hist + (size_t)((m->hist_head + p) % m->L) * NU;
                for (size_t j = 0; j < NU; j++) b += QB[i * stride + (size_t)p * NU + j] * up[j];
            }
            phi[i] = a + b;
        }
        y = phi;
    }
    for (size_t j = 0; j < NU; j++) {
        double s = 0.0;
        for (size_t k = 0; k < NX; k++) s += K[j * NX + k] * y[k];
        u[j] = s;
    }
}

/* The sample the controller reads now: y, or (held_sample) the input held. */
static const double *sampled(const Instance *c) {
    const ModelData *m = &c->d.m;
    return held_sample(c->d.boolean[VR_HELD_SAMPLE], m->y_held_valid, m->y_held,
                       &c->d.real[VR_Y]);
}

/* propose as proposal_once calls it: ctx is the sample, which is never refused */
static int propose_sample(Instance *c, const void *ctx, double *u) {
    propose(c, ctx, u);
    return 0;
}

/* u_i of the current sample (computed once per measurement); -1 (logged) when the
 * feedback overflows for a finite input y */
static int proposed(Instance *c, const double **u) {
    ModelData *m = &c->d.m;
    return proposal_once(c, propose_sample, sampled(c), &m->proposal_valid, m->proposal,
                         &c->d.real[VR_Y], c->d.t0 + (double)m->next * c->d.real[VR_T],
                         m->proposal, u);
}

/* The current output; -1 (logged) when the feedback overflows */
static int output(Instance *c, const double **u) {
    ModelData *m = &c->d.m;
    if (!m->built) { *u = &c->d.real[VR_U0]; return 0; }
    if (m->padding > 0) {  /* padded: u_i reaches the output at t_i + padding */
        *u = m->at_sample || m->released ? m->held : m->pad_line;
        return 0;
    }
    if (!m->at_sample) { *u = m->held; return 0; }
    return proposed(c, u);
}

int model_output(Instance *c, ValueRef vr, double *value) {
    const double *u;
    int rc = output(c, &u);
    *value = u[vr - VR_UOUT];
    return rc;
}

void model_input_set(Instance *c) { c->d.m.proposal_valid = 0; }

/* An unbuilt controller (before initialization, or refused there) holds nothing: no
 * buffer, every field 0. */
static int unbuilt_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    const char *why = "an unbuilt controller: built = 0";
    if (state_in(v, StateStepComplete))
        return state_refuse(v, "built = 0: must be 1 in state 'step complete' (the predictor "
                            "is built at " FMI_FN("ExitInitializationMode") ")");
    return state_nbuf(v, 0, "no predictor and no input history: built = 0") &&
           state_long_is(v, "l", m->l, 0, why) && state_long_is(v, "q", m->q, 0, why) &&
           state_long_is(v, "L", m->L, 0, why) && state_long_is(v, "next", m->next, 0, why) &&
           state_long_is(v, "hist_head", m->hist_head, 0, why) &&
           state_long_is(v, "at_sample", m->at_sample, 0, why) &&
           state_long_is(v, "proposal_valid", m->proposal_valid, 0, why) &&
           state_long_is(v, "y_held_valid", m->y_held_valid, 0, why) &&
           state_double_is(v, "r_tilde", m->r_tilde, 0.0, why) &&
           state_double_is(v, "padding", m->padding, 0.0, why) &&
           state_long_is(v, "released", m->released, 0, why) &&
           state_zeros(v, "pad_line", m->pad_line, NU, why) &&
           state_zeros(v, "proposal", m->proposal, NU, why) &&
           state_zeros(v, "y_held", m->y_held, NX, why) && state_zeros(v, "held", m->held, NU, why);
}

/* proposal_valid = 1: the proposal is u_i of the current sample (recomputed: the same
 * arithmetic gives the same bits). */
static int proposal_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!m->proposal_valid) return 1;
    Instance *s = state_scratch(v, 1);
    if (s == NULL) return 0;
    double u[NU];
    propose(s, sampled(s), u);
    state_scratch_free(s);
    return proposal_same(v, m->proposal, u);
}

static int sample_time_ok(const StateView *v) {
    return state_sampling_time(v, v->d->real[VR_T], v->d->m.next, v->d->m.at_sample);
}

/* A built controller: its sizes those of its parameters (which initialization accepted),
 * its buffer of that size, the flags consistent, the numbers it steps with finite. */
static int built_ok(const StateView *v) {
    const Data *d = v->d;
    const ModelData *m = &d->m;
    Sizes z = {0, 0, 0, 0.0, 0.0, 0.0};
    if (!state_parameters(v, configure, &z, "built = 1") ||
        !state_long_is(v, "l", m->l, z.l, "tau / T, padded up with pad") ||
        !state_long_is(v, "q", m->q, z.q, "[r / T]") ||
        !state_long_is(v, "L", m->L, z.L, "l + q + 1") ||
        !state_double_is(v, "r_tilde", m->r_tilde, z.r_tilde, "r - q T") ||
        !state_double_is(v, "padding", m->padding, z.padding, "tau padded, less tau") ||
        !state_nbuf(v, buffer_size(m->L), "E, Q_1 B .. Q_L B and L inputs: built = 1") ||
        !state_index(v, "hist_head", m->hist_head, m->L) ||
        !state_range(v, "next", m->next, 0, LONG_MAX - 1))
        return 0;
    size_t nEQ = (size_t)NX * NX + (size_t)NX * NU * (size_t)m->L;
    int compensated_mode = strcmp(d->string[STRING_SLOT[VR_MODE]], "compensated") == 0;
    return proposal_flag_ok(v, m->proposal_valid, m->at_sample) &&
           held_state_ok(v, d->boolean[VR_HELD_SAMPLE], m->y_held_valid, m->y_held, NX) &&
           state_finite(v, "held", m->held, NU) && proposal_ok(v) &&
           (m->padding > 0 ? state_finite(v, "pad_line", m->pad_line, NU)
                           : state_zeros(v, "pad_line", m->pad_line, NU, "padding = 0")) &&
           (m->padding > 0 || m->released ||
            state_refuse(v, "released = 0: must be 1 without padding")) &&
           state_finite(v, "history", v->buf + nEQ, (size_t)m->L * NU) &&
           (!compensated_mode || state_finite(v, "predictor", v->buf, nEQ)) &&
           (!state_in(v, StateStepComplete) || sample_time_ok(v));
}

int model_state_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!state_flag(v, "built", m->built) || !state_flag(v, "at_sample", m->at_sample) ||
        !state_flag(v, "released", m->released) ||
        !state_flag(v, "proposal_valid", m->proposal_valid) ||
        !state_flag(v, "y_held_valid", m->y_held_valid))
        return 0;
    return m->built ? built_ok(v) : unbuilt_ok(v);
}

int model_step(Instance *c, double t, double h) {
    ModelData *m = &c->d.m;
    if (check_step(c, t, h) != 0) return -1;
    if (check_inputs_finite(c, VR_Y, NX, t) != 0) return -1;
    if (m->at_sample) {  /* commit u_i: held, and the newest entry of the history */
        const double *u;
        if (proposed(c, &u) != 0) return -1;
        double committed[NU];
        memcpy(committed, u, NU * sizeof(double));
        if (m->padding > 0) {  /* the output before t_i + padding: u_{i-1} */
            memcpy(m->pad_line, m->held, NU * sizeof(double));
            m->released = 0;
        }
        memcpy(m->held, committed, NU * sizeof(double));
        double *hist = c->buf + (size_t)NX * NX + (size_t)NX * NU * (size_t)m->L;
        m->hist_head = (m->hist_head + m->L - 1) % m->L;
        memcpy(hist + (size_t)m->hist_head * NU, committed, NU * sizeof(double));
        m->next += 1;
        m->proposal_valid = 0;
    }
    if (!m->released) {  /* delaycomp.fmu.sampling.reaches_release */
        double T = c->d.real[VR_T], t_end = t + h;
        double release = c->d.t0 + (double)(m->next - 1) * T + m->padding;
        double tol = GRID_RTOL * T + fmax(4 * DBL_EPSILON * fabs(t_end), drift(t_end, h, c->d.t0));
        if (t_end > release + tol) {
            log_error(c, "step [%s, %s] is not allowed: it passes over the padded output's "
                      "instant %s; steps must end on t0 + iT + padding", num(t).s,
                      num(t_end).s, num(release).s);
            return -1;
        }
        m->released = t_end >= release - tol;
    }
    if (ends_on_sample(c, t, h, c->d.real[VR_T], m->next, &m->at_sample) != 0) return -1;
    if (held_keep(c->d.boolean[VR_HELD_SAMPLE], &c->d.real[VR_Y], NX, m->y_held,
                  &m->y_held_valid))
        m->proposal_valid = 0;  /* the held input is sampled at the next instant */
    return 0;
}
