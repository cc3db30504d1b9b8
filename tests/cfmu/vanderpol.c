/* VanDerPol: a test plant FMU in C shaped like the modelica/Reference-FMUs' Van der Pol
 * oscillator (FMI 2.0, co-simulation and Model Exchange), with a control input u:
 *
 *   x0' = x1
 *   x1' = mu (1 - x0^2) x1 - x0 + u
 *
 * Its continuous states x0, x1 are its outputs, declared initial="exact" with start values
 * (2 and 0) and settable before initialization (Instantiated and Initialization Mode), as
 * FMI 2.0 allows for such variables; ModelStructure lists them with dependencies="".
 * Co-simulation: doStep(t, H) holds u and takes n = ceil(H / substep) equal classical
 * Runge-Kutta (RK4) steps of H / n. Directional derivatives are exact. See README.md.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define INSTANTIATION_TOKEN "{3d0b9c7e-51a2-4f0e-8c6d-delaycomp0vdp}"

enum { VR_TIME, VR_X0, VR_DER_X0, VR_X1, VR_DER_X1, VR_MU, VR_U, VR_SUBSTEP, N_VR };

/* where the instance is in FMI 2.0's state machine (what may be set when) */
enum { INSTANTIATED, INITIALIZING, RUNNING };

typedef struct {
    double v[N_VR];
    int cs;
    int phase;
    fmi2CallbackFunctions cb;
    char *name;
} Model;

static void fail(Model *m, const char *msg) {
    if (m->cb.logger) m->cb.logger(m->cb.componentEnvironment, m->name, fmi2Error,
                                   "logStatusError", "%s", msg);
}

static void rhs(const Model *m, const double x[2], double u, double dx[2]) {
    dx[0] = x[1];
    dx[1] = m->v[VR_MU] * (1.0 - x[0] * x[0]) * x[1] - x[0] + u;
}

static void refresh(Model *m) {
    double x[2] = {m->v[VR_X0], m->v[VR_X1]}, dx[2];
    rhs(m, x, m->v[VR_U], dx);
    m->v[VR_DER_X0] = dx[0];
    m->v[VR_DER_X1] = dx[1];
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
    m->name = strdup(name ? name : "vanderpol");
    m->cs = type == fmi2CoSimulation;
    m->phase = INSTANTIATED;
    m->v[VR_X0] = 2.0;  /* the start values of the modelDescription */
    m->v[VR_X1] = 0.0;
    m->v[VR_MU] = 1.0;
    m->v[VR_U] = 0.0;
    m->v[VR_SUBSTEP] = 0.01;
    return m;
}

void fmi2FreeInstance(fmi2Component c) {
    Model *m = (Model *)c;
    if (!m) return;
    free(m->name);
    free(m);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol,
                               fmi2Real start, fmi2Boolean stopDef, fmi2Real stop) {
    (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    ((Model *)c)->v[VR_TIME] = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ((Model *)c)->phase = INITIALIZING;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Model *m = (Model *)c;
    if (!(isfinite(m->v[VR_MU]) && isfinite(m->v[VR_X0]) && isfinite(m->v[VR_X1]))) {
        fail(m, "mu, x0 and x1 must be finite numbers");
        return fmi2Error;
    }
    if (!(isfinite(m->v[VR_SUBSTEP]) && m->v[VR_SUBSTEP] > 0)) {
        fail(m, "substep must be a finite number > 0");
        return fmi2Error;
    }
    m->phase = RUNNING;  /* the states start where they were set (or at their starts) */
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Model *m = (Model *)c;
    size_t i;
    refresh(m);
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_VR) { fail(m, "unknown value reference"); return fmi2Error; }
        value[i] = m->v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Model *m = (Model *)c;
    size_t i;
    for (i = 0; i < n; i++) {
        switch (vr[i]) {
        case VR_U:
            if (!isfinite(value[i])) { fail(m, "u is not a finite number"); return fmi2Error; }
            break;
        case VR_X0: case VR_X1:  /* outputs with initial = "exact": before initialization */
        case VR_MU: case VR_SUBSTEP:  /* fixed parameters */
            if (m->phase == RUNNING) {
                fail(m, "x0, x1, mu and substep can be set only before initialization ends");
                return fmi2Error;
            }
            break;
        default:
            fail(m, "variable cannot be set");
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

/* exact: d(unknown) = J d(known), knowns x0, x1, u (the states' outputs are the states) */
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknown[], size_t nu,
                                        const fmi2ValueReference known[], size_t nk,
                                        const fmi2Real seed[], fmi2Real out[]) {
    Model *m = (Model *)c;
    double d[N_VR] = {0}, x0 = m->v[VR_X0], x1 = m->v[VR_X1], mu = m->v[VR_MU];
    size_t i;
    for (i = 0; i < nk; i++) {
        if (known[i] != VR_X0 && known[i] != VR_X1 && known[i] != VR_U) {
            fail(m, "directional derivatives: the knowns are x0, x1 and u");
            return fmi2Error;
        }
        d[known[i]] += seed[i];
    }
    for (i = 0; i < nu; i++) {
        switch (unknown[i]) {
        case VR_X0: out[i] = d[VR_X0]; break;
        case VR_X1: out[i] = d[VR_X1]; break;
        case VR_DER_X0: out[i] = d[VR_X1]; break;
        case VR_DER_X1:
            out[i] = (-2.0 * mu * x0 * x1 - 1.0) * d[VR_X0] + mu * (1.0 - x0 * x0) * d[VR_X1]
                     + d[VR_U];
            break;
        default:
            fail(m, "directional derivatives: the unknowns are x0, x1 and their derivatives");
            return fmi2Error;
        }
    }
    return fmi2OK;
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
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((Model *)c)->v[VR_TIME] = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    Model *m = (Model *)c;
    if (n != 2) return fmi2Error;
    m->v[VR_X0] = x[0]; m->v[VR_X1] = x[1];
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    Model *m = (Model *)c;
    double x[2] = {m->v[VR_X0], m->v[VR_X1]};
    if (n != 2) return fmi2Error;
    rhs(m, x, m->v[VR_U], dx);
    return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { (void)c; (void)z; return n == 0 ? fmi2OK : fmi2Error; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    Model *m = (Model *)c;
    if (n != 2) return fmi2Error;
    x[0] = m->v[VR_X0]; x[1] = m->v[VR_X1];
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
    double x[2] = {m->v[VR_X0], m->v[VR_X1]}, u = m->v[VR_U], k[4][2], y[2], h, n;
    long s, steps;
    int i, j;
    (void)noPrior;
    if (!(isfinite(H) && H > 0)) { fail(m, "communication step size must be > 0"); return fmi2Error; }
    n = ceil(H / m->v[VR_SUBSTEP] * (1.0 - 1e-12));
    steps = n < 1 ? 1 : (long)n;
    h = H / (double)steps;
    for (s = 0; s < steps; s++) {  /* classical RK4 */
        rhs(m, x, u, k[0]);
        for (j = 1; j < 4; j++) {
            double a = j == 3 ? h : 0.5 * h;
            for (i = 0; i < 2; i++) y[i] = x[i] + a * k[j - 1][i];
            rhs(m, y, u, k[j]);
        }
        for (i = 0; i < 2; i++) x[i] += h / 6.0 * (k[0][i] + 2.0 * k[1][i] + 2.0 * k[2][i] + k[3][i]);
    }
    m->v[VR_X0] = x[0];
    m->v[VR_X1] = x[1];
    m->v[VR_TIME] = t + H;
    if (!(isfinite(x[0]) && isfinite(x[1]))) { fail(m, "the state is no longer finite"); return fmi2Error; }
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    if (s == fmi2LastSuccessfulTime) { *v = ((Model *)c)->v[VR_TIME]; return fmi2OK; }
    return fmi2Discard;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) { (void)c; (void)s; (void)v; return fmi2Discard; }
