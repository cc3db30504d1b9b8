/* The FMI 2.0 co-simulation interface of the delaycomp native FMUs, written once.
 *
 * State machine of FMI 2.0.4, section 4.2.4: every function checks the state it is called
 * in and refuses a call in the wrong state with fmi2Error and a logged message (the state
 * is left as it was). A fault of the model (a bad parameter at fmi2ExitInitializationMode,
 * a non-finite input or a step it cannot take at fmi2DoStep, an output that overflows)
 * logs the reason, returns fmi2Error and puts the instance into the error state, from
 * which only getters, FMU-state calls, fmi2Terminate, fmi2Reset and fmi2FreeInstance are
 * accepted.
 * The FMU state holds everything (Data and the model buffer), so a restored instance
 * continues bit-identically; it serializes to a self-checking byte string.
 * Memory: the C library's calloc/free (canNotUseMemoryManagementFunctions = true).
 *
 * It knows no model: each model (fmus/<kind>/<name>.c) supplies the model_* functions of
 * native.h and its ModelData (<name>.h, named by config.h's MODEL_HEADER).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "native.h"

#define ANY_STATE (StateInstantiated | StateInitializationMode | StateStepComplete | \
                   StateTerminated | StateError)
#define MASK_GET (StateInitializationMode | StateStepComplete | StateTerminated | StateError)
#define MASK_SET_PARAMETER (StateInstantiated | StateInitializationMode)
#define MASK_SET_INPUT (StateInstantiated | StateInitializationMode | StateStepComplete)
#define MASK_STATE (ANY_STATE)

static const char *state_name(FsmState s) {
    switch (s) {
    case StateInstantiated: return "instantiated";
    case StateInitializationMode: return "initialization mode";
    case StateStepComplete: return "step complete";
    case StateTerminated: return "terminated";
    case StateError: return "error";
    }
    return "unknown";
}

/* ---- state machine ------------------------------------------------------------------- */
static int allowed(Instance *c, const char *fn, int mask) {
    if (c == NULL) return 0;
    if (c->d.state & mask) return 1;
    log_error(c, "%s is not allowed in state '%s' (FMI 2.0 co-simulation state machine)", fn,
              state_name(c->d.state));
    return 0;
}

static fmi2Status model_fault(Instance *c) {
    c->d.state = StateError;
    return fmi2Error;
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

/* ---- common functions -------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn,
                               size_t nCategories, const fmi2String categories[]) {
    Instance *c = comp;
    (void)nCategories;
    (void)categories;
    if (c == NULL) return fmi2Error;
    c->logging_on = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)fmuResourceLocation;
    (void)visible;
    if (functions == NULL || functions->logger == NULL) return NULL;
    const char *name = instanceName ? instanceName : "";
    if (fmuType != fmi2CoSimulation) {
        functions->logger(functions->componentEnvironment, name, fmi2Error, "logStatusError",
                          "%s", "fmuType is not allowed: this FMU supports only "
                                "fmi2CoSimulation");
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, INSTANTIATION_TOKEN) != 0) {
        functions->logger(functions->componentEnvironment, name, fmi2Error, "logStatusError",
                          "GUID %s is not allowed: this FMU is %s", fmuGUID ? fmuGUID : "(null)",
                          INSTANTIATION_TOKEN);
        return NULL;
    }
    Instance *c = calloc(1, sizeof *c);
    if (c == NULL) return NULL;
    c->instance_name = malloc(strlen(name) + 1);
    if (c->instance_name == NULL) { free(c); return NULL; }
    strcpy(c->instance_name, name);
    c->cb = *functions;
    c->logging_on = loggingOn ? 1 : 0;
    set_start_values(c);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = comp;
    if (c == NULL) return;
    free(c->buf);
    free(c->instance_name);
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *c = comp;
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!allowed(c, "fmi2SetupExperiment", StateInstantiated)) return fmi2Error;
    if (!isfinite(startTime)) {
        log_error(c, "startTime = %s is not allowed: must be a finite number",
                  num(startTime).s);
        return fmi2Error;
    }
    c->d.t0 = startTime;
    c->d.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2EnterInitializationMode", StateInstantiated)) return fmi2Error;
    c->d.state = StateInitializationMode;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2ExitInitializationMode", StateInitializationMode)) return fmi2Error;
    c->d.time = c->d.t0;
    if (model_setup(c) != 0) return model_fault(c);
    c->d.state = StateStepComplete;
    return fmi2OK;
}

/* Also after a fault (the error state): hosts end every instance of a failed run with
 * fmi2Terminate, and the Python FMUs accept it. Refused, it broke OMSimulator's command
 * line: its terminate pass stopped at the refusing instance after it had freed the ones
 * before, and its model's destructor called fmi2Terminate and fmi2FreeInstance on those
 * again (a use-after-free and a double free in the host, seen with valgrind). */
fmi2Status fmi2Terminate(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2Terminate", StateStepComplete | StateError)) return fmi2Error;
    c->d.state = StateTerminated;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2Reset", ANY_STATE)) return fmi2Error;
    free(c->buf);
    c->buf = NULL;
    c->nbuf = 0;
    set_start_values(c);
    return fmi2OK;
}

/* ---- getters and setters ---------------------------------------------------------- */
static int check_vr(Instance *c, const char *fn, fmi2ValueReference vr, char type) {
    static const char *const type_names[] = {"Real", "Integer", "Boolean", "String"};
    const char *tname = type == 'r' ? type_names[0] : type == 'i' ? type_names[1]
                      : type == 'b' ? type_names[2] : type_names[3];
    if (vr >= NVR || VAR_TYPE[vr] != type) {
        log_error(c, "%s: value reference %u is not allowed: it is not a %s variable of this "
                  "FMU", fn, (unsigned)vr, tname);
        return 0;
    }
    return 1;
}

static int check_settable(Instance *c, const char *fn, fmi2ValueReference vr) {
    if (VAR_CAUSALITY[vr] == 'o') {
        log_error(c, "%s: %s is an output: it cannot be set", fn, VAR_NAME[vr]);
        return 0;
    }
    if (VAR_CAUSALITY[vr] == 'p' && !(c->d.state & MASK_SET_PARAMETER)) {
        log_error(c, "%s: %s is a fixed parameter: it can be set only before "
                  "fmi2ExitInitializationMode (state is '%s')", fn, VAR_NAME[vr],
                  state_name(c->d.state));
        return 0;
    }
    return 1;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetReal", MASK_GET)) return fmi2Error;
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        if (!check_vr(c, "fmi2GetReal", vr[k], 'r')) return fmi2Error;
        if (VAR_CAUSALITY[vr[k]] == 'o') {
            if (model_output(c, vr[k], &value[k]) != 0) return model_fault(c);
        } else {
            value[k] = c->d.real[vr[k]];
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetInteger", MASK_GET)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        if (!check_vr(c, "fmi2GetInteger", vr[k], 'i')) return fmi2Error;
        value[k] = c->d.integer[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetBoolean", MASK_GET)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        if (!check_vr(c, "fmi2GetBoolean", vr[k], 'b')) return fmi2Error;
        value[k] = c->d.boolean[vr[k]] ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetString", MASK_GET)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        if (!check_vr(c, "fmi2GetString", vr[k], 's')) return fmi2Error;
#if NSTRING > 0
        value[k] = c->d.string[STRING_SLOT[vr[k]]];
#else
        (void)value;
#endif
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2SetReal", MASK_SET_INPUT)) return fmi2Error;
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    int inputs = 0;
    for (size_t k = 0; k < nvr; k++) {  /* all or nothing */
        if (!check_vr(c, "fmi2SetReal", vr[k], 'r') || !check_settable(c, "fmi2SetReal", vr[k]))
            return fmi2Error;
    }
    for (size_t k = 0; k < nvr; k++) {
        c->d.real[vr[k]] = value[k];
        inputs |= VAR_CAUSALITY[vr[k]] == 'i';
    }
    if (inputs) model_input_set(c);
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2SetInteger", MASK_SET_INPUT)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        if (!check_vr(c, "fmi2SetInteger", vr[k], 'i') ||
            !check_settable(c, "fmi2SetInteger", vr[k]))
            return fmi2Error;
    }
    for (size_t k = 0; k < nvr; k++) c->d.integer[vr[k]] = value[k];
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2SetBoolean", MASK_SET_INPUT)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        if (!check_vr(c, "fmi2SetBoolean", vr[k], 'b') ||
            !check_settable(c, "fmi2SetBoolean", vr[k]))
            return fmi2Error;
    }
    for (size_t k = 0; k < nvr; k++) c->d.boolean[vr[k]] = value[k] ? 1 : 0;
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    Instance *c = comp;
    if (!allowed(c, "fmi2SetString", MASK_SET_INPUT)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        if (!check_vr(c, "fmi2SetString", vr[k], 's') ||
            !check_settable(c, "fmi2SetString", vr[k]))
            return fmi2Error;
        if (value[k] == NULL || strlen(value[k]) >= STRING_MAX) {
            log_error(c, "%s is not allowed: must be a string of at most %d characters",
                      VAR_NAME[vr[k]], STRING_MAX - 1);
            return fmi2Error;
        }
    }
#if NSTRING > 0
    for (size_t k = 0; k < nvr; k++)
        snprintf(c->d.string[STRING_SLOT[vr[k]]], STRING_MAX, "%s", value[k]);
#endif
    return fmi2OK;
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

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = comp;
    if (!allowed(c, "fmi2GetFMUstate", MASK_STATE)) return fmi2Error;
    if (FMUstate == NULL) return fmi2Error;
    Snapshot *s = *FMUstate;
    if (s == NULL || s->h.nbuf != c->nbuf) {  /* a new snapshot, or one of another size */
        Snapshot *fresh = snapshot_new(c->nbuf);
        if (fresh == NULL) {
            log_error(c, "fmi2GetFMUstate: out of memory");
            return fmi2Error;
        }
        free(s);
        s = fresh;
    }
    s->d = c->d;
    if (c->nbuf) memcpy(s->buf, c->buf, c->nbuf * sizeof(double));
    *FMUstate = s;
    return fmi2OK;
}

static int data_ok(const StateView *v);

/* A snapshot to install: this FMU's (magic, GUID, sizeof(Data)), and its data and buffer
 * checked in full (data_ok, model_state_ok); else 0 and the refusal logged. */
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
    return data_ok(&v) && model_state_ok(&v);
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    Instance *c = comp;
    if (!allowed(c, "fmi2SetFMUstate", MASK_STATE)) return fmi2Error;
    const Snapshot *s = FMUstate;
    if (s == NULL) {
        log_error(c, "fmi2SetFMUstate: FMU state is not allowed: NULL");
        return fmi2Error;
    }
    if (!snapshot_valid(c, s, "fmi2SetFMUstate")) return fmi2Error;
    double *buf = NULL;
    if (s->h.nbuf) {
        buf = malloc((size_t)s->h.nbuf * sizeof(double));
        if (buf == NULL) {
            log_error(c, "fmi2SetFMUstate: out of memory");
            return fmi2Error;
        }
        memcpy(buf, s->buf, (size_t)s->h.nbuf * sizeof(double));
    }
    free(c->buf);
    c->buf = buf;
    c->nbuf = (size_t)s->h.nbuf;
    c->d = s->d;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = comp;
    if (c == NULL) return fmi2Error;
    if (FMUstate != NULL) {
        free(*FMUstate);
        *FMUstate = NULL;  /* a second free of the same pointer is harmless */
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate,
                                      size_t *size) {
    Instance *c = comp;
    if (c == NULL || FMUstate == NULL || size == NULL) return fmi2Error;
    const Snapshot *s = FMUstate;
    *size = sizeof(Snapshot) + (size_t)s->h.nbuf * sizeof(double);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    Instance *c = comp;
    if (c == NULL || FMUstate == NULL || serializedState == NULL) return fmi2Error;
    const Snapshot *s = FMUstate;
    size_t need = sizeof(Snapshot) + (size_t)s->h.nbuf * sizeof(double);
    if (size < need) {
        log_error(c, "fmi2SerializeFMUstate: size = %lu is not allowed: must be at least %lu",
                  (unsigned long)size, (unsigned long)need);
        return fmi2Error;
    }
    memcpy(serializedState, s, need);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    Instance *c = comp;
    if (c == NULL || serializedState == NULL || FMUstate == NULL) return fmi2Error;
    Header h;
    if (size < sizeof(Snapshot)) {
        log_error(c, "fmi2DeSerializeFMUstate: %lu bytes are not allowed: not a state of "
                  "this FMU (too short)", (unsigned long)size);
        return fmi2Error;
    }
    memcpy(&h, serializedState, sizeof h);
    if (h.nbuf > (size - sizeof(Snapshot)) / sizeof(double) ||
        size != sizeof(Snapshot) + (size_t)h.nbuf * sizeof(double)) {
        log_error(c, "fmi2DeSerializeFMUstate: %lu bytes are not allowed: not a state of "
                  "this FMU (wrong length)", (unsigned long)size);
        return fmi2Error;
    }
    Snapshot *s = malloc(size);
    if (s == NULL) {
        log_error(c, "fmi2DeSerializeFMUstate: out of memory");
        return fmi2Error;
    }
    memcpy(s, serializedState, size);
    if (!snapshot_valid(c, s, "fmi2DeSerializeFMUstate")) {
        free(s);
        return fmi2Error;
    }
    free(*FMUstate);  /* FMI 2.0: a non-NULL *FMUstate is the state to overwrite */
    *FMUstate = s;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp,
                                        const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown;
    (void)dvUnknown;
    Instance *c = comp;
    if (c != NULL)
        log_error(c, "fmi2GetDirectionalDerivative is not allowed: "
                  "providesDirectionalDerivative is false");
    return fmi2Error;
}

/* ---- co-simulation -------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    Instance *c = comp;
    if (c != NULL)
        log_error(c, "fmi2SetRealInputDerivatives is not allowed: canInterpolateInputs is "
                  "false");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    Instance *c = comp;
    if (c != NULL)
        log_error(c, "fmi2GetRealOutputDerivatives is not allowed: "
                  "maxOutputDerivativeOrder is 0");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *c = comp;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(c, "fmi2DoStep", StateStepComplete)) return fmi2Error;
    double t = currentCommunicationPoint, h = communicationStepSize, last = c->d.time;
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
    if (model_step(c, currentCommunicationPoint, communicationStepSize) != 0)
        return model_fault(c);
    c->d.time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    Instance *c = comp;
    if (c != NULL)
        log_error(c, "fmi2CancelStep is not allowed: fmi2DoStep never returns fmi2Pending");
    return fmi2Error;
}

static fmi2Status no_status(fmi2Component comp, const char *fn) {
    Instance *c = comp;
    if (c != NULL)
        log_error(c, "%s is not allowed: fmi2DoStep never returns fmi2Pending", fn);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    return no_status(c, "fmi2GetStatus");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    (void)s; (void)value;
    return no_status(c, "fmi2GetRealStatus");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    return no_status(c, "fmi2GetIntegerStatus");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)s; (void)value;
    return no_status(c, "fmi2GetBooleanStatus");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    return no_status(c, "fmi2GetStringStatus");
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
        st != StateTerminated && st != StateError)
        return state_refuse(v, "state = %d: must be one of 1 (instantiated), 2 "
                            "(initialization mode), 4 (step complete), 8 (terminated), 16 "
                            "(error)", st);
    if (!isfinite(d->t0) || !isfinite(d->time))
        return state_refuse(v, "%s = %s: must be a finite number", isfinite(d->t0) ? "time"
                            : "t0", num(isfinite(d->t0) ? d->time : d->t0).s);
    if (st & (StateInstantiated | StateInitializationMode)) {
        if (!state_nbuf(v, 0, "no model buffer before fmi2ExitInitializationMode")) return 0;
        if (!state_double_is(v, "time", d->time, d->t0, "t0, before fmi2ExitInitializationMode"))
            return 0;
    }
    return variables_ok(v);
}
