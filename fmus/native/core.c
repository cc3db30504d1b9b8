/* The version-free core of the FMI layers of the delaycomp native FMUs (declared in
 * core.h): the state machine's checks, start values, initialization and steps through the
 * model, and the FMU state with every buffer and its serialization to a self-checking byte
 * string. fmi2.c and fmi3.c are thin faces on it: a restored or serialized state, a step, a
 * refusal behave alike in both versions; the messages name the caller's FMI function.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core.h"

const char *state_name(FsmState s) {
    switch (s) {
    case StateInstantiated: return "instantiated";
    case StateInitializationMode: return "initialization mode";
    case StateStepComplete: return FMI_MAJOR == 3 ? "step mode" : "step complete";
    case StateTerminated: return "terminated";
    case StateError: return "error";
    case StateConfigurationMode: return "configuration mode";
    case StateEventMode: return "event mode";
    }
    return "unknown";
}

int allowed(Instance *c, const char *fn, int mask) {
    if (c == NULL) return 0;
    if (c->d.state & mask) return 1;
    log_error(c, "%s is not allowed in state '%s' (" FMI_VERSION_TEXT " co-simulation state "
              "machine)", fn, state_name(c->d.state));
    return 0;
}

int model_fault(Instance *c) {
    c->d.state = StateError;
    return STATUS_ERROR;
}

static void set_start_values(Instance *c) {
    memset(&c->d, 0, sizeof c->d);
    for (size_t vr = 0; vr < NVR; vr++) {
        c->d.real[vr] = REAL_START[vr];
        c->d.boolean[vr] = BOOLEAN_START[vr];
        c->d.integer[vr] = INTEGER_START[vr];
    }
#if NSTRING > 0
    for (size_t k = 0; k < NSTRING; k++)
        snprintf(c->d.string[k], STRING_MAX, "%s", STRING_START[k]);
#endif
    c->d.state = StateInstantiated;
}

Instance *core_new(size_t size, const char *name) {
    Instance *c = calloc(1, size);
    if (c == NULL) return NULL;
    c->instance_name = malloc(strlen(name) + 1);
    if (c->instance_name == NULL) {
        free(c);
        return NULL;
    }
    strcpy(c->instance_name, name);
    set_start_values(c);
    return c;
}

void core_free(Instance *c) {
    if (c == NULL) return;
    free(c->buf);
    free(c->instance_name);
    free(c);
}

void core_reset(Instance *c) {
    free(c->buf);
    c->buf = NULL;
    c->nbuf = 0;
    set_start_values(c);
}

int core_exit_initialization(Instance *c, const char *fn) {
    if (!allowed(c, fn, StateInitializationMode)) return STATUS_ERROR;
    c->d.time = c->d.t0;
    if (model_setup(c) != 0) return model_fault(c);
    c->d.state = StateStepComplete;
    return STATUS_OK;
}

/* Also after a fault (the error state): hosts end every instance of a failed run with
 * Terminate, and the Python FMUs accept it. Refused, it broke OMSimulator's command
 * line: its terminate pass stopped at the refusing instance after it had freed the ones
 * before, and its model's destructor called fmi2Terminate and fmi2FreeInstance on those
 * again (a use-after-free and a double free in the host, seen with valgrind). */
int core_terminate(Instance *c, const char *fn) {
    if (!allowed(c, fn, StateStepComplete | StateError | StateEventMode)) return STATUS_ERROR;
    c->d.state = StateTerminated;
    return STATUS_OK;
}

int core_get_real(Instance *c, ValueRef slot, double *value) {
    if (VAR_CAUSALITY[slot] == 'o') {
        if (model_output(c, slot, value) != 0) return model_fault(c);
    } else {
        *value = c->d.real[slot];
    }
    return STATUS_OK;
}

int core_string_ok(Instance *c, const char *name, const char *value) {
    if (value == NULL || strlen(value) >= STRING_MAX) {
        log_error(c, "%s is not allowed: must be a string of at most %d characters", name,
                  STRING_MAX - 1);
        return 0;
    }
    return 1;
}

int core_do_step(Instance *c, double t, double h) {
    double last = c->d.time;
    /* the Python FMUs' rule (delaycomp.fmu.slave.TableSlave._step_refusal): libcosim keeps
     * time in integer nanoseconds, about 1e-12 relative off the sum of the steps; a jump
     * or a step back is many orders larger */
    if (isfinite(t) && isfinite(h) && h > 0 &&
        fabs(t - last) > 1e-9 * fmax(fmax(fabs(last), h), 1.0)) {
        log_error(c, "step from t = %s is not allowed: time %s; the last step ended at %s (a "
                  "step must start where the last one ended)", num(t).s,
                  t < last ? "goes backwards" : "jumps ahead", num(last).s);
        return model_fault(c);
    }
    if (model_step(c, t, h) != 0) return model_fault(c);
    c->d.time = t + h;
    return STATUS_OK;
}

/* ---- FMU state ------------------------------------------------------------------------ */
#define MAGIC "DCNATIV1"

typedef struct {
    char magic[8];
    char token[64];
    uint64_t data_size;
    uint64_t nbuf;
} Header;

typedef struct {
    Header h;
    Data d;
    double buf[];
} Snapshot;

static Snapshot *snapshot_new(size_t nbuf) {
    Snapshot *s = calloc(1, sizeof(Snapshot) + nbuf * sizeof(double));
    if (s == NULL) return NULL;
    memcpy(s->h.magic, MAGIC, 8);
    snprintf(s->h.token, sizeof s->h.token, "%s", INSTANTIATION_TOKEN);
    s->h.data_size = sizeof(Data);
    s->h.nbuf = nbuf;
    return s;
}

int core_get_state(Instance *c, const char *fn, void **state) {
    if (!allowed(c, fn, MASK_STATE)) return STATUS_ERROR;
    if (state == NULL) return STATUS_ERROR;
    Snapshot *s = *state;
    if (s == NULL || s->h.nbuf != c->nbuf) {  /* a new snapshot, or one of another size */
        Snapshot *fresh = snapshot_new(c->nbuf);
        if (fresh == NULL) {
            log_error(c, "%s: out of memory", fn);
            return STATUS_ERROR;
        }
        free(s);
        s = fresh;
    }
    s->d = c->d;
    if (c->nbuf) memcpy(s->buf, c->buf, c->nbuf * sizeof(double));
    *state = s;
    return STATUS_OK;
}

static int data_ok(const StateView *v);

/* A snapshot to install: this FMU's (magic, instantiation token, sizeof(Data)), and its
 * data and buffer checked in full (data_ok, model_state_ok); else 0 and the refusal
 * logged. */
/* The clock's schedule against the time (CLOCKED builds), once initialization has ended:
 * the next tick is the first one at or after the time, or the one after a tick at the time
 * that was handled, t0 + (tick_next - 1) T <= time <= t0 + tick_next T, each end within the
 * grid's tolerance (fmi3.c's at_next_tick). Another index would let the host step on
 * without the ticks, or refuse every tick it sets. */
static int clock_ok(const StateView *v) {
#if CLOCKED
    const Data *d = v->d;
    if (!(d->state & (StateStepComplete | StateEventMode))) return 1;
    double T = d->real[CLOCK_INTERVAL_SLOT];
    double next = d->t0 + (double)d->tick_next * T;
    double tol = GRID_RTOL * T + drift(d->time, T * 1e-3, d->t0);
    if (!(d->time <= next + tol && d->time >= next - T - tol))
        return state_refuse(v, "tick_next = %ld: must be the index i of the clock's next tick "
                            "t0 + i T at or after time = %s (t0 = %s, T = %s)", d->tick_next,
                            num(d->time).s, num(d->t0).s, num(T).s);
#else
    (void)v;
#endif
    return 1;
}

static int snapshot_valid(Instance *c, const Snapshot *s, const char *fn) {
    if (memcmp(s->h.magic, MAGIC, 8) != 0 || strcmp(s->h.token, INSTANTIATION_TOKEN) != 0) {
        log_error(c, "%s: FMU state is not allowed: it is not a consistent state of this FMU "
                  "(%s)", fn, INSTANTIATION_TOKEN);
        return 0;
    }
    if (s->h.data_size != sizeof(Data)) {
        log_error(c, "%s: FMU state is not allowed: data_size = %lu: must be %lu (it is not a "
                  "state of this FMU's build)", fn, (unsigned long)s->h.data_size,
                  (unsigned long)sizeof(Data));
        return 0;
    }
    StateView v = {c, fn, &s->d, s->h.nbuf ? s->buf : NULL, (size_t)s->h.nbuf};
    return data_ok(&v) && model_state_ok(&v) && clock_ok(&v);
}

int core_set_state(Instance *c, const char *fn, const void *state) {
    if (!allowed(c, fn, MASK_STATE)) return STATUS_ERROR;
    const Snapshot *s = state;
    if (s == NULL) {
        log_error(c, "%s: FMU state is not allowed: NULL", fn);
        return STATUS_ERROR;
    }
    if (!snapshot_valid(c, s, fn)) return STATUS_ERROR;
    double *buf = NULL;
    if (s->h.nbuf) {
        buf = malloc((size_t)s->h.nbuf * sizeof(double));
        if (buf == NULL) {
            log_error(c, "%s: out of memory", fn);
            return STATUS_ERROR;
        }
        memcpy(buf, s->buf, (size_t)s->h.nbuf * sizeof(double));
    }
    free(c->buf);
    c->buf = buf;
    c->nbuf = (size_t)s->h.nbuf;
    c->d = s->d;
    return STATUS_OK;
}

void core_free_state(void **state) {
    if (state != NULL) {
        free(*state);
        *state = NULL;  /* a second free of the same pointer is harmless */
    }
}

size_t core_state_size(const void *state) {
    const Snapshot *s = state;
    return sizeof(Snapshot) + (size_t)s->h.nbuf * sizeof(double);
}

int core_serialize(Instance *c, const char *fn, const void *state, unsigned char *out,
                   size_t size) {
    size_t need = core_state_size(state);
    if (size < need) {
        log_error(c, "%s: size = %lu is not allowed: must be at least %lu", fn,
                  (unsigned long)size, (unsigned long)need);
        return STATUS_ERROR;
    }
    memcpy(out, state, need);
    return STATUS_OK;
}

int core_deserialize(Instance *c, const char *fn, const unsigned char *in, size_t size,
                     void **state) {
    Header h;
    if (size < sizeof(Snapshot)) {
        log_error(c, "%s: %lu bytes are not allowed: not a state of this FMU (too short)", fn,
                  (unsigned long)size);
        return STATUS_ERROR;
    }
    memcpy(&h, in, sizeof h);
    if (h.nbuf > (size - sizeof(Snapshot)) / sizeof(double) ||
        size != sizeof(Snapshot) + (size_t)h.nbuf * sizeof(double)) {
        log_error(c, "%s: %lu bytes are not allowed: not a state of this FMU (wrong length)",
                  fn, (unsigned long)size);
        return STATUS_ERROR;
    }
    Snapshot *s = malloc(size);
    if (s == NULL) {
        log_error(c, "%s: out of memory", fn);
        return STATUS_ERROR;
    }
    memcpy(s, in, size);
    if (!snapshot_valid(c, s, fn)) {
        free(s);
        return STATUS_ERROR;
    }
    free(*state);  /* a non-NULL *state is the state to overwrite */
    *state = s;
    return STATUS_OK;
}

/* ---- a restored state's data, what every model shares --------------------------------- */
static int variables_ok(const StateView *v) {
    const Data *d = v->d;
    for (size_t vr = 0; vr < NVR; vr++) {
        double x = d->real[vr];
        if (VAR_TYPE[vr] != 'r' && (x != 0.0 || signbit(x)))
            return state_refuse(v, "real[%lu] = %s: must be 0.0 (value reference %lu is not "
                                "a Real variable)", (unsigned long)vr, num(x).s,
                                (unsigned long)vr);
        if (VAR_TYPE[vr] == 'r' && VAR_CAUSALITY[vr] == 'o' && !isfinite(x))
            return state_refuse(v, "%s = %s: must be a finite number (an output)",
                                VAR_NAME[vr], num(x).s);
        int b = d->boolean[vr], i = d->integer[vr];
        if (VAR_TYPE[vr] == 'b' ? !(b == 0 || b == 1) : b != 0)
            return state_refuse(v, "boolean[%lu] = %d: must be %s", (unsigned long)vr, b,
                                VAR_TYPE[vr] == 'b' ? "0 or 1" : "0 (not a Boolean variable)");
        if (VAR_TYPE[vr] != 'i' && i != 0)
            return state_refuse(v, "integer[%lu] = %d: must be 0 (not an Integer variable)",
                                (unsigned long)vr, i);
    }
#if NSTRING > 0
    for (size_t k = 0; k < NSTRING; k++)
        if (memchr(d->string[k], '\0', STRING_MAX) == NULL)
            return state_refuse(v, "string[%lu] = (%d characters, not terminated): must be a "
                                "string of at most %d characters", (unsigned long)k,
                                STRING_MAX, STRING_MAX - 1);
#endif
    return 1;
}

/* The state machine's state, the times, the variables; before initialization ends, no
 * model buffer and the time at t0. */
static int data_ok(const StateView *v) {
    const Data *d = v->d;
    int st = d->state;
    if (st != StateInstantiated && st != StateInitializationMode && st != StateStepComplete &&
        st != StateTerminated && st != StateError && !(CLOCKED && st == StateEventMode))
        return state_refuse(v, "state = %d: must be one of 1 (instantiated), 2 "
                            "(initialization mode), 4 (step complete), 8 (terminated), 16 "
                            "(error)%s", st, CLOCKED ? ", 64 (event mode)" : "");
#if CLOCKED
    if (!state_range(v, "tick_next", d->tick_next, 0, 2147483647L) ||
        !state_flag(v, "clock_active", d->clock_active))
        return 0;
    if (d->clock_active && st != StateEventMode)
        return state_refuse(v, "clock_active = 1: must be 0 outside event mode");
#endif
    if (!isfinite(d->t0) || !isfinite(d->time))
        return state_refuse(v, "%s = %s: must be a finite number", isfinite(d->t0) ? "time"
                            : "t0", num(isfinite(d->t0) ? d->time : d->t0).s);
    if (st & (StateInstantiated | StateInitializationMode)) {
        if (!state_nbuf(v, 0, "no model buffer before " FMI_FN("ExitInitializationMode"))) return 0;
        if (!state_double_is(v, "time", d->time, d->t0, "t0, before " FMI_FN("ExitInitializationMode")))
            return 0;
    }
    return variables_ok(v);
}
