/* DelaycompChannel, native: n signals through a network channel on the grid t0 + k h.
 * The twin of fmus/delay/delaycomp_channel.py (delaycomp.maths.channel.ChannelLine): the
 * same variables, checks and messages, and the same numbers (the counter-based draws are
 * integer arithmetic; gamma's log, sqrt, cos and pow are libm's, as CPython's math calls
 * them, in the same order of operations).
 *
 * The buffer holds packets of PK_WIDTH doubles (channel.h): slot 0 the packet shown (when
 * has_current), slots 1 .. count those in flight in the order sent, zeros beyond. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "draws.h"  /* mix, draw, packet_draw, gamma_draw: shared with the batch */
#include "native.h"
#include "grid.h"   /* nearest_multiple, steps_up: the grid's rules */

enum { DIST_CONSTANT, DIST_UNIFORM, DIST_EXPONENTIAL, DIST_GAMMA, DIST_TRACE, NDIST };
enum { LOSS_NONE, LOSS_BERNOULLI, LOSS_GILBERT_ELLIOTT, NLOSS };
enum { POLICY_IN_ORDER, POLICY_DROP_STALE, POLICY_PLAYOUT, NPOLICY };

/* delaycomp.maths.channel.DISTRIBUTIONS, LOSS_MODELS, POLICIES */
static const char *const DISTRIBUTIONS[NDIST] = {"constant", "uniform", "exponential", "gamma",
                                                 "trace"};
static const char *const LOSS_MODELS[NLOSS] = {"none", "bernoulli", "gilbert_elliott"};
static const char *const POLICIES[NPOLICY] = {"in_order", "drop_stale", "playout"};

#define SEED_MAX 2147483647L                    /* delaycomp.maths.channel.SEED_MAX */
static const size_t N_TRACE = NTRACE;  /* a variable: loops over no trace compile cleanly */

/* The channel's parameters as the maths takes them (delaycomp.maths.channel.Channel). */
typedef struct {
    double delay, jitter, shape, max_delay, loss, p_gb, p_bg, loss_good, loss_bad, period;
    int dist, loss_model, policy;  /* -1: a String that is no choice */
    long seed;
    uint64_t key;
    uint64_t offset;  /* where a trace starts */
} Chan;

static int choice_of(const Instance *c, ValueRef vr, const char *const *choices, int count) {
    const char *value = c->d.string[STRING_SLOT[vr]];
    for (int k = 0; k < count; k++)
        if (strcmp(value, choices[k]) == 0) return k;
    return -1;
}

static void channel_of(const Instance *c, Chan *ch) {
    const double *r = c->d.real;
    ch->delay = r[VR_DELAY];
    ch->jitter = r[VR_JITTER];
    ch->shape = r[VR_SHAPE];
    ch->max_delay = r[VR_MAX_DELAY];
    ch->loss = r[VR_LOSS];
    ch->p_gb = r[VR_P_GB];
    ch->p_bg = r[VR_P_BG];
    ch->loss_good = r[VR_LOSS_GOOD];
    ch->loss_bad = r[VR_LOSS_BAD];
    ch->period = r[VR_PERIOD];
    ch->dist = choice_of(c, VR_DISTRIBUTION, DISTRIBUTIONS, NDIST);
    ch->loss_model = choice_of(c, VR_LOSS_MODEL, LOSS_MODELS, NLOSS);
    ch->policy = choice_of(c, VR_POLICY, POLICIES, NPOLICY);
    ch->seed = c->d.integer[VR_SEED];
    ch->key = mix((uint64_t)ch->seed ^ KEY_XOR);  /* a seed is checked >= 0 before use */
    ch->offset = ch->dist == DIST_TRACE && NTRACE > 0
                     ? (uint64_t)(draw(ch->key, 0) * (double)NTRACE) : 0;
}

/* packet j's delay [s] (NaN: lost in the trace) */
static double delay_of(const Instance *c, const Chan *ch, uint64_t j) {
    if (ch->dist == DIST_CONSTANT || (ch->dist != DIST_TRACE && ch->jitter == 0)) return ch->delay;
    if (ch->dist == DIST_UNIFORM)
        return ch->delay + ch->jitter * packet_draw(ch->key, j, DRAW_DELAY);
    if (ch->dist == DIST_EXPONENTIAL)
        return ch->delay - ch->jitter * log(1.0 - packet_draw(ch->key, j, DRAW_DELAY));
    if (ch->dist == DIST_GAMMA)
        return ch->delay + (ch->jitter / ch->shape) * gamma_draw(ch->key, j, ch->shape);
#if NTRACE > 0
    double d = c->d.real[VR_TRACE + (ValueRef)((ch->offset + j) % (uint64_t)NTRACE)];
    return d < 0 ? NAN : d;  /* a negative entry: a lost packet */
#else
    (void)c;
    return NAN;  /* refused at initialization: no trace */
#endif
}

/* packet j's draws (Channel.draw_fate): lost by the loss model or not, its delay in *d,
 * the Gilbert-Elliott chain's state before it in *bad, after it on return */
static int draw_fate(const Instance *c, const Chan *ch, uint64_t j, int *bad, double *d) {
    int lost = 0;
    if (ch->loss_model == LOSS_BERNOULLI) {
        lost = packet_draw(ch->key, j, DRAW_LOSS) < ch->loss;
    } else if (ch->loss_model == LOSS_GILBERT_ELLIOTT) {
        double u = packet_draw(ch->key, j, DRAW_STATE);
        *bad = *bad ? u >= ch->p_bg : u < ch->p_gb;
        lost = packet_draw(ch->key, j, DRAW_LOSS) < (*bad ? ch->loss_bad : ch->loss_good);
    }
    *d = delay_of(c, ch, j);
    return lost;
}

/* ChannelLine.fate: the steps until packet j is seen (lost: until its timeout, Q) */
static int fate(const Instance *c, const Chan *ch, uint64_t j, int *bad, double *q) {
    const ModelData *m = &c->d.m;
    double d;
    int lost = draw_fate(c, ch, j, bad, &d);
    if (lost || !(d / m->h <= (double)m->Q + 1.0)) {  /* NaN, or surely later than Q */
        *q = (double)m->Q;
        return 1;
    }
    *q = steps_up(d, m->h);
    if (*q > (double)m->Q) {
        *q = (double)m->Q;
        return 1;
    }
    return 0;
}

/* the largest delay a delivered packet has (Channel.bound) */
static double bound_of(const Instance *c, const Chan *ch) {
    if (ch->max_delay != 0) return ch->max_delay;
    if (ch->dist == DIST_UNIFORM) return ch->delay + ch->jitter;
    if (ch->dist == DIST_TRACE) {
        double most = NAN;
        for (size_t i = 0; i < N_TRACE; i++) {
            double d = c->d.real[VR_TRACE + i];
            if (d >= 0 && !(d <= most)) most = d;  /* the first finite, then the largest */
        }
        return isnan(most) ? ch->delay : most;
    }
    return ch->delay;
}

/* The checks of fmi2ExitInitializationMode, in the Python slave's order: 0, or -1 with
 * the refusal logged. */
static int parameters_ok(Instance *c) {
    if (resolve_choice_index(c, "distribution", VR_DISTRIBUTION, VR_DISTRIBUTION_INDEX,
                             DISTRIBUTIONS, NDIST) != 0 ||
        resolve_choice_index(c, "loss_model", VR_LOSS_MODEL, VR_LOSS_MODEL_INDEX, LOSS_MODELS,
                             NLOSS) != 0 ||
        resolve_choice_index(c, "policy", VR_POLICY, VR_POLICY_INDEX, POLICIES, NPOLICY) != 0)
        return -1;
    static const ValueRef reals[] = {VR_DELAY, VR_JITTER, VR_SHAPE, VR_MAX_DELAY, VR_LOSS,
                                     VR_P_GB, VR_P_BG, VR_LOSS_GOOD, VR_LOSS_BAD, VR_PERIOD};
    for (size_t i = 0; i < sizeof reals / sizeof reals[0]; i++) {
        double v = c->d.real[reals[i]];
        if (!isfinite(v)) {
            log_error(c, "%s = %s is not allowed: must be a finite number", VAR_NAME[reals[i]],
                      num(v).s);
            return -1;
        }
    }
    Chan ch;
    channel_of(c, &ch);
    if (ch.dist == DIST_TRACE && NTRACE == 0) {
        log_error(c, "distribution = 'trace' is not allowed: this channel FMU is built without "
                  "a trace (L = 0): build it with the trace's length L >= 1");
        return -1;
    }
    for (size_t i = 0; i < N_TRACE; i++) {
        double d = c->d.real[VR_TRACE + i];
        if (!isfinite(d)) {
            log_error(c, "trace[%lu] = %s is not allowed: must be a finite number",
                      (unsigned long)i + 1, num(d).s);
            return -1;
        }
        if (ch.dist == DIST_TRACE && d >= 0 && d < ch.delay) {
            log_error(c, "trace[%lu] = %s is not allowed: must be a delay >= delay = %s [s], or "
                      "negative (a lost packet)", (unsigned long)i + 1, num(d).s,
                      num(ch.delay).s);
            return -1;
        }
    }
    /* Channel.check */
    static const struct { ValueRef vr; const char *const *choices; int count; } named[] = {
        {VR_DISTRIBUTION, DISTRIBUTIONS, NDIST},
        {VR_LOSS_MODEL, LOSS_MODELS, NLOSS},
        {VR_POLICY, POLICIES, NPOLICY}};
    for (size_t s = 0; s < 3; s++) {
        if (choice_of(c, named[s].vr, named[s].choices, named[s].count) < 0) {
            char listed[STRING_MAX * 4];
            join_choices(named[s].choices, named[s].count, listed, sizeof listed);
            log_error(c, "%s = '%s' is not allowed: must be one of %s", VAR_NAME[named[s].vr],
                      c->d.string[STRING_SLOT[named[s].vr]], listed);
            return -1;
        }
    }
    static const ValueRef at_least_0[] = {VR_DELAY, VR_JITTER, VR_PERIOD};
    for (size_t i = 0; i < 3; i++) {
        double v = c->d.real[at_least_0[i]];
        if (!(v >= 0.0)) {
            log_error(c, "%s = %s is not allowed: must be a finite number >= 0.0",
                      VAR_NAME[at_least_0[i]], num(v).s);
            return -1;
        }
    }
    static const ValueRef probabilities[] = {VR_LOSS, VR_P_GB, VR_P_BG, VR_LOSS_GOOD,
                                             VR_LOSS_BAD};
    for (size_t i = 0; i < 5; i++) {
        double v = c->d.real[probabilities[i]];
        if (!(v >= 0.0 && v <= 1.0)) {
            log_error(c, "%s = %s is not allowed: must be a finite number >= 0.0 and <= 1.0",
                      VAR_NAME[probabilities[i]], num(v).s);
            return -1;
        }
    }
    if (!(ch.shape > 0)) {
        log_error(c, "shape = %s is not allowed: must be a finite number > 0", num(ch.shape).s);
        return -1;
    }
    if (ch.seed < 0 || ch.seed > SEED_MAX) {
        log_error(c, "seed = %ld is not allowed: must be an integer in 0 .. %ld", ch.seed,
                  SEED_MAX);
        return -1;
    }
    if (ch.max_delay != 0) {  /* 0: none (the distribution's largest delay) */
        if (!(ch.max_delay >= ch.delay)) {
            log_error(c, "max_delay = %s is not allowed: must be a finite number >= %s",
                      num(ch.max_delay).s, num(ch.delay).s);
            return -1;
        }
    } else if ((ch.dist == DIST_EXPONENTIAL || ch.dist == DIST_GAMMA) && ch.jitter > 0) {
        log_error(c, "max_delay is required for distribution = '%s': the timeout after which a "
                  "packet is lost (a finite number >= delay = %s)", DISTRIBUTIONS[ch.dist],
                  num(ch.delay).s);
        return -1;
    }
    for (size_t i = 0; i < NX; i++) {
        double v = c->d.real[VR_U0 + i];
        if (!isfinite(v)) {
            log_error(c, "u0[%lu] = %s is not allowed: must be a finite number",
                      (unsigned long)i + 1, num(v).s);
            return -1;
        }
    }
    return 0;
}

/* What the bound is, in a message (Channel.bound_name). */
static const char *bound_name(const Chan *ch) {
    if (ch->max_delay != 0) return "max_delay";
    if (ch->dist == DIST_UNIFORM && ch->jitter > 0) return "delay + jitter";
    if (ch->dist == DIST_TRACE) return "the trace's largest delay";
    return "delay";
}

/* ChannelLine's grid of step h: the packet period P and the timeout Q in steps (out[0],
 * out[1]); -1 with the refusal logged. */
static int line_sizes(Instance *c, const Chan *ch, double h, long *out) {
    double ratio = ch->period / h;
    if (!(ratio <= MAX_STEPS)) {
        log_error(c, "period = %s is not allowed: must be at most %.0f steps of the "
                  "communication step %s (it needs %.6g)", num(ch->period).s, MAX_STEPS,
                  num(h).s, ratio);
        return -1;
    }
    double P;
    if (!nearest_multiple(ch->period, h, &P)) {
        log_error(c, "period = %s is not allowed: must be a multiple of the communication step "
                  "%s", num(ch->period).s, num(h).s);
        return -1;
    }
    double bound = bound_of(c, ch), steps = bound / h;
    if (!(steps <= MAX_STEPS)) {
        log_error(c, "%s = %s is not allowed: must be at most %.0f steps of the communication "
                  "step %s (it needs %.6g)", bound_name(ch),
                  num(bound).s, MAX_STEPS, num(h).s, steps);
        return -1;
    }
    out[0] = P < 1 ? 1 : (long)P;
    out[1] = (long)steps_up(bound, h);
    return 0;
}

int model_setup(Instance *c) {
    if (parameters_ok(c) != 0) return -1;
    memset(&c->d.m, 0, sizeof c->d.m);
    return alloc_buf(c, 0);
}

/* This step's deliveries for the current input (ChannelLine._deliver): the packet shown
 * (NULL: the history), `fresh` (PK_WIDTH doubles) receiving the packet sent in this step.
 * With apply, the line takes them: the shown packet into slot 0, the packets still in
 * flight into slots 1 .., the chain's state. */
static const double *deliver(Instance *c, const Chan *ch, double *fresh, int apply) {
    ModelData *m = &c->d.m;
    const long long k = m->k;
    int bad = m->bad;
    const long stored = m->count;
    const int sends = k % m->P == 0;
    if (sends) {
        uint64_t j = (uint64_t)(k / m->P);
        double q;
        int lost = fate(c, ch, j, &bad, &q);
        if (ch->policy == POLICY_PLAYOUT) q = (double)m->Q;  /* at send time + the timeout */
        fresh[PK_SEQ] = (double)j;
        fresh[PK_SENT] = (double)k;
        fresh[PK_READY] = (double)k + q;
        fresh[PK_LOST] = lost ? 1.0 : 0.0;
        memcpy(fresh + PK_VALUES, &c->d.real[VR_U], NX * sizeof(double));
    }
    double *flight = c->buf + PK_WIDTH;
    const long pending = stored + sends;
    const double now = (double)k;
#define PENDING(i) ((i) < stored ? flight + (size_t)(i) * PK_WIDTH : fresh)
    const double *shown = m->has_current ? c->buf : NULL;
    long delivered = 0;  /* in order: the packets delivered, a prefix of those pending */
    if (ch->policy != POLICY_DROP_STALE) {  /* in order (play-out: the order sent) */
        for (; delivered < pending; delivered++) {
            const double *p = PENDING(delivered);
            if (p[PK_READY] > now) break;  /* it, and all after it, wait */
            if (p[PK_LOST] == 0.0) shown = p;
        }
    } else {  /* drop stale: the newest arrival wins, older and lost ones go */
        for (long i = 0; i < pending; i++) {
            const double *p = PENDING(i);
            if (p[PK_LOST] == 0.0 && p[PK_READY] <= now &&
                (shown == NULL || p[PK_SEQ] > shown[PK_SEQ]))
                shown = p;
        }
    }
    if (!apply) return shown;
    if (shown != NULL && shown != c->buf) {
        memcpy(c->buf, shown, PK_WIDTH * sizeof(double));
        m->has_current = 1;
    }
    long kept = 0;
    for (long i = 0; i < pending; i++) {
        const double *p = PENDING(i);
        int keep = ch->policy != POLICY_DROP_STALE
                       ? i >= delivered
                       : p[PK_LOST] == 0.0 && p[PK_READY] > now &&
                             (!m->has_current || p[PK_SEQ] > c->buf[PK_SEQ]);
        if (keep) {
            double *to = flight + (size_t)kept * PK_WIDTH;
            if (to != p) memmove(to, p, PK_WIDTH * sizeof(double));
            kept++;
        }
    }
#undef PENDING
    if (pending > kept)  /* the slots left behind are zeros again */
        memset(flight + (size_t)kept * PK_WIDTH, 0,
               (size_t)((stored > kept ? stored : kept) - kept) * PK_WIDTH * sizeof(double));
    m->count = kept;
    m->bad = bad;
    return c->buf;
}

int model_output(Instance *c, ValueRef vr, double *value) {
    const ModelData *m = &c->d.m;
    const double *u = &c->d.real[VR_U], *u0 = &c->d.real[VR_U0];
    int now = 0;  /* this step's input shown (before the first step) */
    double stamp;
    const double *shown = NULL;
    double fresh[PK_WIDTH];
    if (c->d.state & (StateInstantiated | StateInitializationMode)) {
        stamp = c->d.t0 - c->d.real[VR_DELAY];
    } else {
        Chan ch;
        channel_of(c, &ch);
        if (!m->has_line) {
            /* packet 0 is seen at once where it is not lost and has no delay (a play-out
             * buffer: where no packet has a delay) */
            int bad = 0;
            double d;
            now = !draw_fate(c, &ch, 0, &bad, &d) &&
                  (ch.policy == POLICY_PLAYOUT ? bound_of(c, &ch) == 0 : d == 0);
            stamp = now ? c->d.t0 : c->d.t0 - ch.delay;
        } else {
            shown = deliver(c, &ch, fresh, 0);
            if (shown != NULL) {
                stamp = c->d.t0 + shown[PK_SENT] * m->h;
            } else {  /* the history, which holds up to t0 */
                double s = (c->d.t0 + (double)m->k * m->h) - ch.delay;
                stamp = c->d.t0 < s ? c->d.t0 : s;
            }
        }
    }
    if (vr == VR_STAMP) {
        *value = stamp;
    } else {
        size_t i = vr - VR_Y;
        *value = shown != NULL ? shown[PK_VALUES + i] : now ? u[i] : u0[i];
    }
    return 0;
}

void model_input_set(Instance *c) { (void)c; }

int model_step(Instance *c, double t, double h) {
    ModelData *m = &c->d.m;
    if (check_step(c, t, h) != 0) return -1;
    Chan ch;
    channel_of(c, &ch);
    if (!m->has_line) {
        long sizes[2];
        if (line_sizes(c, &ch, h, sizes) != 0) return -1;
        long cap = sizes[1] / sizes[0] + 3;
        if (alloc_buf(c, (size_t)(1 + cap) * PK_WIDTH) != 0) return -1;
        memset(m, 0, sizeof *m);
        m->P = sizes[0];
        m->Q = sizes[1];
        m->cap = cap;
        m->h = h;
        m->has_line = 1;
    } else if (h <= ROUNDOFF_STEP_FRACTION * m->h) {
        return 0;  /* the master's round-off (delaycomp.fmu.slave.is_roundoff_step): nothing moves */
    } else if (!same_step(h, m->h, t) && !grid_step(t, h, m->h, c->d.t0)) {
        log_error(c, "step size %s is not allowed: this channel runs on a fixed communication "
                  "step, %s", num(h).s, num(m->h).s);
        return -1;
    }
    if (check_inputs_finite(c, VR_U, NX, t) != 0) return -1;
    double fresh[PK_WIDTH];
    deliver(c, &ch, fresh, 1);
    m->k += 1;
    return 0;
}

/* A restored line's checks: the parameters', then P and Q for its h (out: two longs). */
static int line_of(Instance *c, void *out) {
    if (parameters_ok(c) != 0) return -1;
    Chan ch;
    channel_of(c, &ch);
    return line_sizes(c, &ch, c->d.m.h, out);
}

static int no_line_ok(Instance *c, void *out) {
    (void)out;
    return parameters_ok(c);
}

static int whole(double x) { return x >= 0 && x <= 0x1p53 && x == floor(x); }

/* A packet of a restored state (the Python twin's _packet): sent at its send step before
 * step k, seen within the timeout, lost 0 or 1, its values finite. */
static int packet_ok(const StateView *v, const char *field, const double *p) {
    const ModelData *m = &v->d->m;
    char name[64];
    if (!whole(p[PK_SEQ]))
        return state_refuse(v, "%s.seq = %s: must be an integer >= 0", field, num(p[PK_SEQ]).s);
    if (p[PK_SENT] != p[PK_SEQ] * (double)m->P)
        return state_refuse(v, "%s.sent = %s: must be %s (seq P)", field, num(p[PK_SENT]).s,
                            num(p[PK_SEQ] * (double)m->P).s);
    if (!(p[PK_SENT] < (double)m->k))
        return state_refuse(v, "%s.sent = %s: must be a step before %lld", field,
                            num(p[PK_SENT]).s, m->k);
    if (!whole(p[PK_READY]) || p[PK_READY] < p[PK_SENT] ||
        p[PK_READY] > p[PK_SENT] + (double)m->Q)
        return state_refuse(v, "%s.ready = %s: must be an integer in %s .. %s", field,
                            num(p[PK_READY]).s, num(p[PK_SENT]).s,
                            num(p[PK_SENT] + (double)m->Q).s);
    if (p[PK_LOST] != 0.0 && p[PK_LOST] != 1.0)
        return state_refuse(v, "%s.lost = %s: must be 0.0 or 1.0", field, num(p[PK_LOST]).s);
    snprintf(name, sizeof name, "%s.values", field);
    return state_finite(v, name, p + PK_VALUES, NX);
}

/* The line (a shown packet and up to Q / P + 2 in flight, in the order sent) exists from
 * the first step on (has_line), its P and Q those of that step's h. */
int model_state_ok(const StateView *v) {
    const ModelData *m = &v->d->m;
    if (!state_flag(v, "has_line", m->has_line)) return 0;
    if (!m->has_line) {
        const char *why = "no channel line before the first step: has_line = 0";
        if (m->k != 0) return state_refuse(v, "k = %lld: must be 0 (%s)", m->k, why);
        return state_long_is(v, "P", m->P, 0, why) && state_long_is(v, "Q", m->Q, 0, why) &&
               state_long_is(v, "cap", m->cap, 0, why) &&
               state_long_is(v, "count", m->count, 0, why) &&
               state_long_is(v, "bad", m->bad, 0, why) &&
               state_long_is(v, "has_current", m->has_current, 0, why) &&
               state_double_is(v, "h", m->h, 0.0, why) && state_nbuf(v, 0, why) &&
               (!state_in(v, StateStepComplete) ||
                state_parameters(v, no_line_ok, NULL, "state 'step complete'"));
    }
    if (state_in(v, StateInstantiated | StateInitializationMode))
        return state_refuse(v, "has_line = 1: must be 0 before " FMI_FN("ExitInitializationMode"));
    long sizes[2] = {0, 0};
    if (!state_positive(v, "h", m->h) || !state_flag(v, "bad", m->bad) ||
        !state_flag(v, "has_current", m->has_current) ||
        !state_parameters(v, line_of, sizes, "has_line = 1") ||
        !state_long_is(v, "P", m->P, sizes[0], "period / h") ||
        !state_long_is(v, "Q", m->Q, sizes[1], "steps_up(the largest delay, h)") ||
        !state_long_is(v, "cap", m->cap, m->Q / m->P + 3, "Q / P + 3") ||
        !state_nbuf(v, (size_t)(1 + m->cap) * PK_WIDTH, "1 + cap packets of n + 4 numbers"))
        return 0;
    if (m->k < 0) return state_refuse(v, "k = %lld: must be >= 0", m->k);
    if (!state_range(v, "count", m->count, 0, m->Q / m->P + 2)) return 0;
    const double *slot = v->buf;
    if (m->has_current ? !packet_ok(v, "current", slot)
                       : !state_zeros(v, "current", slot, PK_WIDTH, "has_current = 0"))
        return 0;
    double last = m->has_current ? slot[PK_SEQ] : -1.0;
    for (long i = 0; i < m->cap; i++) {
        const double *p = slot + (size_t)(1 + i) * PK_WIDTH;
        char field[48];
        snprintf(field, sizeof field, "inflight[%ld]", i);
        if (i >= m->count) {
            if (!state_zeros(v, field, p, PK_WIDTH, "beyond count")) return 0;
            continue;
        }
        if (!packet_ok(v, field, p)) return 0;
        if (!(p[PK_SEQ] > last))
            return state_refuse(v, "%s.seq = %s: must be > %s (packets in the order sent, each "
                                "newer than the one shown)", field, num(p[PK_SEQ]).s,
                                num(last).s);
        last = p[PK_SEQ];
    }
    return 1;
}
