/* The FMI 3.0 co-simulation interface of the delaycomp native FMUs, written once.
 *
 * The same instance, model, checks and FMU state as the FMI 2.0 face (core.c), under the
 * FMI 3.0 names and types: a build compiles this file instead of fmi2.c (config.h's
 * FMI_MAJOR 3). What FMI 3.0 adds:
 *
 * - Arrays. A vector or matrix parameter of the FMI 2.0 twin (A[i,j], B[i,j], K[j,i], x0[i],
 *   u0[j], z0[i]) is one Float64 variable with its <Dimension>s, addressed by one value
 *   reference (its first element's slot of the shared table, so each scalar keeps its FMI
 *   2.0 value reference) and read or written whole, row-major: fmi3GetFloat64 and
 *   fmi3SetFloat64 take nValues = the sum of the elements of the variables named, and
 *   refuse another count.
 * - Structural parameters. The dimensions (n, m) are UInt64 structural parameters that
 *   the <Dimension>s name. The arrays' sizes are compiled in (the model's C is sized by
 *   them, nothing is allocated per element), so in configuration mode a structural
 *   parameter accepts its own value and refuses another, naming it and the built value.
 * - Sized types: Real is Float64, Integer Int32; Float32, Int8 .. UInt64 other than the
 *   structural parameters, Binary and Clock variables this FMU has none of (refused).
 *
 * State machine of FMI 3.0 co-simulation without event mode (hasEventMode = false):
 * instantiated -> (configuration mode ->) initialization mode -> step mode -> terminated,
 * every call checked as in fmi2.c; a fault of the model logs the reason, returns
 * fmi3Error and puts the instance into the error state. Model Exchange and Scheduled
 * Execution are not provided: their functions exist (every FMI 3.0 function is exported,
 * as importers resolve them all) and refuse with a logged message.
 *
 * A clocked build (config.h's CLOCKED: `build --fmi 3 --clocked`, the controller) has
 * event mode and an input Clock CLOCK_NAME, time-based and periodic, whose interval is
 * the parameter at CLOCK_INTERVAL_SLOT (T: intervalVariability = "fixed", read with
 * fmi3GetIntervalDecimal from initialization mode on) and shift 0: it ticks at
 * t0 + i T. The host schedules each tick: at t0 + i T it enters event mode (the FMU is in
 * event mode after fmi3ExitInitializationMode, for the tick at t0), sets the inputs, sets
 * the clock active (fmi3SetClock) and calls fmi3UpdateDiscreteStates, which samples the
 * inputs and latches the outputs; fmi3EnterStepMode, then steps. The inputs and outputs
 * are clocked: the inputs are set only in event mode, the outputs hold their latched
 * values between ticks. A host that does not schedule the clock gets a refusal, not a
 * silently wrong loop: eventModeUsed = false at instantiation, a tick at another time, a
 * step from a tick instant whose tick did not come, an input set in step mode.
 */
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "core.h"

/* An instance: the shared one and the host's logger (FMI 3.0: one message, no format). */
typedef struct {
    Instance base;
    fmi3LogMessageCallback log_message;
    fmi3InstanceEnvironment env;
} Instance3;

static void host_log(Instance *c, int status, const char *category, const char *text) {
    Instance3 *c3 = (Instance3 *)c;
    if (c3->log_message != NULL) c3->log_message(c3->env, (fmi3Status)status, category, text);
}

/* Refused before an instance exists (fmi3Instantiate*): logged through the callback. */
static void refuse_instantiation(fmi3LogMessageCallback log, fmi3InstanceEnvironment env,
                                 const char *text) {
    if (log != NULL) log(env, fmi3Error, "logStatusError", text);
}

/* ---- the clock (CLOCKED builds) -------------------------------------------------------- */
#if CLOCKED
/* The clock's interval (the parameter T) and the time of its next tick, t0 + i T. */
static double clock_interval(const Instance *c) { return c->d.real[CLOCK_INTERVAL_SLOT]; }

static double next_tick(const Instance *c) {
    return c->d.t0 + (double)c->d.tick_next * clock_interval(c);
}

/* Is t the next tick's instant, up to the grid's tolerance and a host clock's drift? (A
 * host's communication points are at least T / MAX_STEPS apart: far more than this.)
 * delaycomp.maths.grid.on_tick, the same arithmetic. */
static int at_next_tick(const Instance *c, double t) {
    double T = clock_interval(c);
    return fabs(t - next_tick(c)) <= GRID_RTOL * T + drift(t, T * 1e-3, c->d.t0);
}

/* The latched outputs: each output's value of the tick (the model's, at the tick). */
static int latch_outputs(Instance *c) {
    for (ValueRef vr = 0; vr < NVR; vr++)
        if (VAR_CAUSALITY[vr] == 'o' && model_output(c, vr, &c->d.real[vr]) != 0) return -1;
    return 0;
}
#endif

/* ---- the FMI 3.0 variables (config.h: VAR3, VAR3_INDEX) ------------------------------ */
static const char *type_name(char type) {
    switch (type) {
    case 'r': return "Float64";
    case 'i': return "Int32";
    case 'b': return "Boolean";
    case 's': return "String";
    case 'n': return "UInt64";
    case 'k': return "Clock";
    }
    return "?";
}

/* The variable of value reference vr if it is one of type `type`, else NULL (logged). */
static const Var3 *var_of(Instance *c, const char *fn, fmi3ValueReference vr, char type) {
    int k = vr < NVR3 ? VAR3_INDEX[vr] : -1;
    if (k < 0 || VAR3[k].type != type) {
        log_error(c, "%s: value reference %u is not allowed: it is not a %s variable of this "
                  "FMU", fn, (unsigned)vr, type_name(type));
        return NULL;
    }
    return &VAR3[k];
}

/* Check each value reference (all of type `type`) and that nValues is their elements. */
static int check_refs(Instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr,
                      size_t nvalues, char type) {
    size_t need = 0;
    if (nvr > 0 && vr == NULL) return 0;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = var_of(c, fn, vr[k], type);
        if (v == NULL) return 0;
        need += v->count;
    }
    if (nvalues != need) {
        log_error(c, "%s: nValues = %lu is not allowed: must be %lu (the elements of the "
                  "variables named)", fn, (unsigned long)nvalues, (unsigned long)need);
        return 0;
    }
    return 1;
}

static int check_settable(Instance *c, const char *fn, const Var3 *v) {
    if (v->causality == 'o' || v->causality == 't') {
        log_error(c, "%s: %s is %s: it cannot be set", fn, v->name,
                  v->causality == 'o' ? "an output" : "the independent variable");
        return 0;
    }
    if (c->d.state == StateConfigurationMode && v->causality != 's') {
        log_error(c, "%s: %s cannot be set in configuration mode (only the structural "
                  "parameters are)", fn, v->name);
        return 0;
    }
    if (v->causality == 's') {
        if (c->d.state != StateConfigurationMode) {
            log_error(c, "%s: %s is a structural parameter: it can be set only in "
                      "configuration mode (state is '%s')", fn, v->name,
                      state_name(c->d.state));
            return 0;
        }
        return 1;
    }
#if CLOCKED
    if (v->causality == 'i' && c->d.state == StateStepComplete) {
        log_error(c, "%s: %s is not allowed in step mode: it is clocked by %s (set it in "
                  "event mode, at the clock's tick)", fn, v->name, CLOCK_NAME);
        return 0;
    }
#endif
    if (v->causality == 'p' && !(c->d.state & MASK_SET_PARAMETER)) {
        log_error(c, "%s: %s is a fixed parameter: it can be set only before "
                  "fmi3ExitInitializationMode (state is '%s')", fn, v->name,
                  state_name(c->d.state));
        return 0;
    }
    return 1;
}

/* Setters: all named variables settable (and the count right), or nothing is set. */
static int check_set(Instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr,
                     const void *values, size_t nvalues, char type, int mask) {
    if (!allowed(c, fn, mask)) return 0;
    if (nvr > 0 && values == NULL) return 0;
    if (!check_refs(c, fn, vr, nvr, nvalues, type)) return 0;
    for (size_t k = 0; k < nvr; k++)
        if (!check_settable(c, fn, &VAR3[VAR3_INDEX[vr[k]]])) return 0;
    return 1;
}

#define MASK_SET3 (MASK_SET_INPUT | StateConfigurationMode | StateEventMode)

/* Structural parameters are readable in every state but configuration's peers; the others
 * from initialization mode on (MASK_GET). */
static int get_allowed(Instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr,
                       char type) {
    int structural_only = 1;
    if (c == NULL) return 0;
    for (size_t k = 0; k < nvr && vr != NULL; k++) {
        int i = vr[k] < NVR3 ? VAR3_INDEX[vr[k]] : -1;
        structural_only &= i >= 0 && VAR3[i].causality == 's';
    }
    (void)type;
    return allowed(c, fn, structural_only && nvr > 0 ? ANY_STATE | StateConfigurationMode
                                                     : MASK_GET);
}

/* ---- common functions -------------------------------------------------------------- */
const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn,
                               size_t nCategories, const fmi3String categories[]) {
    Instance *c = instance;
    (void)nCategories;
    (void)categories;
    if (c == NULL) return fmi3Error;
    c->logging_on = loggingOn ? 1 : 0;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName,
                                          fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn;
    refuse_instantiation(logMessage, instanceEnvironment, "fmi3InstantiateModelExchange is "
                         "not allowed: this FMU supports only co-simulation");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    refuse_instantiation(logMessage, instanceEnvironment, "fmi3InstantiateScheduledExecution "
                         "is not allowed: this FMU supports only co-simulation");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)intermediateUpdate;
    char text[TEXT_MAX];
    if (instantiationToken == NULL || strcmp(instantiationToken, INSTANTIATION_TOKEN) != 0) {
        snprintf(text, sizeof text, "instantiationToken %s is not allowed: this FMU is %s",
                 instantiationToken ? instantiationToken : "(null)", INSTANTIATION_TOKEN);
        refuse_instantiation(logMessage, instanceEnvironment, text);
        return NULL;
    }
#if CLOCKED
    if (!eventModeUsed) {
        refuse_instantiation(logMessage, instanceEnvironment, "eventModeUsed = false is not "
                             "allowed: this controller samples at the ticks of its clock "
                             CLOCK_NAME ", which the host schedules in event mode (a host "
                             "without clocks takes the unclocked FMU)");
        return NULL;
    }
#else
    if (eventModeUsed) {
        refuse_instantiation(logMessage, instanceEnvironment, "eventModeUsed = true is not "
                             "allowed: this FMU has no event mode (hasEventMode = false)");
        return NULL;
    }
#endif
    if (nRequiredIntermediateVariables > 0) {
        refuse_instantiation(logMessage, instanceEnvironment, "requiredIntermediateVariables "
                             "is not allowed: this FMU provides no intermediate update");
        return NULL;
    }
    Instance *c = core_new(sizeof(Instance3), instanceName ? instanceName : "");
    if (c == NULL) {
        refuse_instantiation(logMessage, instanceEnvironment,
                             "fmi3InstantiateCoSimulation: out of memory");
        return NULL;
    }
    ((Instance3 *)c)->log_message = logMessage;
    ((Instance3 *)c)->env = instanceEnvironment;
    c->logger = host_log;
    c->logging_on = loggingOn ? 1 : 0;
    return c;
}

void fmi3FreeInstance(fmi3Instance instance) { core_free(instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    Instance *c = instance;
    (void)toleranceDefined; (void)tolerance; (void)stopTimeDefined; (void)stopTime;
    if (!allowed(c, "fmi3EnterInitializationMode", StateInstantiated)) return fmi3Error;
    if (!isfinite(startTime)) {
        log_error(c, "startTime = %s is not allowed: must be a finite number",
                  num(startTime).s);
        return fmi3Error;
    }
    c->d.t0 = startTime;
    c->d.time = startTime;
    c->d.state = StateInitializationMode;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    Instance *c = instance;
    fmi3Status status = (fmi3Status)core_exit_initialization(c, "fmi3ExitInitializationMode");
#if CLOCKED
    if (status == fmi3OK) {  /* event mode: the tick at t0 comes first */
        c->d.state = StateEventMode;
        c->d.tick_next = 0;
        c->d.clock_active = 0;
    }
#endif
    return status;
}

static fmi3Status refuse(fmi3Instance instance, const char *text) {
    Instance *c = instance;
    if (c != NULL) log_error(c, "%s", text);
    return fmi3Error;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
#if CLOCKED
    Instance *c = instance;
    if (!allowed(c, "fmi3EnterEventMode", StateStepComplete)) return fmi3Error;
    c->d.state = StateEventMode;
    c->d.clock_active = 0;
    return fmi3OK;
#else
    return refuse(instance, "fmi3EnterEventMode is not allowed: this FMU has no event mode "
                  "(hasEventMode = false)");
#endif
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    return (fmi3Status)core_terminate(instance, "fmi3Terminate");
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    Instance *c = instance;
    if (!allowed(c, "fmi3Reset", ANY_STATE | StateConfigurationMode)) return fmi3Error;
    core_reset(c);
    return fmi3OK;
}

/* ---- getters and setters ----------------------------------------------------------- */
fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues) {
    Instance *c = instance;
    if (!get_allowed(c, "fmi3GetFloat64", vr, nvr, 'r')) return fmi3Error;
    if (!check_refs(c, "fmi3GetFloat64", vr, nvr, nValues, 'r')) return fmi3Error;
    if (nValues > 0 && values == NULL) return fmi3Error;
    size_t at = 0;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = &VAR3[VAR3_INDEX[vr[k]]];
        if (v->causality == 't') {  /* the independent variable: the current time */
            values[at++] = c->d.time;
            continue;
        }
#if CLOCKED
        if (v->causality == 'o') {  /* clocked: the values latched at the last tick */
            for (size_t e = 0; e < v->count; e++) values[at++] = c->d.real[v->first + e];
            continue;
        }
#endif
        for (size_t e = 0; e < v->count; e++)
            if (core_get_real(c, v->first + (ValueRef)e, &values[at++]) != STATUS_OK)
                return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    Instance *c = instance;
    if (!check_set(c, "fmi3SetFloat64", vr, nvr, values, nValues, 'r', MASK_SET3))
        return fmi3Error;
    size_t at = 0;
    int inputs = 0;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = &VAR3[VAR3_INDEX[vr[k]]];
        for (size_t e = 0; e < v->count; e++) c->d.real[v->first + e] = values[at++];
        inputs |= v->causality == 'i';
    }
    if (inputs) model_input_set(c);
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Int32 values[], size_t nValues) {
    Instance *c = instance;
    if (!get_allowed(c, "fmi3GetInt32", vr, nvr, 'i')) return fmi3Error;
    if (!check_refs(c, "fmi3GetInt32", vr, nvr, nValues, 'i')) return fmi3Error;
    size_t at = 0;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = &VAR3[VAR3_INDEX[vr[k]]];
        for (size_t e = 0; e < v->count; e++) values[at++] = c->d.integer[v->first + e];
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Int32 values[], size_t nValues) {
    Instance *c = instance;
    if (!check_set(c, "fmi3SetInt32", vr, nvr, values, nValues, 'i', MASK_SET3))
        return fmi3Error;
    size_t at = 0;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = &VAR3[VAR3_INDEX[vr[k]]];
        for (size_t e = 0; e < v->count; e++) c->d.integer[v->first + e] = values[at++];
    }
    return fmi3OK;
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Boolean values[], size_t nValues) {
    Instance *c = instance;
    if (!get_allowed(c, "fmi3GetBoolean", vr, nvr, 'b')) return fmi3Error;
    if (!check_refs(c, "fmi3GetBoolean", vr, nvr, nValues, 'b')) return fmi3Error;
    size_t at = 0;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = &VAR3[VAR3_INDEX[vr[k]]];
        for (size_t e = 0; e < v->count; e++) values[at++] = c->d.boolean[v->first + e] != 0;
    }
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Boolean values[], size_t nValues) {
    Instance *c = instance;
    if (!check_set(c, "fmi3SetBoolean", vr, nvr, values, nValues, 'b', MASK_SET3))
        return fmi3Error;
    size_t at = 0;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = &VAR3[VAR3_INDEX[vr[k]]];
        for (size_t e = 0; e < v->count; e++) c->d.boolean[v->first + e] = values[at++] ? 1 : 0;
    }
    return fmi3OK;
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         fmi3String values[], size_t nValues) {
    Instance *c = instance;
    if (!get_allowed(c, "fmi3GetString", vr, nvr, 's')) return fmi3Error;
    if (!check_refs(c, "fmi3GetString", vr, nvr, nValues, 's')) return fmi3Error;
#if NSTRING > 0
    for (size_t k = 0; k < nvr; k++) values[k] = c->d.string[STRING_SLOT[vr[k]]];
#else
    (void)values;
#endif
    return fmi3OK;
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const fmi3String values[], size_t nValues) {
    Instance *c = instance;
    if (!check_set(c, "fmi3SetString", vr, nvr, values, nValues, 's', MASK_SET3))
        return fmi3Error;
    for (size_t k = 0; k < nvr; k++)
        if (!core_string_ok(c, VAR3[VAR3_INDEX[vr[k]]].name, values[k])) return fmi3Error;
#if NSTRING > 0
    for (size_t k = 0; k < nvr; k++)
        snprintf(c->d.string[STRING_SLOT[vr[k]]], STRING_MAX, "%s", values[k]);
#endif
    return fmi3OK;
}

/* The structural parameters: UInt64, their built values. */
fmi3Status fmi3GetUInt64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         fmi3UInt64 values[], size_t nValues) {
    Instance *c = instance;
    if (!get_allowed(c, "fmi3GetUInt64", vr, nvr, 'n')) return fmi3Error;
    if (!check_refs(c, "fmi3GetUInt64", vr, nvr, nValues, 'n')) return fmi3Error;
    for (size_t k = 0; k < nvr; k++) values[k] = VAR3[VAR3_INDEX[vr[k]]].value;
    return fmi3OK;
}

fmi3Status fmi3SetUInt64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const fmi3UInt64 values[], size_t nValues) {
    Instance *c = instance;
    if (!check_set(c, "fmi3SetUInt64", vr, nvr, values, nValues, 'n', MASK_SET3))
        return fmi3Error;
    for (size_t k = 0; k < nvr; k++) {
        const Var3 *v = &VAR3[VAR3_INDEX[vr[k]]];
        if (values[k] != v->value) {
            log_error(c, "fmi3SetUInt64: %s = %llu is not allowed: this FMU is built for %s = "
                      "%llu (its arrays' sizes are compiled in: build an FMU for %s = %llu)",
                      v->name, (unsigned long long)values[k], v->name,
                      (unsigned long long)v->value, v->name, (unsigned long long)values[k]);
            return fmi3Error;
        }
    }
    return fmi3OK;
}

/* Types this FMU has no variable of: an empty call passes, any value reference is refused. */
#define NO_SUCH_TYPE(Type, CType, what)                                                      \
    fmi3Status fmi3Get##Type(fmi3Instance instance, const fmi3ValueReference vr[],          \
                             size_t nvr, CType values[], size_t nValues) {                  \
        (void)values; (void)nValues;                                                        \
        return nvr == 0 ? fmi3OK : refuse_type(instance, "fmi3Get" #Type, vr[0], what);     \
    }                                                                                       \
    fmi3Status fmi3Set##Type(fmi3Instance instance, const fmi3ValueReference vr[],          \
                             size_t nvr, const CType values[], size_t nValues) {            \
        (void)values; (void)nValues;                                                        \
        return nvr == 0 ? fmi3OK : refuse_type(instance, "fmi3Set" #Type, vr[0], what);     \
    }

static fmi3Status refuse_type(fmi3Instance instance, const char *fn, fmi3ValueReference vr,
                              const char *what) {
    Instance *c = instance;
    if (c != NULL)
        log_error(c, "%s: value reference %u is not allowed: it is not a %s variable of this "
                  "FMU", fn, (unsigned)vr, what);
    return fmi3Error;
}

NO_SUCH_TYPE(Float32, fmi3Float32, "Float32")
NO_SUCH_TYPE(Int8, fmi3Int8, "Int8")
NO_SUCH_TYPE(UInt8, fmi3UInt8, "UInt8")
NO_SUCH_TYPE(Int16, fmi3Int16, "Int16")
NO_SUCH_TYPE(UInt16, fmi3UInt16, "UInt16")
NO_SUCH_TYPE(UInt32, fmi3UInt32, "UInt32")
NO_SUCH_TYPE(Int64, fmi3Int64, "Int64")

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    return nvr == 0 ? fmi3OK : refuse_type(instance, "fmi3GetBinary", vr[0], "Binary");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[],
                         size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    return nvr == 0 ? fmi3OK : refuse_type(instance, "fmi3SetBinary", vr[0], "Binary");
}

#if CLOCKED
/* Every value reference the clock's, else 0 (logged). */
static int clock_refs(Instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr) {
    for (size_t k = 0; k < nvr; k++)
        if (var_of(c, fn, vr[k], 'k') == NULL) return 0;
    return nvr == 0 || vr != NULL;
}
#endif

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[]) {
#if CLOCKED
    Instance *c = instance;
    if (!allowed(c, "fmi3GetClock", StateEventMode | StateStepComplete)) return fmi3Error;
    if (!clock_refs(c, "fmi3GetClock", vr, nvr)) return fmi3Error;
    for (size_t k = 0; k < nvr; k++) values[k] = c->d.clock_active ? fmi3ClockActive
                                                                   : fmi3ClockInactive;
    return fmi3OK;
#else
    (void)values;
    return nvr == 0 ? fmi3OK : refuse_type(instance, "fmi3GetClock", vr[0], "Clock");
#endif
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
#if CLOCKED
    Instance *c = instance;
    if (!allowed(c, "fmi3SetClock", StateEventMode)) return fmi3Error;
    if (!clock_refs(c, "fmi3SetClock", vr, nvr)) return fmi3Error;
    for (size_t k = 0; k < nvr; k++) {
        if (values[k] && !at_next_tick(c, c->d.time)) {
            log_error(c, "fmi3SetClock: %s ticking at t = %s is not allowed: its next tick is "
                      "at t0 + %ld T = %s (interval T = %s)", CLOCK_NAME, num(c->d.time).s,
                      c->d.tick_next, num(next_tick(c)).s, num(clock_interval(c)).s);
            return fmi3Error;
        }
        c->d.clock_active = values[k] ? 1 : 0;
    }
    return fmi3OK;
#else
    (void)values;
    return nvr == 0 ? fmi3OK : refuse_type(instance, "fmi3SetClock", vr[0], "Clock");
#endif
}

/* ---- dependencies ------------------------------------------------------------------ */
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    return refuse(instance, "fmi3GetNumberOfVariableDependencies is not allowed: the "
                  "dependencies are those of modelDescription.xml");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return refuse(instance, "fmi3GetVariableDependencies is not allowed: the dependencies "
                  "are those of modelDescription.xml");
}

/* ---- FMU state (core.c) ------------------------------------------------------------- */
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return (fmi3Status)core_get_state(instance, "fmi3GetFMUState", FMUState);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return (fmi3Status)core_set_state(instance, "fmi3SetFMUState", FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    if (instance == NULL) return fmi3Error;
    core_free_state(FMUState);
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    if (instance == NULL || FMUState == NULL || size == NULL) return fmi3Error;
    *size = core_state_size(FMUState);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    if (instance == NULL || FMUState == NULL || serializedState == NULL) return fmi3Error;
    return (fmi3Status)core_serialize(instance, "fmi3SerializeFMUState", FMUState,
                                      serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    if (instance == NULL || serializedState == NULL || FMUState == NULL) return fmi3Error;
    return (fmi3Status)core_deserialize(instance, "fmi3DeserializeFMUState", serializedState,
                                        size, FMUState);
}

/* ---- derivatives, configuration, clocks, discrete states ---------------------------- */
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance,
                                        const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return refuse(instance, "fmi3GetDirectionalDerivative is not allowed: "
                  "providesDirectionalDerivatives is false");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return refuse(instance, "fmi3GetAdjointDerivative is not allowed: "
                  "providesAdjointDerivatives is false");
}

/* Configuration mode: from instantiated only (the structural parameters are fixed, not
 * tunable: no reconfiguration in step mode). */
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    Instance *c = instance;
    if (!allowed(c, "fmi3EnterConfigurationMode", StateInstantiated)) return fmi3Error;
    c->d.state = StateConfigurationMode;
    return fmi3OK;
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    Instance *c = instance;
    if (!allowed(c, "fmi3ExitConfigurationMode", StateConfigurationMode)) return fmi3Error;
    c->d.state = StateInstantiated;
    return fmi3OK;
}

#define NO_CLOCKS "is not allowed: this FMU has no clocks"

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
                                  size_t nvr, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
#if CLOCKED
    /* intervalVariability = "fixed": T, known once the parameters are (initialization
     * mode on); reported as changed there, unchanged after */
    Instance *c = instance;
    if (!allowed(c, "fmi3GetIntervalDecimal", MASK_GET)) return fmi3Error;
    if (!clock_refs(c, "fmi3GetIntervalDecimal", vr, nvr)) return fmi3Error;
    double T = clock_interval(c);
    if (!(isfinite(T) && T > 0)) {
        log_error(c, "fmi3GetIntervalDecimal: the interval of %s is T = %s, which is not "
                  "allowed: must be a finite number > 0", CLOCK_NAME, num(T).s);
        return fmi3Error;
    }
    for (size_t k = 0; k < nvr; k++) {
        intervals[k] = T;
        qualifiers[k] = c->d.state == StateInitializationMode ? fmi3IntervalChanged
                                                              : fmi3IntervalUnchanged;
    }
    return fmi3OK;
#else
    (void)vr; (void)nvr; (void)intervals; (void)qualifiers;
    return refuse(instance, "fmi3GetIntervalDecimal " NO_CLOCKS);
#endif
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[],
                                   size_t nvr, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    return refuse(instance, "fmi3GetIntervalFraction " NO_CLOCKS);
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
                               size_t nvr, fmi3Float64 shifts[]) {
#if CLOCKED
    Instance *c = instance;  /* the first tick at t0: shift 0 */
    if (!allowed(c, "fmi3GetShiftDecimal", MASK_GET)) return fmi3Error;
    if (!clock_refs(c, "fmi3GetShiftDecimal", vr, nvr)) return fmi3Error;
    for (size_t k = 0; k < nvr; k++) shifts[k] = 0.0;
    return fmi3OK;
#else
    (void)vr; (void)nvr; (void)shifts;
    return refuse(instance, "fmi3GetShiftDecimal " NO_CLOCKS);
#endif
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[],
                                size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return refuse(instance, "fmi3GetShiftFraction " NO_CLOCKS);
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
                                  size_t nvr, const fmi3Float64 intervals[]) {
    (void)vr; (void)nvr; (void)intervals;
    return refuse(instance, "fmi3SetIntervalDecimal " NO_CLOCKS);
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[],
                                   size_t nvr, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return refuse(instance, "fmi3SetIntervalFraction " NO_CLOCKS);
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
                               size_t nvr, const fmi3Float64 shifts[]) {
    (void)vr; (void)nvr; (void)shifts;
    return refuse(instance, "fmi3SetShiftDecimal " NO_CLOCKS);
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[],
                                size_t nvr, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return refuse(instance, "fmi3SetShiftFraction " NO_CLOCKS);
}

#define NO_EVENTS "is not allowed: this FMU has no event mode (hasEventMode = false)"

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return refuse(instance, "fmi3EvaluateDiscreteStates " NO_EVENTS);
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance,
                                    fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
#if CLOCKED
    /* the tick: the model samples the inputs set in this event mode, the outputs latch */
    Instance *c = instance;
    if (!allowed(c, "fmi3UpdateDiscreteStates", StateEventMode)) return fmi3Error;
    if (c->d.clock_active) {
        if (latch_outputs(c) != 0) return model_fault(c);
        c->d.tick_next += 1;
        c->d.clock_active = 0;
    }
    if (discreteStatesNeedUpdate != NULL) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation != NULL) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged != NULL)
        *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged != NULL) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined != NULL) *nextEventTimeDefined = fmi3True;
    if (nextEventTime != NULL) *nextEventTime = next_tick(c);
    return fmi3OK;
#else
    (void)discreteStatesNeedUpdate; (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged; (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined; (void)nextEventTime;
    return refuse(instance, "fmi3UpdateDiscreteStates " NO_EVENTS);
#endif
}

/* ---- Model Exchange: not provided --------------------------------------------------- */
#define NO_ME "is not allowed: this FMU supports only co-simulation"

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return refuse(instance, "fmi3EnterContinuousTimeMode " NO_ME);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return refuse(instance, "fmi3CompletedIntegratorStep " NO_ME);
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return refuse(instance, "fmi3SetTime " NO_ME);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance,
                                   const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return refuse(instance, "fmi3SetContinuousStates " NO_ME);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives; (void)nContinuousStates;
    return refuse(instance, "fmi3GetContinuousStateDerivatives " NO_ME);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators; (void)nEventIndicators;
    return refuse(instance, "fmi3GetEventIndicators " NO_ME);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return refuse(instance, "fmi3GetContinuousStates " NO_ME);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals; (void)nContinuousStates;
    return refuse(instance, "fmi3GetNominalsOfContinuousStates " NO_ME);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    return refuse(instance, "fmi3GetNumberOfEventIndicators " NO_ME);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    return refuse(instance, "fmi3GetNumberOfContinuousStates " NO_ME);
}

/* ---- co-simulation ------------------------------------------------------------------ */
fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
#if CLOCKED
    Instance *c = instance;
    if (!allowed(c, "fmi3EnterStepMode", StateEventMode)) return fmi3Error;
    if (c->d.clock_active) {
        log_error(c, "fmi3EnterStepMode is not allowed: %s is active and not yet updated "
                  "(call fmi3UpdateDiscreteStates)", CLOCK_NAME);
        return fmi3Error;
    }
    c->d.state = StateStepComplete;
    return fmi3OK;
#else
    return refuse(instance, "fmi3EnterStepMode " NO_EVENTS);
#endif
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[],
                                    size_t nvr, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)vr; (void)nvr; (void)orders; (void)values; (void)nValues;
    return refuse(instance, "fmi3GetOutputDerivatives is not allowed: "
                  "maxOutputDerivativeOrder is 0");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    Instance *c = instance;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(c, "fmi3DoStep", StateStepComplete)) return fmi3Error;
    if (eventHandlingNeeded != NULL) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation != NULL) *terminateSimulation = fmi3False;
    if (earlyReturn != NULL) *earlyReturn = fmi3False;
#if CLOCKED
    if (at_next_tick(c, currentCommunicationPoint)) {
        log_error(c, "fmi3DoStep from t = %s is not allowed: %s ticks there (t0 + %ld T) and "
                  "did not (enter event mode, set the inputs, fmi3SetClock, "
                  "fmi3UpdateDiscreteStates, fmi3EnterStepMode)",
                  num(currentCommunicationPoint).s, CLOCK_NAME, c->d.tick_next);
        if (lastSuccessfulTime != NULL) *lastSuccessfulTime = c->d.time;
        return (fmi3Status)model_fault(c);
    }
#endif
    fmi3Status status = (fmi3Status)core_do_step(c, currentCommunicationPoint,
                                                 communicationStepSize);
    if (lastSuccessfulTime != NULL) *lastSuccessfulTime = c->d.time;
    return status;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return refuse(instance, "fmi3ActivateModelPartition is not allowed: this FMU supports "
                  "only co-simulation");
}
