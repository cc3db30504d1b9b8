/* What the FMI layers (fmi2.c, fmi3.c) and the models share, defined once (declared in native.h):
 * logging, the checks whose messages are the Python FMUs' own, the rule of a step on an
 * FMU's own grid (same_step) and the model buffer. Knows no model: it reads only the
 * generated variable table of config.h. */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "native.h"

/* ---- logging ------------------------------------------------------------------------ */
/* The message is formatted on the stack (nothing allocated; a message longer than the
 * buffer is cut and ends in "..."). */
static void vlog(Instance *c, int status, const char *category, const char *fmt,
                 va_list ap) {
    char text[TEXT_MAX + 2048];
    if (c->logger == NULL) return;
    int len = vsnprintf(text, sizeof text, fmt, ap);
    if (len < 0) return;
    if ((size_t)len >= sizeof text) memcpy(text + sizeof text - 4, "...", 4);
    c->logger(c, status, category, text);
}

void log_error(Instance *c, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog(c, STATUS_ERROR, "logStatusError", fmt, ap);
    va_end(ap);
}

void log_info(Instance *c, const char *fmt, ...) {
    if (!c->logging_on) return;
    va_list ap;
    va_start(ap, fmt);
    vlog(c, STATUS_OK, "logAll", fmt, ap);
    va_end(ap);
}

/* ---- checks shared by the models --------------------------------------------------- */
int check_real_parameters_finite(Instance *c) {
    for (size_t vr = 0; vr < NVR; vr++) {
        if (VAR_TYPE[vr] == 'r' && VAR_CAUSALITY[vr] == 'p' && !isfinite(c->d.real[vr])) {
            log_error(c, "%s = %s is not allowed: must be a finite number", VAR_NAME[vr],
                      num(c->d.real[vr]).s);
            return -1;
        }
    }
    return 0;
}

#if NSTRING > 0
void join_choices(const char *const *choices, int count, char *buf, size_t size) {
    buf[0] = '\0';
    for (int j = 0; j < count; j++) {
        strncat(buf, j ? ", " : "", size - strlen(buf) - 1);
        strncat(buf, choices[j], size - strlen(buf) - 1);
    }
}

int resolve_choice_index(Instance *c, const char *name, ValueRef vr_string,
                         ValueRef vr_index, const char *const *choices,
                         int count) {
    int k = c->d.integer[vr_index];
    if (k == 0) return 0;
    if (k < 1 || k > count) {
        char listed[STRING_MAX * 4];
        join_choices(choices, count, listed, sizeof listed);
        log_error(c, "%s_index = %d is not allowed: must be 0 (as %s says) or 1 .. %d (%s)",
                  name, k, name, count, listed);
        return -1;
    }
    char *value = c->d.string[STRING_SLOT[vr_string]];
    if (strcmp(value, STRING_START[STRING_SLOT[vr_string]]) != 0 &&
        strcmp(value, choices[k - 1]) != 0) {
        log_error(c, "%s = '%s' and %s_index = %d ('%s') disagree: set one of them", name,
                  value, name, k, choices[k - 1]);
        return -1;
    }
    snprintf(value, STRING_MAX, "%s", choices[k - 1]);
    return 0;
}
#endif

int check_control_finite(Instance *c, const double *u, const double *y, double t,
                         const char *why) {
    int finite = 1, y_finite = 1;
    for (size_t j = 0; j < NU; j++) finite &= isfinite(u[j]) != 0;
    for (size_t i = 0; i < NX; i++) y_finite &= isfinite(y[i]) != 0;
    if (finite || !y_finite) return 0;
    log_error(c, "control %s = %s at t = %s is not allowed: must be finite (%s)",
              OUTPUT_NAMES, vector_text(u, NU).s, num(t).s, why);
    return -1;
}

int check_step(Instance *c, double t, double h) {
    if (isfinite(t) && isfinite(h) && h > 0) return 0;
    log_error(c, "step size %s at t = %s is not allowed: must be a finite number > 0 from a "
              "finite time", num(h).s, num(t).s);
    return -1;
}

int check_inputs_finite(Instance *c, ValueRef first, size_t count, double t) {
    for (size_t k = 0; k < count; k++) {
        double v = c->d.real[first + k];
        if (!isfinite(v)) {
            log_error(c, "input %s = %s at t = %s is not allowed: must be a finite number",
                      VAR_NAME[first + k], num(v).s, num(t).s);
            return -1;
        }
    }
    return 0;
}

int same_step(double step, double h, double t) {
    return fabs(step - h) <= GRID_RTOL * h + 8 * DBL_EPSILON * fmax(fabs(t), fabs(t + step));
}

double drift(double t, double h, double t0) {
    double scale = fmax(fabs(t), fabs(t0));
    return fmin((fabs(t - t0) / h + 8) * DBL_EPSILON * scale, DRIFT_RTOL * h);
}

int grid_step(double t, double step, double h, double t0) {
    if (!(isfinite(t) && isfinite(step) && h > 0 && isfinite(t0))) return 0;
    double k = nearbyint((t - t0) / h), end = t + step;
    return fabs(t - (t0 + k * h)) <= GRID_RTOL * h + drift(t, h, t0) &&
           fabs(end - (t0 + (k + 1) * h)) <= GRID_RTOL * h + drift(end, h, t0);
}

int alloc_buf(Instance *c, size_t n) {
    free(c->buf);
    c->buf = NULL;
    c->nbuf = 0;
    if (n == 0) return 0;
    c->buf = calloc(n, sizeof(double));
    if (c->buf == NULL) {
        log_error(c, "out of memory: the model needs %lu numbers", (unsigned long)n);
        return -1;
    }
    c->nbuf = n;
    return 0;
}


/* ---- restored FMU states (StateView, native.h) ------------------------------------- */
int state_refuse(const StateView *v, const char *fmt, ...) {
    char text[TEXT_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    log_error(v->c, "%s: FMU state is not allowed: %s", v->fn, text);
    return 0;
}

int state_in(const StateView *v, int mask) { return (v->d->state & mask) != 0; }

int state_flag(const StateView *v, const char *name, int value) {
    return value == 0 || value == 1 || state_refuse(v, "%s = %d: must be 0 or 1", name, value);
}

int state_range(const StateView *v, const char *name, long value, long lo, long hi) {
    return (value >= lo && value <= hi) ||
           state_refuse(v, "%s = %ld: must be in %ld .. %ld", name, value, lo, hi);
}

int state_index(const StateView *v, const char *name, long value, long n) {
    if (n == 0)
        return value == 0 || state_refuse(v, "%s = %ld: must be 0 (an empty ring)", name, value);
    return (value >= 0 && value < n) ||
           state_refuse(v, "%s = %ld: must be in 0 .. %ld (a position in a ring of %ld)", name,
                        value, n - 1, n);
}

int state_long_is(const StateView *v, const char *name, long value, long expected,
                  const char *why) {
    return value == expected ||
           state_refuse(v, "%s = %ld: must be %ld (%s)", name, value, expected, why);
}

int state_double_is(const StateView *v, const char *name, double value, double expected,
                    const char *why) {
    if (value == expected && signbit(value) == signbit(expected)) return 1;
    return state_refuse(v, "%s = %s: must be %s (%s)", name, num(value).s, num(expected).s, why);
}

int state_positive(const StateView *v, const char *name, double value) {
    return (isfinite(value) && value > 0) ||
           state_refuse(v, "%s = %s: must be a finite number > 0", name, num(value).s);
}

int state_finite(const StateView *v, const char *name, const double *x, size_t n) {
    for (size_t k = 0; k < n; k++)
        if (!isfinite(x[k]))
            return state_refuse(v, "%s[%lu] = %s: must be a finite number", name,
                                (unsigned long)k, num(x[k]).s);
    return 1;
}

int state_zeros(const StateView *v, const char *name, const double *x, size_t n,
                const char *why) {
    for (size_t k = 0; k < n; k++)
        if (x[k] != 0.0 || signbit(x[k]))
            return state_refuse(v, "%s[%lu] = %s: must be 0.0 (%s)", name, (unsigned long)k,
                                num(x[k]).s, why);
    return 1;
}

int state_same(const StateView *v, const char *name, const double *x, const double *expected,
               size_t n, const char *why) {
    for (size_t k = 0; k < n; k++)
        if (memcmp(&x[k], &expected[k], sizeof(double)) != 0)
            return state_refuse(v, "%s[%lu] = %s: must be %s (%s)", name, (unsigned long)k,
                                num(x[k]).s, num(expected[k]).s, why);
    return 1;
}

int ends_on_sample(Instance *c, double t, double h, double T, long next, int *at_sample) {
    double t_end = t + h;
    double t_sample = c->d.t0 + (double)next * T;
    /* the grid's tolerance and the drift of a host's clock (t += h: drift) */
    double tol = GRID_RTOL * T + fmax(4 * DBL_EPSILON * fabs(t_end), drift(t_end, h, c->d.t0));
    if (t_end > t_sample + tol) {
        log_error(c, "step [%s, %s] is not allowed: it passes over the sampling instant %s; "
                  "steps must end on t0 + iT", num(t).s, num(t_end).s, num(t_sample).s);
        return -1;
    }
    *at_sample = fabs(t_end - t_sample) <= tol;
    return 0;
}

/* In state 'step complete' the time is where the last step left the sample counter: at the
 * sampling instant t0 + next T (at_sample), or before it (model_step's own test). */
int state_sampling_time(const StateView *v, double T, long next, int at_sample) {
    const Data *d = v->d;
    double t_sample = d->t0 + (double)next * T;
    double tol = 1e-9 * T + 4 * DBL_EPSILON * fabs(d->time);
    int at = fabs(d->time - t_sample) <= tol;
    /* between instants: after t_{next-1}, up to the host's round-off of its start */
    double slack = 1e-6 * fmax(fmax(T, fabs(d->time)), 1.0);
    if (at == at_sample && (at || (d->time < t_sample && d->time > t_sample - T - slack)))
        return 1;
    return state_refuse(v, "next = %ld: must put the sampling instant t0 + next T = %s %s the "
                        "time %s (at_sample = %d)", next, num(t_sample).s,
                        at_sample ? "at" : "within one period after", num(d->time).s,
                        at_sample);
}

int state_nbuf(const StateView *v, size_t need, const char *why) {
    return v->nbuf == need || state_refuse(v, "nbuf = %lu: must be %lu (%s)",
                                           (unsigned long)v->nbuf, (unsigned long)need, why);
}

/* The first message a check logs, kept (state_parameters). */
typedef struct {
    char text[TEXT_MAX];
} Captured;

static void capture(Instance *c, int status, const char *category, const char *text) {
    Captured *cap = c->log_env;
    (void)status;
    (void)category;
    if (cap->text[0] != '\0') return;
    snprintf(cap->text, sizeof cap->text, "%s", text);
}

/* A String that initialization would set from its _index twin, not set in the state. */
static int string_unresolved(const StateView *v, size_t slot) {
#if NSTRING > 0
    const char *name = "?";
    for (size_t vr = 0; vr < NVR; vr++)
        if (VAR_TYPE[vr] == 's' && STRING_SLOT[vr] == (int)slot) name = VAR_NAME[vr];
    return state_refuse(v, "%s = '%s': must be what its %s_index selects (initialization set "
                        "it)", name, v->d->string[slot], name);
#else
    (void)v;
    (void)slot;
    return 0;
#endif
}

Instance *state_scratch(const StateView *v, int with_buffer) {
    Instance *s = calloc(1, sizeof *s);  /* Data may be large: not on the stack */
    double *buf = with_buffer && v->nbuf ? malloc(v->nbuf * sizeof(double)) : NULL;
    if (s == NULL || (with_buffer && v->nbuf && buf == NULL)) {
        free(s);
        free(buf);
        log_error(v->c, "%s: out of memory", v->fn);
        return NULL;
    }
    s->d = *v->d;
    if (buf != NULL) memcpy(buf, v->buf, v->nbuf * sizeof(double));
    s->buf = buf;
    s->nbuf = buf != NULL ? v->nbuf : 0;
    s->instance_name = v->c->instance_name;  /* logger NULL: nothing is logged */
    return s;
}

void state_scratch_free(Instance *s) {
    if (s == NULL) return;
    free(s->buf);
    free(s);
}

int state_parameters(const StateView *v, int (*check)(Instance *c, void *out), void *out,
                     const char *why) {
    Instance *scratch = state_scratch(v, 0);
    if (scratch == NULL) return 0;
    Captured cap = {{0}};
    scratch->logger = capture;
    scratch->log_env = &cap;
    int rc = check(scratch, out), changed = -1;
#if NSTRING > 0
    for (size_t k = 0; k < NSTRING && rc == 0 && changed < 0; k++)
        if (strcmp(scratch->d.string[k], v->d->string[k]) != 0) changed = (int)k;
#endif
    state_scratch_free(scratch);
    if (rc != 0)
        return state_refuse(v, "%s (%s: its parameters must pass initialization's checks)",
                            cap.text[0] ? cap.text : "(no message)", why);
    return changed < 0 || string_unresolved(v, (size_t)changed);
}
