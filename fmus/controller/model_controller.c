/* DelaycompController_<model>, native: the predictor-based controller of a user model on
 * the base grid h = T/N, both families of delaycomp.maths.nlcontrol:
 *
 * - continuous input (Theorem 2.1): the controller's own copy z' = f(z, u) of the plant,
 *   u = k(t + tau, z) at each base tick, held for h; at each sampling instant t_i, i >= 1,
 *   z(t_i) = Phi(y_i, u on [t_i - r - tau, t_i));
 * - zero-order hold (Theorem 3.2): u_i = k(Phi(y_i, history)) held over each period, with
 *   tau padded up to the next multiple of T when pad = true (Remark 3.3(b)): the output
 *   goes through a delay line of the difference, and Phi predicts over the padded delay.
 *
 * Phi is the flow of the plant over the stored inputs of the window (the segments of equal
 * neighbours merged, oldest first, as delaycomp.maths.history.InputHistory hands them out):
 * predictor = closed composes the model's exact step (model.c's gen_step) segment by
 * segment, numerical solves each segment with ode.c (DOP853, rtol = atol = tolerance), none
 * is the sample itself. The twin of fmus/controller/delaycomp_model_controller.py: same
 * variables, checks, messages and timing, held_sample included. */
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "native.h"
#include "grid.h"  /* nearest_multiple, padded_delay: the grid's rules */
#include "held.h"  /* held_sample, as the other controllers */
#include "model.h"
#include "model_common.h"
#include "model_config.h"
#include "ode.h"

static const char *const MODE_CHOICES[] = {"continuous", "zoh"};
static const char *const PREDICTOR_CHOICES[] = {"closed", "numerical", "none"};
enum { PREDICT_CLOSED, PREDICT_NUMERICAL, PREDICT_NONE };

static int index_of(const char *value, const char *const *choices, int count) {
    for (int j = 0; j < count; j++)
        if (strcmp(value, choices[j]) == 0) return j;
    return -1;
}

/* Python's tuple equality of two inputs (so 0.0 == -0.0, and NaN equals nothing) */
static int same_input(const double *a, const double *b) {
    for (size_t j = 0; j < NU; j++)
        if (!(a[j] == b[j])) return 0;
    return 1;
}

static const char *string_of(const Instance *c, ValueRef vr) {
    return c->d.string[STRING_SLOT[vr]];
}

/* delaycomp.maths.grid.steps_of(value, h, name): base steps in value, 0 .. MAX_STEPS */
static int steps_of(Instance *c, double value, double h, const char *name, long *steps) {
    if (!(isfinite(h) && h > 0)) {
        log_error(c, "step size must be a finite number > 0, got %s", num(h).s);
        return -1;
    }
    if (!(isfinite(value) && value >= 0)) {
        log_error(c, "%s = %s is not allowed: must be a finite number >= 0", name,
                  num(value).s);
        return -1;
    }
    double need = value / h;
    if (!(need <= MAX_STEPS)) {
        log_error(c, "%s = %s is not allowed: must be at most %.0f steps of the base step "
                  "h = %s (it needs %.6g)", name, num(value).s, MAX_STEPS, num(h).s, need);
        return -1;
    }
    double k;
    if (!nearest_multiple(value, h, &k)) {
        log_error(c, "%s = %s is not allowed: must be a multiple of the base step h = %s",
                  name, num(value).s, num(h).s);
        return -1;
    }
    *steps = (long)k;
    return 0;
}

/* The buffers, in c->buf: the input history (W x NU, a ring), the padding line (D x NU,
 * a ring), ode.c's work, and scratch for two states. */
static double *history(Instance *c) { return c->buf; }
static double *pad_line(Instance *c) { return c->buf + (size_t)c->d.m.W * NU; }
static double *ode_work(Instance *c) { return pad_line(c) + (size_t)c->d.m.D * NU; }
#if MODEL_HAS_STEP
static double *scratch(Instance *c) { return ode_work(c) + ode_work_size(NX); }
#endif

static size_t buffer_size(long W, long D) {
    return (size_t)(W + D) * NU + ode_work_size(NX) + 2 * (size_t)NX;
}

static int check_finite(Instance *c, ValueRef vr) {
    double v = c->d.real[vr];
    if (isfinite(v)) return 0;
    log_error(c, "%s = %s is not allowed: must be a finite number", VAR_NAME[vr], num(v).s);
    return -1;
}

/* What initialization derives from the parameters (ModelData's configuration). */
typedef struct {
    int branch, zoh, predictor;
    long N, W, D;
    double h, tau_eff;
} Config;

/* The checks of fmi2ExitInitializationMode in the Python FMU's order (the Integer twins,
 * then _setup, then make_controller), part one: the Strings, the numbers, the branch. */
static int check_choices(Instance *c, Config *g) {
    const Data *d = &c->d;
    if (resolve_choice_index(c, "mode", VR_MODE, VR_MODE_INDEX, MODE_CHOICES, 2) != 0 ||
        resolve_choice_index(c, "predictor", VR_PREDICTOR, VR_PREDICTOR_INDEX,
                             PREDICTOR_CHOICES, 3) != 0 ||
        model_resolve_choices(c) != 0)
        return -1;
    if (check_finite(c, VR_T) || check_finite(c, VR_R) || check_finite(c, VR_TAU) ||
        check_finite(c, VR_TOL))
        return -1;
    for (size_t j = 0; j < NU; j++)
        if (check_finite(c, VR_U0 + j)) return -1;
    for (size_t i = 0; i < NX; i++)
        if (check_finite(c, VR_Z0 + i)) return -1;
    const char *mode = string_of(c, VR_MODE), *predictor = string_of(c, VR_PREDICTOR);
    g->zoh = index_of(mode, MODE_CHOICES, 2);
    if (g->zoh < 0) {
        log_error(c, "mode = '%s' is not allowed: must be one of continuous, zoh", mode);
        return -1;
    }
    double tol = d->real[VR_TOL];
    if (!(tol > 0 && tol < 1)) {
        log_error(c, "tolerance = %s is not allowed: must be in (0, 1)", num(tol).s);
        return -1;
    }
    if (model_check_numbers(c) != 0 || model_branch(c, &g->branch) != 0) return -1;
    g->predictor = index_of(predictor, PREDICTOR_CHOICES, 3);
    if (g->predictor < 0) {
        log_error(c, "predictor = '%s' is not allowed: must be one of closed, numerical, "
                  "none", predictor);
        return -1;
    }
    if (g->zoh != MODEL_ZOH) {
        log_error(c, "mode = '%s' is not allowed: model %s gives a %s feedback", mode,
                  MODEL_NAME, MODE_CHOICES[MODEL_ZOH]);
        return -1;
    }
    return 0;
}

/* Part two: T, r, tau, N, the predictor; N and the base step h. */
static int check_timing(Instance *c, Config *g) {
    const Data *d = &c->d;
    double T = d->real[VR_T], r = d->real[VR_R], tau = d->real[VR_TAU];
    if (!(T > 0)) {
        log_error(c, "T = %s is not allowed: must be > 0", num(T).s);
        return -1;
    }
    if (!(r >= 0)) {
        log_error(c, "r = %s is not allowed: must be >= 0", num(r).s);
        return -1;
    }
    if (!(tau >= 0)) {
        log_error(c, "tau = %s is not allowed: must be >= 0", num(tau).s);
        return -1;
    }
    int N = d->integer[VR_N];
    if (N < 1) {
        log_error(c, "N = %d is not allowed: must be a positive integer", N);
        return -1;
    }
    if (g->predictor == PREDICT_CLOSED && !MODEL_HAS_PREDICTOR) {
        log_error(c, "predictor = 'closed' is not allowed: model %s has no closed-form "
                  "predictor (use 'numerical')", MODEL_NAME);
        return -1;
    }
    g->N = N;
    g->h = T / N;
    return 0;
}

/* Part three: the window W and the padding D in base steps (tau_eff: tau padded). */
static int check_window(Instance *c, Config *g) {
    const Data *d = &c->d;
    double T = d->real[VR_T], r = d->real[VR_R], tau = d->real[VR_TAU], h = g->h;
    g->D = 0;
    g->tau_eff = tau;
    if (!g->zoh) return steps_of(c, r + tau, h, "r + tau", &g->W);
    g->tau_eff = padded_delay(tau, T);
    if (g->tau_eff != tau && !d->boolean[VR_PAD]) {
        log_error(c, "tau = %s is not allowed: zero-order hold needs a multiple l*T "
                  "(l >= 0) of T = %s; pad = true pads it up to %s (Remark 3.3(b))",
                  num(tau).s, num(T).s, num(g->tau_eff).s);  /* delaycomp.maths.grid.periods */
        return -1;
    }
    long q;
    if (steps_of(c, g->tau_eff - tau, h, "padding", &g->D) != 0 ||
        steps_of(c, r, h, "r", &q) != 0)
        return -1;
    double w = (double)q + nearbyint(g->tau_eff / h);
    if (!(w <= MAX_STEPS)) {
        log_error(c, "r + tau = %s is not allowed: must be at most %.0f base steps of "
                  "h = %s (it needs %.6g)", num(r + g->tau_eff).s, MAX_STEPS, num(h).s, w);
        return -1;
    }
    g->W = (long)w;
    if (g->D > 0)
        log_info(c, "input delay padded from tau = %s to %s: the controller delays its "
                 "output by %s s", num(tau).s, num(g->tau_eff).s, num(g->tau_eff - tau).s);
    return 0;
}

/* Every check of fmi2ExitInitializationMode; *out (a Config) what they give. */
static int configure(Instance *c, void *out) {
    Config *g = out;
    return check_choices(c, g) != 0 || check_timing(c, g) != 0 || check_window(c, g) != 0
               ? -1 : 0;
}

int model_setup(Instance *c) {
    Data *d = &c->d;
    ModelData *m = &d->m;
    Config g;
    m->built = 0;
    if (alloc_buf(c, 0) != 0 || configure(c, &g) != 0) return -1;
    if (alloc_buf(c, buffer_size(g.W, g.D)) != 0) return -1;
    m->branch = g.branch;
    m->zoh = g.zoh;
    m->predictor = g.predictor;
    m->N = g.N;
    m->h = g.h;
    m->tau_eff = g.tau_eff;
    m->W = g.W;
    m->D = g.D;
    const double *u0 = &d->real[VR_U0];
    for (long k = 0; k < g.W; k++) memcpy(history(c) + (size_t)k * NU, u0, NU * sizeof(double));
    for (long k = 0; k < g.D; k++) memcpy(pad_line(c) + (size_t)k * NU, u0, NU * sizeof(double));
    memcpy(m->z, &d->real[VR_Z0], NX * sizeof(double));
    memcpy(m->held, u0, NU * sizeof(double));
    m->k_tick = 0;
    m->hist_head = 0;
    m->pad_head = 0;
    m->cache_valid = 0;
    m->y_held_valid = 0;
    m->built = 1;
    return 0;
}

/* A failed ODE solve: where and why, as delaycomp.maths.predictors.IntegrationError says it. */
typedef struct {
    double elapsed;
    const double *u;
    const char *reason;
} SolveFailure;

/* the message is logged with log_error's format: nothing allocated */
#define FAILURE_FORMAT "ODE solve failed %.6g s into a window (input %s): %s"
#define FAILURE_ARGS(f) (f)->elapsed, vector_text((f)->u, NU).s, (f)->reason

/* x <- the flow of x' = f(x, u) over `duration` (u held): the exact step, else DOP853.
 * 0, or -1 with *why filled. */
static int model_flow(Instance *c, double *x, const double *u, double duration, const double *p,
                int exact, long *budget, const char **why) {
    if (exact) {
#if MODEL_HAS_STEP
        double *next = scratch(c) + NX;
        if (gen_step(c->d.m.branch, x, u, duration, p, next) != 0) {
            *why = "the model's step failed";
            return -1;
        }
        memcpy(x, next, NX * sizeof(double));
        return 0;
#endif
    }
    if (duration <= 0) return 0;
    ModelRhs ctx = {c->d.m.branch, u, p};
    double u_size = 0.0;
    for (size_t j = 0; j < NU; j++) u_size = fmax(u_size, fabs(u[j]));
    double tol = c->d.real[VR_TOL];
    if (*budget < 1) {  /* the budget of the whole window is spent (model_common.h) */
        *why = ode_reason(ODE_MAX_STEPS);
        return -1;
    }
    OdeReport rep;
    int code = ode_solve(model_rhs, &ctx, NX, x, duration, tol, tol, *budget, u_size,
                         ode_work(c), &rep);
    *budget -= rep.steps;
    if (code != ODE_OK) {
        *why = rep.reason;
        return -1;
    }
    return 0;
}

/* x <- Phi(y, history): the flow over the window's segments, oldest first, equal
 * neighbours merged (InputHistory.segments). 0, or -1 with *fail filled. */
static int predict(Instance *c, const double *y, const double *p, double *x,
                   SolveFailure *fail) {
    const ModelData *m = &c->d.m;
    memcpy(x, y, NX * sizeof(double));
    if (m->predictor == PREDICT_NONE) return 0;
    const double *hist = history(c);
    double elapsed = 0.0;
    long budget = MAX_ODE_STEPS;  /* DOP853 steps of the whole window (model_common.h) */
    for (long j = 0; j < m->W;) {
        const double *u = hist + (size_t)((m->hist_head + j) % m->W) * NU;
        long count = 1;
        while (j + count < m->W &&
               same_input(u, hist + (size_t)((m->hist_head + j + count) % m->W) * NU))
            count++;
        double duration = (double)count * m->h;
        const char *why = "";
        if (model_flow(c, x, u, duration, p, m->predictor == PREDICT_CLOSED, &budget,
                       &why) != 0) {
            fail->elapsed = elapsed;
            fail->u = u;
            fail->reason = why;
            return -1;
        }
        elapsed += duration;
        j += count;
    }
    return 0;
}

/* u = k(x) (zero-order hold) or k(t, x) (continuous input), as the model gives it */
static void feedback(int branch, double t, const double *x, const double *p, double *u) {
#if MODEL_ZOH
    (void)t;
    gen_k(branch, x, p, u);
#else
    gen_k(branch, t, x, p, u);
#endif
}

static double sample_time(const Instance *c) {  /* t_k = t0 + k h, as the Python FMU */
    return c->d.t0 + (double)c->d.m.k_tick * c->d.m.h;
}

/* The sample the controller reads now: the input, or (held_sample) the held one. */
static const double *sample(const Instance *c) {
    const ModelData *m = &c->d.m;
    return held_sample(c->d.boolean[VR_HELD_SAMPLE], m->y_held_valid, m->y_held,
                       &c->d.real[VR_Y]);
}

/* The evaluation at the current tick of ContinuousController._evaluate (z after a reset,
 * u = k(t + tau, z)) or ZOHModelController._held_now (u), memoized until the input or
 * the tick changes. 0, or -1 with *fail filled (the prediction's ODE solve failed). */
static int evaluate(Instance *c, SolveFailure *fail) {
    ModelData *m = &c->d.m;
    if (m->cache_valid) return 0;
    int at_sample = m->k_tick % m->N == 0;
    double p[MODEL_NP > 0 ? MODEL_NP : 1];
    model_parameters(c, p);
    if (m->zoh) {
        if (!at_sample) {
            memcpy(m->cache_u, m->held, NU * sizeof(double));
        } else {
            if (predict(c, sample(c), p, m->cache_z, fail) != 0) return -1;
            feedback(m->branch, 0.0, m->cache_z, p, m->cache_u);
        }
    } else {
        if (at_sample && m->k_tick > 0) {
            if (predict(c, sample(c), p, m->cache_z, fail) != 0) return -1;
        } else {
            memcpy(m->cache_z, m->z, NX * sizeof(double));
        }
        double T = c->d.real[VR_T];
        double t = c->d.t0 + (double)(m->k_tick / m->N) * T + (double)(m->k_tick % m->N) * m->h;
        feedback(m->branch, t + c->d.real[VR_TAU], m->cache_z, p, m->cache_u);
    }
    m->cache_valid = 1;
    return 0;
}

/* The control now: u0 before initialization, NaN after a fault; -1 (logged) when the
 * prediction fails or the control is not finite for a finite measurement. */
static int output(Instance *c, const double **u) {
    ModelData *m = &c->d.m;
    if (!m->built) {
        *u = &c->d.real[VR_U0];
        return 0;
    }
    if (c->d.state == StateError) {  /* the Python FMU's NaN after a refusal */
        *u = NULL;
        return 0;
    }
    SolveFailure fail;
    if (evaluate(c, &fail) != 0) {
        log_error(c, "computing the control at t = %s failed: IntegrationError: "
                  FAILURE_FORMAT, num(sample_time(c)).s, FAILURE_ARGS(&fail));
        *u = NULL;
        return -1;
    }
    const double *value = m->cache_u;
    if (m->zoh && m->D > 0) value = pad_line(c) + (size_t)m->pad_head * NU;
    if (check_control_finite(c, value, &c->d.real[VR_Y], sample_time(c),
                             "the predictor or the feedback diverged") != 0) {
        *u = NULL;
        return -1;
    }
    *u = value;
    return 0;
}

int model_output(Instance *c, ValueRef vr, double *value) {
    const double *u;
    int rc = output(c, &u);
    *value = u != NULL ? u[vr - VR_UOUT] : NAN;
    return rc;
}

void model_input_set(Instance *c) { c->d.m.cache_valid = 0; }

/* ContinuousController.advance / ZOHModelController.advance: commit the tick. */
static int advance(Instance *c, double t) {
    ModelData *m = &c->d.m;
    SolveFailure fail = {0.0, NULL, ""};
    int failed = evaluate(c, &fail) != 0;
    if (!failed && !m->zoh) {
        double p[MODEL_NP > 0 ? MODEL_NP : 1];
        model_parameters(c, p);
        memcpy(m->z, m->cache_z, NX * sizeof(double));
        const char *why = "";
        long budget = MAX_ODE_STEPS;
        if (model_flow(c, m->z, m->cache_u, m->h, p, MODEL_HAS_STEP, &budget, &why) != 0) {
            fail = (SolveFailure){0.0, m->cache_u, why};
            failed = 1;
        }
    }
    if (failed) {
        log_error(c, "predictor ODE solve at t = %s failed: " FAILURE_FORMAT, num(t).s,
                  FAILURE_ARGS(&fail));
        return -1;
    }
    const double *u = m->cache_u;
    if (m->W > 0) {  /* the newest value replaces the oldest */
        memcpy(history(c) + (size_t)m->hist_head * NU, u, NU * sizeof(double));
        m->hist_head = (m->hist_head + 1) % m->W;
    }
    if (m->zoh) {
        memcpy(m->held, u, NU * sizeof(double));
        if (m->D > 0) {
            memcpy(pad_line(c) + (size_t)m->pad_head * NU, u, NU * sizeof(double));
            m->pad_head = (m->pad_head + 1) % m->D;
        }
    }
    m->k_tick += 1;
    m->cache_valid = 0;
    return 0;
}

int model_step(Instance *c, double t, double hs) {
    ModelData *m = &c->d.m;
    if (check_step(c, t, hs) != 0) return -1;
    double T = c->d.real[VR_T];
    double expected = sample_time(c);
    double slack = 1e-9 * fmax(T, fabs(t));
    /* the master's round-off (delaycomp.fmu.slave.ROUNDOFF_STEP_FRACTION): nothing moves */
    if (hs <= ROUNDOFF_STEP_FRACTION * m->h && fabs(t + hs - expected) <= slack) return 0;
    /* the step is h up to the round-off of the host's times (same_step) or ends on the grid
     * up to a host's drift (t += h: grid_step); it starts where this controller stands */
    int one_step = same_step(hs, m->h, t) || grid_step(t, hs, m->h, c->d.t0);
    if (!one_step || fabs(t - expected) > slack) {
        log_error(c, "step (%s, %s) is not allowed: this controller steps from %s by exactly "
                  "T/N = %s", num(t).s, num(hs).s, num(expected).s, num(m->h).s);
        return -1;
    }
    if (check_inputs_finite(c, VR_Y, NX, t) != 0) return -1;
    if (advance(c, t) != 0) return -1;
    /* advance left no evaluation cached: the held input needs no invalidation here */
    held_keep(c->d.boolean[VR_HELD_SAMPLE], &c->d.real[VR_Y], NX, m->y_held, &m->y_held_valid);
    return 0;
}

/* ---- a restored FMU state ------------------------------------------------------------ */
/* An unbuilt controller (before initialization, or refused there) holds nothing: no
 * buffer, every field 0 (the branch in range: an older build kept it from a refusal). */
static int unbuilt_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    const char *why = "an unbuilt controller: built = 0";
    if (state_in(v, StateStepComplete))
        return state_refuse(v, "built = 0: must be 1 in state 'step complete' (the controller "
                            "is built at " FMI_FN("ExitInitializationMode") ")");
    return state_nbuf(v, 0, "no input history and no padding line: built = 0") &&
           state_range(v, "branch", m->branch, 0, MODEL_NBRANCH - 1) &&
           state_long_is(v, "zoh", m->zoh, 0, why) &&
           state_long_is(v, "predictor", m->predictor, 0, why) &&
           state_long_is(v, "N", m->N, 0, why) && state_long_is(v, "W", m->W, 0, why) &&
           state_long_is(v, "D", m->D, 0, why) && state_long_is(v, "k_tick", m->k_tick, 0, why) &&
           state_long_is(v, "hist_head", m->hist_head, 0, why) &&
           state_long_is(v, "pad_head", m->pad_head, 0, why) &&
           state_long_is(v, "cache_valid", m->cache_valid, 0, why) &&
           state_long_is(v, "y_held_valid", m->y_held_valid, 0, why) &&
           state_double_is(v, "h", m->h, 0.0, why) &&
           state_double_is(v, "tau_eff", m->tau_eff, 0.0, why) &&
           state_zeros(v, "z", m->z, NX, why) && state_zeros(v, "held", m->held, NU, why) &&
           state_zeros(v, "cache_z", m->cache_z, NX, why) &&
           state_zeros(v, "cache_u", m->cache_u, NU, why) &&
           state_zeros(v, "y_held", m->y_held, NX, why);
}

/* cache_valid = 1: the cache is the evaluation of the current tick (recomputed: the same
 * arithmetic gives the same bits; cache_z is left as it was where zero-order hold holds
 * its output between sampling instants). */
static int cache_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!m->cache_valid) return 1;
    Instance *s = state_scratch(v, 1);
    if (s == NULL) return 0;
    s->d.m.cache_valid = 0;
    SolveFailure fail;
    int failed = evaluate(s, &fail) != 0, z_kept = m->zoh && m->k_tick % m->N != 0;
    double u[NU], z[NX];
    memcpy(u, s->d.m.cache_u, sizeof u);
    memcpy(z, s->d.m.cache_z, sizeof z);
    state_scratch_free(s);
    if (failed)
        return state_refuse(v, "cache_valid = 1: must be 0 (evaluating the current tick fails: "
                            FAILURE_FORMAT ")", FAILURE_ARGS(&fail));
    if (memcmp(u, m->cache_u, sizeof u) != 0)
        return state_refuse(v, "cache_u = %s: must be %s, the evaluation of the current tick "
                            "(cache_valid = 1)", vector_text(m->cache_u, NU).s,
                            vector_text(u, NU).s);
    if (!z_kept && memcmp(z, m->cache_z, sizeof z) != 0)
        return state_refuse(v, "cache_z = %s: must be %s, the evaluation of the current tick "
                            "(cache_valid = 1)", vector_text(m->cache_z, NX).s,
                            vector_text(z, NX).s);
    return 1;
}

/* A built controller's configuration: what its parameters (which initialization accepted)
 * give, and its buffer of that size. */
static int configuration_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    Config g = {0, 0, 0, 0, 0, 0, 0.0, 0.0};
    return state_parameters(v, configure, &g, "built = 1") &&
           state_long_is(v, "branch", m->branch, g.branch, "its String parameters' branch") &&
           state_long_is(v, "zoh", m->zoh, g.zoh, "mode") &&
           state_long_is(v, "predictor", m->predictor, g.predictor, "predictor") &&
           state_long_is(v, "N", m->N, g.N, "the parameter N") &&
           state_double_is(v, "h", m->h, g.h, "T / N") &&
           state_double_is(v, "tau_eff", m->tau_eff, g.tau_eff, "tau, padded") &&
           state_long_is(v, "W", m->W, g.W, "the window r + tau in base steps") &&
           state_long_is(v, "D", m->D, g.D, "the padding in base steps") &&
           state_nbuf(v, buffer_size(m->W, m->D), "W + D inputs, the ODE solver's work "
                      "memory and two states: built = 1");
}

/* A built controller: its configuration, the ring positions, the tick counter at the
 * time (state 'step complete'), the held input. */
static int built_ok(const StateView *v) {
    const Data *d = v->d;
    const ModelData *m = &d->m;
    if (!configuration_ok(v) || !state_index(v, "hist_head", m->hist_head, m->W) ||
        !state_index(v, "pad_head", m->pad_head, m->D) ||
        !state_range(v, "k_tick", m->k_tick, 0, LONG_MAX - 1))
        return 0;
    double T = d->real[VR_T], t_tick = d->t0 + (double)m->k_tick * m->h;
    double tol = 1e-8 * fmax(fmax(T, fabs(d->time)), fabs(d->t0));
    if (state_in(v, StateStepComplete) && !(fabs(d->time - t_tick) <= tol))
        return state_refuse(v, "k_tick = %ld: must give t0 + k_tick h = %s, the time %s",
                            m->k_tick, num(t_tick).s, num(d->time).s);
    const char *u0 = "u0: continuous input holds no control", *z0 = "z0: zero-order hold "
                     "keeps no copy of the plant";
    return held_state_ok(v, d->boolean[VR_HELD_SAMPLE], m->y_held_valid, m->y_held, NX) &&
           (m->zoh ? state_same(v, "z", m->z, &d->real[VR_Z0], NX, z0)
                   : state_same(v, "held", m->held, &d->real[VR_U0], NU, u0)) &&
           cache_ok(v);
}

int model_state_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!state_flag(v, "built", m->built) || !state_flag(v, "zoh", m->zoh) ||
        !state_flag(v, "cache_valid", m->cache_valid) ||
        !state_flag(v, "y_held_valid", m->y_held_valid))
        return 0;
    return m->built ? built_ok(v) : unbuilt_ok(v);
}
