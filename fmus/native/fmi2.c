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
 * native.h and its ModelData (<name>.h, named by config.h's MODEL_HEADER). What it shares
 * with the FMI 3.0 face (fmi3.c) is core.c's: this file maps the FMI 2.0 calls onto it.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "core.h"

/* An instance: the shared one and the host's callbacks (its logger takes a format). */
typedef struct {
    Instance base;
    fmi2CallbackFunctions cb;
} Instance2;

static void host_log(Instance *c, int status, const char *category, const char *text) {
    Instance2 *c2 = (Instance2 *)c;
    c2->cb.logger(c2->cb.componentEnvironment, c->instance_name, (fmi2Status)status, category,
                  "%s", text);
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
    Instance *c = core_new(sizeof(Instance2), name);
    if (c == NULL) return NULL;
    ((Instance2 *)c)->cb = *functions;
    c->logger = host_log;
    c->logging_on = loggingOn ? 1 : 0;
    return c;
}

void fmi2FreeInstance(fmi2Component comp) { core_free(comp); }

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
    return (fmi2Status)core_exit_initialization(comp, "fmi2ExitInitializationMode");
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    return (fmi2Status)core_terminate(comp, "fmi2Terminate");
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = comp;
    if (!allowed(c, "fmi2Reset", ANY_STATE)) return fmi2Error;
    core_reset(c);
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
        if (core_get_real(c, vr[k], &value[k]) != STATUS_OK) return fmi2Error;
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
        if (!core_string_ok(c, VAR_NAME[vr[k]], value[k])) return fmi2Error;
    }
#if NSTRING > 0
    for (size_t k = 0; k < nvr; k++)
        snprintf(c->d.string[STRING_SLOT[vr[k]]], STRING_MAX, "%s", value[k]);
#endif
    return fmi2OK;
}

/* ---- FMU state (core.c) --------------------------------------------------------------- */
fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    return (fmi2Status)core_get_state(comp, "fmi2GetFMUstate", FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    return (fmi2Status)core_set_state(comp, "fmi2SetFMUstate", FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    if (comp == NULL) return fmi2Error;
    core_free_state(FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate,
                                      size_t *size) {
    if (comp == NULL || FMUstate == NULL || size == NULL) return fmi2Error;
    *size = core_state_size(FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    if (comp == NULL || FMUstate == NULL || serializedState == NULL) return fmi2Error;
    return (fmi2Status)core_serialize(comp, "fmi2SerializeFMUstate", FMUstate,
                                      (unsigned char *)serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    if (comp == NULL || serializedState == NULL || FMUstate == NULL) return fmi2Error;
    return (fmi2Status)core_deserialize(comp, "fmi2DeSerializeFMUstate",
                                        (const unsigned char *)serializedState, size,
                                        FMUstate);
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
    return (fmi2Status)core_do_step(c, currentCommunicationPoint, communicationStepSize);
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
