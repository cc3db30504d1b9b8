/* Drive: a test plant FMU that behaves like a Modelica tool's export (FMI 2.0, CS + ME).
 *
 * Hidden continuous states (locals, as Modelica tools keep them), outputs that are a
 * function of them, its own variable-step solver with a tolerance, extra inputs, dotted
 * names, info messages and solver statistics through the logger:
 *
 *   der(body.phi) = body.w
 *   der(body.w)   = (motor.tau + load.tau - spring.c * body.phi
 *                    - (damper.d + brake.engaged * brake.d) * body.w) / body.J
 *   sensor.phi    = fixed.phi0 - body.phi - sensor.cubic * body.phi^3
 *   sensor.w      = -body.w - sensor.mix * body.phi
 *
 * Co-simulation: doStep integrates with the embedded Heun-Euler 2(1) pair, its step size
 * controlled to rtol = atol = the tolerance passed to fmi2SetupExperiment (default 1e-4,
 * as Dymola's), inputs held over the step: the tolerance shows in the results. See README.md beside this file.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define INSTANTIATION_TOKEN "{0d7e3c8a-5b1f-4f6e-8d2a-delaycompdrv1}"
#define DEFAULT_TOLERANCE 1e-4

enum { VR_PHI, VR_W, VR_DER_PHI, VR_DER_W, VR_SENSOR_PHI, VR_SENSOR_W, VR_MOTOR_TAU,
       VR_LOAD_TAU, VR_SPRING_C, VR_DAMPER_D, VR_BODY_J, VR_FIXED_PHI0, VR_CUBIC, VR_MIX,
       VR_BRAKE_D, N_VR };
enum { VB_BRAKE, N_VB };
#define FIRST_PARAMETER VR_SPRING_C

typedef struct {
    double v[N_VR];
    int b[N_VB];
    double time, tol;
    int cs, initialized, logging;
    long steps, rejected, evaluations, calls;
    double hmin, hmax, hlast;
    fmi2CallbackFunctions cb;
    const char *name;
} Model;

static void logf_(Model *m, fmi2Status s, const char *cat, const char *fmt, ...) {
    char buf[300];
    va_list ap;
    if (!m->cb.logger) return;  /* info too, whatever loggingOn says (as tools' exports do) */
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    m->cb.logger(m->cb.componentEnvironment, m->name, s, cat, "%s", buf);
}

static double friction(const Model *m) {
    return m->v[VR_DAMPER_D] + (m->b[VB_BRAKE] ? m->v[VR_BRAKE_D] : 0.0);
}

static void derivatives(Model *m, const double x[2], double dx[2]) {
    dx[0] = x[1];
    dx[1] = (m->v[VR_MOTOR_TAU] + m->v[VR_LOAD_TAU] - m->v[VR_SPRING_C] * x[0]
             - friction(m) * x[1]) / m->v[VR_BODY_J];
    m->evaluations++;
}

static void update(Model *m) {
    double x[2] = {m->v[VR_PHI], m->v[VR_W]}, dx[2];
    derivatives(m, x, dx);
    m->v[VR_DER_PHI] = dx[0];
    m->v[VR_DER_W] = dx[1];
    m->v[VR_SENSOR_PHI] = m->v[VR_FIXED_PHI0] - x[0] - m->v[VR_CUBIC] * x[0] * x[0] * x[0];
    m->v[VR_SENSOR_W] = -x[1] - m->v[VR_MIX] * x[0];
}

/* one Heun-Euler 2(1) step of size h from x: Heun's (2nd order) result in y, its difference
 * from Euler's (the local error estimate of the 1st-order result) in e */
static void heun(Model *m, const double x[2], double h, double y[2], double e[2]) {
    double k1[2], k2[2], z[2];
    int i;
    derivatives(m, x, k1);
    for (i = 0; i < 2; i++) z[i] = x[i] + h * k1[i];
    derivatives(m, z, k2);
    for (i = 0; i < 2; i++) {
        y[i] = x[i] + 0.5 * h * (k1[i] + k2[i]);
        e[i] = 0.5 * h * (k2[i] - k1[i]);
    }
}

/* integrate over [0, H] with the step size controlled to rtol = atol = tol */
static int integrate(Model *m, double H) {
    double x[2] = {m->v[VR_PHI], m->v[VR_W]}, y[2], e[2], t = 0.0;
    double h = m->hlast > 0 ? m->hlast : H, err, sc;
    int i, guard = 0;
    while (t < H) {
        if (h > H - t || H - t - h < 1e-12 * H) h = H - t;
        heun(m, x, h, y, e);
        err = 0.0;
        for (i = 0; i < 2; i++) {
            sc = m->tol + m->tol * fmax(fabs(x[i]), fabs(y[i]));
            err += (e[i] / sc) * (e[i] / sc);
        }
        err = sqrt(err / 2.0);
        if (!isfinite(err)) return 0;
        if (err <= 1.0) {
            t = (H - t - h < 1e-12 * H) ? H : t + h;
            x[0] = y[0]; x[1] = y[1];
            m->steps++;
            if (m->hmin == 0 || h < m->hmin) m->hmin = h;
            if (h > m->hmax) m->hmax = h;
            if (t < H) m->hlast = h;
        } else {
            m->rejected++;
        }
        h *= fmin(5.0, fmax(0.2, 0.9 * pow(err > 0 ? err : 1e-10, -0.5)));
        if (++guard > 10000000) return 0;
    }
    m->v[VR_PHI] = x[0];
    m->v[VR_W] = x[1];
    return 1;
}

static int check_parameters(Model *m) {
    if (!(isfinite(m->v[VR_BODY_J]) && m->v[VR_BODY_J] > 0)) {
        logf_(m, fmi2Error, "logStatusError",
              "body.J = %g is not allowed: must be a finite number > 0", m->v[VR_BODY_J]);
        return 0;
    }
    if (!(isfinite(m->tol) && m->tol > 0 && m->tol < 1)) {
        logf_(m, fmi2Error, "logStatusError",
              "tolerance = %g is not allowed: must be in (0, 1)", m->tol);
        return 0;
    }
    return 1;
}

/* ---- common ---------------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)n; (void)cats; ((Model *)c)->logging = on ? 1 : 0; return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String location, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Model *m;
    (void)location; (void)visible;
    if (!cb || !guid || strcmp(guid, INSTANTIATION_TOKEN) != 0) return NULL;
    m = (Model *)calloc(1, sizeof(Model));
    if (!m) return NULL;
    m->cb = *cb;
    m->name = name ? strdup(name) : strdup("drive");
    m->cs = type == fmi2CoSimulation;
    m->logging = loggingOn ? 1 : 0;
    m->tol = DEFAULT_TOLERANCE;
    m->v[VR_SPRING_C] = -1.0;
    m->v[VR_DAMPER_D] = 0.2;
    m->v[VR_BODY_J] = 1.0;
    m->v[VR_BRAKE_D] = 5.0;
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
    Model *m = (Model *)c;
    (void)stopDef; (void)stop;
    if (tolDef) m->tol = tol;
    m->time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Model *m = (Model *)c;
    if (!check_parameters(m)) return fmi2Error;
    m->initialized = 1;
    update(m);
    logf_(m, fmi2OK, "logEvents", "Integration started at T = %g with tolerance %g "
          "(Heun-Euler 2(1))", m->time, m->tol);
    if (m->tol > 1e-3)
        logf_(m, fmi2Warning, "logStatusWarning", "tolerance %g is larger than 1e-3: the "
              "results may be inaccurate", m->tol);
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Model *m = (Model *)c;
    if (m->cs && m->initialized) {  /* as a tool's export prints: the solver's statistics */
        logf_(m, fmi2OK, "logStatistics", "Integration terminated successfully at T = %g",
              m->time);
        logf_(m, fmi2OK, "logStatistics", "   CPU-time for integration      : %g s", 0.0);
        logf_(m, fmi2OK, "logStatistics", "   Number of result points        : %g",
              (double)m->calls);
        logf_(m, fmi2OK, "logStatistics", "   Number of accepted steps       : %g",
              (double)m->steps);
        logf_(m, fmi2OK, "logStatistics", "   Number of rejected steps       : %g",
              (double)m->rejected);
        logf_(m, fmi2OK, "logStatistics", "   Number of f-evaluations (dynamics) : %g",
              (double)m->evaluations);
        logf_(m, fmi2OK, "logStatistics", "   Minimum / maximum step size : %g / %g",
              m->hmin, m->hmax);
        logf_(m, fmi2OK, "logStatistics", "   Tolerance used                : %g", m->tol);
    }
    return fmi2OK;
}
fmi2Status fmi2Reset(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Model *m = (Model *)c;
    size_t i;
    if (m->v[VR_BODY_J] > 0) update(m);
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_VR) {
            logf_(m, fmi2Error, "logStatusError", "unknown value reference %g", (double)vr[i]);
            return fmi2Error;
        }
        value[i] = m->v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Model *m = (Model *)c;
    size_t i;
    for (i = 0; i < n; i++) {
        fmi2ValueReference r = vr[i];
        int state = r == VR_PHI || r == VR_W, input = r == VR_MOTOR_TAU || r == VR_LOAD_TAU;
        if (r >= N_VR || r == VR_DER_PHI || r == VR_DER_W || r == VR_SENSOR_PHI
            || r == VR_SENSOR_W || (state && m->initialized)) {
            logf_(m, fmi2Error, "logStatusError", "the variable of value reference %g cannot "
                  "be set", (double)r);
            return fmi2Error;
        }
        if (m->initialized && r >= FIRST_PARAMETER) {
            logf_(m, fmi2Error, "logStatusError", "a fixed parameter (value reference %g) "
                  "cannot be set after initialization", (double)r);
            return fmi2Error;
        }
        if (input && !isfinite(value[i])) {
            logf_(m, fmi2Error, "logStatusError", "input %g is not a finite number",
                  (double)r);
            return fmi2Error;
        }
        m->v[r] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    Model *m = (Model *)c;
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_VB) return fmi2Error;
        value[i] = m->b[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    Model *m = (Model *)c;
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_VB) return fmi2Error;
        m->b[vr[i]] = value[i] ? 1 : 0;
    }
    return fmi2OK;
}

#define NO_TYPE(T, V) \
fmi2Status fmi2Get##T(fmi2Component c, const fmi2ValueReference vr[], size_t n, V value[]) { \
    (void)c; (void)vr; (void)value; return n == 0 ? fmi2OK : fmi2Error; } \
fmi2Status fmi2Set##T(fmi2Component c, const fmi2ValueReference vr[], size_t n, const V value[]) { \
    (void)c; (void)vr; (void)value; return n == 0 ? fmi2OK : fmi2Error; }
NO_TYPE(Integer, fmi2Integer)
NO_TYPE(String, fmi2String)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { (void)c; (void)s; (void)n; return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { (void)c; (void)s; (void)b; (void)n; return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) { (void)c; (void)b; (void)n; (void)s; return fmi2Error; }

#ifndef NO_DIRECTIONAL
/* d(unknown)/d(known) of the linearization at the current point */
static int partial(const Model *m, fmi2ValueReference y, fmi2ValueReference k, double *d) {
    double phi = m->v[VR_PHI], J = m->v[VR_BODY_J];
    *d = 0.0;
    switch (y) {
    case VR_DER_PHI: *d = k == VR_W ? 1.0 : 0.0; return 1;
    case VR_DER_W:
        if (k == VR_PHI) *d = -m->v[VR_SPRING_C] / J;
        else if (k == VR_W) *d = -friction(m) / J;
        else if (k == VR_MOTOR_TAU || k == VR_LOAD_TAU) *d = 1.0 / J;
        return 1;
    case VR_SENSOR_PHI: if (k == VR_PHI) *d = -1.0 - 3.0 * m->v[VR_CUBIC] * phi * phi; return 1;
    case VR_SENSOR_W:
        if (k == VR_PHI) *d = -m->v[VR_MIX];
        else if (k == VR_W) *d = -1.0;
        return 1;
    default: return 0;
    }
}
#endif

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknowns[], size_t nu,
                                        const fmi2ValueReference knowns[], size_t nk,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
#ifdef NO_DIRECTIONAL
    (void)c; (void)unknowns; (void)nu; (void)knowns; (void)nk; (void)dvKnown; (void)dvUnknown;
    return fmi2Error;
#else
    Model *m = (Model *)c;
    size_t i, j;
    double d;
    for (i = 0; i < nu; i++) {
        dvUnknown[i] = 0.0;
        for (j = 0; j < nk; j++) {
            if (!partial(m, unknowns[i], knowns[j], &d)) {
                logf_(m, fmi2Error, "logStatusError", "no directional derivative of value "
                      "reference %g", (double)unknowns[i]);
                return fmi2Error;
            }
            dvUnknown[i] += d * dvKnown[j];
        }
    }
    return fmi2OK;
#endif
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
    m->v[VR_PHI] = x[0]; m->v[VR_W] = x[1];
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    Model *m = (Model *)c;
    double x[2] = {m->v[VR_PHI], m->v[VR_W]};
    if (n != 2) return fmi2Error;
    derivatives(m, x, dx);
    return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { (void)c; (void)z; return n == 0 ? fmi2OK : fmi2Error; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    Model *m = (Model *)c;
    if (n != 2) return fmi2Error;
    x[0] = m->v[VR_PHI]; x[1] = m->v[VR_W];
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
    (void)noPrior;
    if (!(isfinite(H) && H > 0)) {
        logf_(m, fmi2Error, "logStatusError", "communication step size %g must be > 0", H);
        return fmi2Error;
    }
    m->calls++;
    if (!integrate(m, H)) {
        logf_(m, fmi2Error, "logStatusError", "integration failed at T = %g", t);
        return fmi2Error;
    }
    m->time = t + H;
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
