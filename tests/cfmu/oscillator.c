/* Oscillator: a test plant FMU written in C (FMI 2.0, co-simulation and Model Exchange).
 *
 *   position' = velocity
 *   velocity' = acceleration = (force - stiffness * position - damping * velocity) / mass
 *
 * Co-simulation: doStep(t, H) holds `force` constant and takes n = ceil(H / substep)
 * equal classical Runge-Kutta (RK4) steps of H / n. `acceleration` is an output with
 * direct feedthrough from `force`. See README.md beside this file.
 */
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define INSTANTIATION_TOKEN "{6c1f7a52-2d0e-4b7e-9a51-delaycomp0c14}"

enum { VR_POSITION, VR_VELOCITY, VR_DER_POSITION, VR_ACCELERATION, VR_FORCE, VR_STIFFNESS,
       VR_DAMPING, VR_MASS, VR_POSITION_START, VR_VELOCITY_START, VR_SUBSTEP, N_VR };

typedef struct {
    double v[N_VR];
    double time;
    int cs;
    int initialized;
    fmi2CallbackFunctions cb;
    const char *name;
} Model;

static void logmsg(Model *m, fmi2Status s, const char *cat, const char *msg) {
    if (m->cb.logger) m->cb.logger(m->cb.componentEnvironment, m->name, s, cat, "%s", msg);
}

static void derivatives(const Model *m, const double x[2], double u, double dx[2]) {
    dx[0] = x[1];
    dx[1] = (u - m->v[VR_STIFFNESS] * x[0] - m->v[VR_DAMPING] * x[1]) / m->v[VR_MASS];
}

static void update_outputs(Model *m) {
    double x[2] = {m->v[VR_POSITION], m->v[VR_VELOCITY]}, dx[2];
    derivatives(m, x, m->v[VR_FORCE], dx);
    m->v[VR_DER_POSITION] = dx[0];
    m->v[VR_ACCELERATION] = dx[1];
}

static void rk4(Model *m, double h) {
    double x[2] = {m->v[VR_POSITION], m->v[VR_VELOCITY]}, u = m->v[VR_FORCE];
    double k1[2], k2[2], k3[2], k4[2], y[2];
    int i;
    derivatives(m, x, u, k1);
    for (i = 0; i < 2; i++) y[i] = x[i] + 0.5 * h * k1[i];
    derivatives(m, y, u, k2);
    for (i = 0; i < 2; i++) y[i] = x[i] + 0.5 * h * k2[i];
    derivatives(m, y, u, k3);
    for (i = 0; i < 2; i++) y[i] = x[i] + h * k3[i];
    derivatives(m, y, u, k4);
    for (i = 0; i < 2; i++) x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    m->v[VR_POSITION] = x[0];
    m->v[VR_VELOCITY] = x[1];
}

static int check_parameters(Model *m) {
    char buf[256];
    if (!(isfinite(m->v[VR_MASS]) && m->v[VR_MASS] > 0)) {
        snprintf(buf, sizeof buf, "mass = %g is not allowed: must be a finite number > 0",
                 m->v[VR_MASS]);
        logmsg(m, fmi2Error, "logStatusError", buf);
        return 0;
    }
    if (!(isfinite(m->v[VR_SUBSTEP]) && m->v[VR_SUBSTEP] > 0)) {
        snprintf(buf, sizeof buf, "substep = %g is not allowed: must be a finite number > 0",
                 m->v[VR_SUBSTEP]);
        logmsg(m, fmi2Error, "logStatusError", buf);
        return 0;
    }
    return 1;
}

/* ---- common ---------------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)c; (void)on; (void)n; (void)cats; return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String location, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Model *m;
    (void)location; (void)visible; (void)loggingOn;
    if (!cb || !guid || strcmp(guid, INSTANTIATION_TOKEN) != 0) return NULL;
    m = (Model *)calloc(1, sizeof(Model));
    if (!m) return NULL;
    m->cb = *cb;
    m->name = name ? strdup(name) : strdup("oscillator");
    m->cs = type == fmi2CoSimulation;
    m->v[VR_STIFFNESS] = -1.0;
    m->v[VR_DAMPING] = 0.2;
    m->v[VR_MASS] = 1.0;
    m->v[VR_POSITION_START] = 1.0;
    m->v[VR_VELOCITY_START] = 0.0;
    m->v[VR_SUBSTEP] = 0.01;
    m->v[VR_FORCE] = 0.0;
    return m;
}

void fmi2FreeInstance(fmi2Component c) {
    Model *m = (Model *)c;
    if (!m) return;
    free((void *)m->name);
    free(m);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol,
                               fmi2Real start, fmi2Boolean stopDef, fmi2Real stop) {
    (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    ((Model *)c)->time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Model *m = (Model *)c;
    if (!check_parameters(m)) return fmi2Error;
    m->v[VR_POSITION] = m->v[VR_POSITION_START];
    m->v[VR_VELOCITY] = m->v[VR_VELOCITY_START];
    m->initialized = 1;
    update_outputs(m);
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Model *m = (Model *)c;
    size_t i;
    if (!m->initialized) {  /* before initialization the states follow their start values */
        m->v[VR_POSITION] = m->v[VR_POSITION_START];
        m->v[VR_VELOCITY] = m->v[VR_VELOCITY_START];
    }
    if (m->v[VR_MASS] > 0) update_outputs(m);
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_VR) { logmsg(m, fmi2Error, "logStatusError", "unknown value reference"); return fmi2Error; }
        value[i] = m->v[vr[i]];
#ifdef BROKEN_AFTER  /* a plant that breaks down (tests): position reads NaN from then on */
        if (vr[i] == VR_POSITION && m->time >= BROKEN_AFTER) value[i] = NAN;
#endif
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Model *m = (Model *)c;
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_VR || vr[i] == VR_DER_POSITION || vr[i] == VR_ACCELERATION
            || (m->cs && (vr[i] == VR_POSITION || vr[i] == VR_VELOCITY))) {
            logmsg(m, fmi2Error, "logStatusError", "variable cannot be set");
            return fmi2Error;
        }
        if (m->initialized && vr[i] >= VR_STIFFNESS) {
            logmsg(m, fmi2Error, "logStatusError", "a fixed parameter cannot be set after initialization");
            return fmi2Error;
        }
        if (vr[i] == VR_FORCE && !isfinite(value[i])) {
            logmsg(m, fmi2Error, "logStatusError", "force is not a finite number");
            return fmi2Error;
        }
        m->v[vr[i]] = value[i];
    }
    return fmi2OK;
}

#define NO_TYPE(T, V) \
fmi2Status fmi2Get##T(fmi2Component c, const fmi2ValueReference vr[], size_t n, V value[]) { \
    (void)c; (void)vr; (void)value; return n == 0 ? fmi2OK : fmi2Error; } \
fmi2Status fmi2Set##T(fmi2Component c, const fmi2ValueReference vr[], size_t n, const V value[]) { \
    (void)c; (void)vr; (void)value; return n == 0 ? fmi2OK : fmi2Error; }
NO_TYPE(Integer, fmi2Integer)
NO_TYPE(Boolean, fmi2Boolean)
NO_TYPE(String, fmi2String)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { (void)c; (void)s; (void)n; return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { (void)c; (void)s; (void)b; (void)n; return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) { (void)c; (void)b; (void)n; (void)s; return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
                                        const fmi2ValueReference b[], size_t nb, const fmi2Real d[], fmi2Real r[]) {
    (void)c; (void)a; (void)na; (void)b; (void)nb; (void)d; (void)r; return fmi2Error;
}

/* ---- Model Exchange ------------------------------------------------------------------ */
fmi2Status fmi2EnterEventMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) {
    (void)c;
    e->newDiscreteStatesNeeded = fmi2False; e->terminateSimulation = fmi2False;
    e->nominalsOfContinuousStatesChanged = fmi2False; e->valuesOfContinuousStatesChanged = fmi2False;
    e->nextEventTimeDefined = fmi2False; e->nextEventTime = 0.0;
    return fmi2OK;
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSet, fmi2Boolean *enter, fmi2Boolean *term) {
    (void)c; (void)noSet; *enter = fmi2False; *term = fmi2False; return fmi2OK;
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((Model *)c)->time = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    Model *m = (Model *)c;
    if (n != 2) return fmi2Error;
    m->v[VR_POSITION] = x[0]; m->v[VR_VELOCITY] = x[1];
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    Model *m = (Model *)c;
    double x[2] = {m->v[VR_POSITION], m->v[VR_VELOCITY]};
    if (n != 2) return fmi2Error;
    derivatives(m, x, m->v[VR_FORCE], dx);
    return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { (void)c; (void)z; return n == 0 ? fmi2OK : fmi2Error; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    Model *m = (Model *)c;
    if (n != 2) return fmi2Error;
    x[0] = m->v[VR_POSITION]; x[1] = m->v[VR_VELOCITY];
    return fmi2OK;
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    size_t i; (void)c; for (i = 0; i < n; i++) x[i] = 1.0; return fmi2OK;
}

/* ---- Co-Simulation ------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], const fmi2Real v[]) {
    (void)c; (void)vr; (void)n; (void)o; (void)v; return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], fmi2Real v[]) {
    (void)c; (void)vr; (void)n; (void)o; (void)v; return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real H, fmi2Boolean noPrior) {
    Model *m = (Model *)c;
    double n;
    long i, steps;
    (void)noPrior;
    if (!(isfinite(H) && H > 0)) {
        logmsg(m, fmi2Error, "logStatusError", "communication step size must be > 0");
        return fmi2Error;
    }
#ifdef MISBEHAVE_AFTER  /* a plant that misbehaves (tests) at its first step from then on */
    if (t >= MISBEHAVE_AFTER) {
#if MISBEHAVE == 1      /* never returns */
        volatile unsigned long spin = 0;
        for (;;) spin++;
#elif MISBEHAVE == 2    /* ends the host's process, status 0 */
        exit(0);
#else                   /* crashes the host's process */
        raise(SIGSEGV);
#endif
    }
#endif
    n = ceil(H / m->v[VR_SUBSTEP] * (1.0 - 1e-12));
    steps = n < 1 ? 1 : (long)n;
    for (i = 0; i < steps; i++) rk4(m, H / (double)steps);
    m->time = t + H;
    if (!(isfinite(m->v[VR_POSITION]) && isfinite(m->v[VR_VELOCITY]))) {
        logmsg(m, fmi2Error, "logStatusError", "the state is no longer finite");
        return fmi2Error;
    }
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    if (s == fmi2LastSuccessfulTime) { *v = ((Model *)c)->time; return fmi2OK; }
    return fmi2Discard;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
