/* A small closed-loop FMI 2.0 co-simulation host in C (no Python anywhere).
 *
 * Runs the loop  plant -> meas_delay -> controller -> input_delay -> plant  of delaycomp's
 * scenarios (LTI, scalar or with vectors, and model files' nonlinear loops: n states, m
 * inputs; either delay may be a network channel, the controller the time-stamp one), with
 * the FMUs unpacked in four folders (the two delays may share one). Value references,
 * types, GUIDs and model identifiers are read from each folder's modelDescription.xml.
 * Each FMU's Real outputs feed the next FMU's Real inputs (wire()): a `stamp` output to a
 * `stamp` input (a channel's send time to the time-stamp controller; a `stamp` the next
 * FMU has no input for stays unconnected, a `stamp` input needs a `stamp` output); the
 * other outputs by name where every input finds its name among them and the counts agree
 * (a channel's y1 .. yn to the controller's y1 .. yn), else in the order of the
 * modelDescriptions where the counts agree (plant x1 .. xn to the measurement delay's
 * u1 .. un, a channel's y1 .. ym to the plant's u1 .. um). Anything else is refused before
 * any step, in one line naming the FMU and the variable. The step order is delaycomp's
 * master (Gauss-Seidel along the signal chain, orchestrator/master.py):
 * at t_k = t0 + k h the plant's state is read, passed through the measurement delay to the
 * controller, the control through the input delay to the plant (each FMU's outputs read
 * all at once, its inputs set all at once); then every FMU steps from t_k to t_{k+1}. One
 * CSV row per tick, written to stdout after the run: time, the plant's outputs, the
 * controller's outputs (%.17g, exact), headed plant.NAME, controller.NAME.
 *
 * usage: host [--timing] [--exact-grid] [--start=T0] STOP_TIME H plant=DIR meas_delay=DIR
 *             controller=DIR
 *             input_delay=DIR [INSTANCE.VARIABLE=VALUE ...]
 * --timing: print the wall time of the stepping loop (initialization excluded) to stderr.
 * --start=T0: the experiment starts at T0 (fmi2SetupExperiment's startTime; default 0) and
 *   ends at STOP_TIME, after round((STOP_TIME - T0) / H) steps.
 * --exact-grid: step as the FMI guides ask an importer to keep time: t_k = t0 + k h computed
 *   from k, each step t_{k+1} - t_k (steps that differ from H and from one another in the
 *   last bits). Default: every step is H, from t_k = t0 + k h.
 * Build: cc -std=c11 -O2 -Wall -Wextra -Werror -I<fmi2 headers> host.c -o host -ldl -lm
 * (delaycomp.fmu.host.compile_host). The same source builds for Windows (mingw-w64: it loads
 * binaries/win64/ID.dll with LoadLibrary) and Linux on aarch64 (binaries/aarch64-linux/).
 */
#define _POSIX_C_SOURCE 200809L
#if defined(_WIN32)
#include <windows.h>
#define PLATFORM "win64"            /* FMI 2.0's folder and suffix for this platform */
#define LIBRARY_SUFFIX ".dll"
#else
#include <dlfcn.h>
#if defined(__aarch64__)
#define PLATFORM "aarch64-linux"    /* FMI 2.0.4+: the FMI 3.0 platform tuple */
#else
#define PLATFORM "linux64"
#endif
#define LIBRARY_SUFFIX ".so"
#endif
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

#define NI 4
static const char *const NAMES[NI] = {"plant", "meas_delay", "controller", "input_delay"};

typedef struct {
    char name[256];
    char causality[32];
    char type;                   /* r(eal), i(nteger), b(oolean), s(tring), ? (another) */
    fmi2ValueReference vr;
} Var;

typedef struct {
    char dir[4096];
    char *xml;
    Var *vars;                   /* the ScalarVariables, in modelDescription order */
    size_t nvars;
    char guid[128], ident[256];
    void *lib;
    fmi2Component c;
    fmi2InstantiateTYPE *instantiate;
    fmi2FreeInstanceTYPE *free_instance;
    fmi2SetupExperimentTYPE *setup;
    fmi2EnterInitializationModeTYPE *enter;
    fmi2ExitInitializationModeTYPE *exit_init;
    fmi2TerminateTYPE *terminate;
    fmi2SetRealTYPE *set_real;
    fmi2GetRealTYPE *get_real;
    fmi2SetBooleanTYPE *set_boolean;
    fmi2SetStringTYPE *set_string;
    fmi2SetIntegerTYPE *set_integer;
    fmi2DoStepTYPE *do_step;
} Fmu;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env;
    va_list ap;
    va_start(ap, message);
    fprintf(stderr, "[%s %d %s] ", name, (int)status, category);
    vfprintf(stderr, message, ap);
    fputc('\n', stderr);
    va_end(ap);
}

static void die(const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    fputs("host: error: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    exit(1);
}

static char *read_file(const char *path) {
    FILE *f = fopen(path, "rb");
    if (f == NULL) die("cannot read %s", path);
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *text = malloc((size_t)size + 1);
    if (text == NULL || fread(text, 1, (size_t)size, f) != (size_t)size) die("cannot read %s", path);
    text[size] = '\0';
    fclose(f);
    return text;
}

/* the value of attribute `attr` in the tag that starts at `tag` (up to its '>') */
static int attribute(const char *tag, const char *attr, char *out, size_t size) {
    const char *end = strchr(tag, '>');
    char key[64];
    snprintf(key, sizeof key, " %s=\"", attr);
    const char *p = strstr(tag, key);
    if (p == NULL || (end && p > end)) return 0;
    p += strlen(key);
    const char *q = strchr(p, '"');
    if (q == NULL || (size_t)(q - p) >= size) return 0;
    memcpy(out, p, (size_t)(q - p));
    out[q - p] = '\0';
    return 1;
}

/* the variable table of a modelDescription, read once (a 40-state loop sets thousands of
 * parameters: a scan of the XML per name would take seconds) */
static void read_variables(Fmu *f) {
    size_t cap = 0;
    char vr[32];
    for (const char *p = strstr(f->xml, "<ScalarVariable"); p; p = strstr(p + 1, "<ScalarVariable")) {
        if (f->nvars == cap) {
            cap = cap ? 2 * cap : 64;
            f->vars = realloc(f->vars, cap * sizeof *f->vars);
            if (f->vars == NULL) die("out of memory");
        }
        Var *v = &f->vars[f->nvars];
        if (!attribute(p, "name", v->name, sizeof v->name) ||
            !attribute(p, "valueReference", vr, sizeof vr))
            die("%s: a ScalarVariable without name or valueReference", f->dir);
        if (!attribute(p, "causality", v->causality, sizeof v->causality))
            strcpy(v->causality, "local");
        v->vr = (fmi2ValueReference)strtoul(vr, NULL, 10);
        const char *t = strchr(p, '>');
        if (t == NULL) die("%s: a ScalarVariable without its end", f->dir);
        while (*t && *t != '<') t++;
        v->type = strncmp(t, "<Real", 5) == 0 ? 'r' : strncmp(t, "<Boolean", 8) == 0 ? 'b'
                  : strncmp(t, "<String", 7) == 0 ? 's' : strncmp(t, "<Integer", 8) == 0 ? 'i'
                  : '?';
        f->nvars++;
    }
}

/* value reference and type (Real, Integer, Boolean, String) of variable `name` */
static fmi2ValueReference lookup(const Fmu *f, const char *name, char *type) {
    for (size_t i = 0; i < f->nvars; i++) {
        if (strcmp(f->vars[i].name, name) != 0) continue;
        if (f->vars[i].type == '?') die("%s: unsupported type", name);
        *type = f->vars[i].type;
        return f->vars[i].vr;
    }
    die("%s has no variable %s", f->dir, name);
    return 0;
}

/* the Real variables of causality `causality`, in modelDescription order: their value
 * references into vrs[] and names into names[] (at most max); returns how many */
static size_t ports(const Fmu *f, const char *causality, fmi2ValueReference *vrs,
                    const char **names, size_t max) {
    size_t n = 0;
    for (size_t i = 0; i < f->nvars; i++) {
        const Var *v = &f->vars[i];
        if (v->type != 'r' || strcmp(v->causality, causality) != 0) continue;
        if (n == max) die("%s: more than %zu %ss", f->dir, max, causality);
        names[n] = v->name;
        vrs[n++] = v->vr;
    }
    return n;
}

/* the shared library of an FMU: dlopen, or LoadLibrary on Windows */
#if defined(_WIN32)
static void *open_library(const char *path) { return (void *)LoadLibraryA(path); }
static void *library_symbol(void *lib, const char *name) {
    FARPROC p = GetProcAddress((HMODULE)lib, name);
    void *q;
    memcpy(&q, &p, sizeof q);  /* a function pointer as the data pointer the callers cast */
    return q;
}
static void close_library(void *lib) { FreeLibrary((HMODULE)lib); }
static const char *library_error(void) { return "LoadLibrary failed"; }
#else
static void *open_library(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static void *library_symbol(void *lib, const char *name) { return dlsym(lib, name); }
static void close_library(void *lib) { dlclose(lib); }
static const char *library_error(void) { return dlerror(); }
#endif

static void *sym(Fmu *f, const char *name) {
    void *p = library_symbol(f->lib, name);
    if (p == NULL) die("%s: no symbol %s", f->ident, name);
    return p;
}

static void load(Fmu *f, const char *instance, fmi2CallbackFunctions *cb) {
    char path[8192];
    snprintf(path, sizeof path, "%s/modelDescription.xml", f->dir);
    f->xml = read_file(path);
    const char *root = strstr(f->xml, "<fmiModelDescription");
    const char *cs = strstr(f->xml, "<CoSimulation");
    if (!root || !cs || !attribute(root, "guid", f->guid, sizeof f->guid) ||
        !attribute(cs, "modelIdentifier", f->ident, sizeof f->ident))
        die("%s: not a co-simulation FMU", f->dir);
    read_variables(f);
    snprintf(path, sizeof path, "%s/binaries/" PLATFORM "/%s" LIBRARY_SUFFIX, f->dir, f->ident);
    f->lib = open_library(path);
    if (f->lib == NULL) die("cannot load %s: %s", path, library_error());
    f->instantiate = (fmi2InstantiateTYPE *)sym(f, "fmi2Instantiate");
    f->free_instance = (fmi2FreeInstanceTYPE *)sym(f, "fmi2FreeInstance");
    f->setup = (fmi2SetupExperimentTYPE *)sym(f, "fmi2SetupExperiment");
    f->enter = (fmi2EnterInitializationModeTYPE *)sym(f, "fmi2EnterInitializationMode");
    f->exit_init = (fmi2ExitInitializationModeTYPE *)sym(f, "fmi2ExitInitializationMode");
    f->terminate = (fmi2TerminateTYPE *)sym(f, "fmi2Terminate");
    f->set_real = (fmi2SetRealTYPE *)sym(f, "fmi2SetReal");
    f->get_real = (fmi2GetRealTYPE *)sym(f, "fmi2GetReal");
    f->set_boolean = (fmi2SetBooleanTYPE *)sym(f, "fmi2SetBoolean");
    f->set_string = (fmi2SetStringTYPE *)sym(f, "fmi2SetString");
    f->set_integer = (fmi2SetIntegerTYPE *)sym(f, "fmi2SetInteger");
    f->do_step = (fmi2DoStepTYPE *)sym(f, "fmi2DoStep");
    snprintf(path, sizeof path, "file://%s/resources", f->dir);
    f->c = f->instantiate(instance, fmi2CoSimulation, f->guid, path, cb, fmi2False, fmi2False);
    if (f->c == NULL) die("%s: fmi2Instantiate failed", instance);
}

#define CHECK(call, what) do { if ((call) > fmi2Warning) die("%s failed", what); } while (0)

static void put(Fmu *f, fmi2ValueReference vr, double v) {
    CHECK(f->set_real(f->c, &vr, 1, &v), "fmi2SetReal");
}

#define MAXPORTS 1000  /* the largest dimension of a delaycomp FMU */

typedef struct {           /* the Real inputs and outputs of one FMU */
    size_t nin, nout;
    fmi2ValueReference in[MAXPORTS], out[MAXPORTS];
    const char *in_name[MAXPORTS], *out_name[MAXPORTS];
} Ports;

/* How FMU i's Real outputs feed FMU j's Real inputs: input q of j receives output from[q]
 * of i (indices into the Ports). A `stamp` output goes to a `stamp` input, or nowhere if j
 * has none; a `stamp` input needs a `stamp` output. The other outputs go to the other
 * inputs by name when every input finds its name and the counts agree, else in order when
 * the counts agree; else the first variable left unconnected is named and the run refused. */
static void wire(int i, int j, const Ports *s, const Ports *d, size_t *from) {
    size_t so = s->nout, di = d->nin;  /* the stamps' indices; nout, nin: none */
    for (size_t q = 0; q < s->nout; q++) if (strcmp(s->out_name[q], "stamp") == 0) so = q;
    for (size_t q = 0; q < d->nin; q++) if (strcmp(d->in_name[q], "stamp") == 0) di = q;
    if (di < d->nin && so == s->nout)
        die("cannot connect %s.stamp: %s has no Real output stamp (the send time a network "
            "channel gives)", NAMES[j], NAMES[i]);
    if (di < d->nin) from[di] = so;
    size_t nsig = s->nout - (so < s->nout), nin = d->nin - (di < d->nin), named = 0;
    if (nsig == 0) die("%s has no Real output to feed %s", NAMES[i], NAMES[j]);
    for (size_t q = 0; q < d->nin; q++) {  /* by name */
        if (q == di) continue;
        for (size_t p = 0; p < s->nout; p++)
            if (p != so && strcmp(s->out_name[p], d->in_name[q]) == 0) { from[q] = p; named++; }
    }
    if (named == nin && nin == nsig) return;
    if (nin == nsig) {  /* in order */
        size_t p = 0;
        for (size_t q = 0; q < d->nin; q++) {
            if (q == di) continue;
            if (p == so) p++;
            from[q] = p++;
        }
        return;
    }
    for (size_t q = 0; q < d->nin; q++) {  /* refused: the first input without an output */
        size_t p = 0;
        while (p < s->nout && (p == so || strcmp(s->out_name[p], d->in_name[q]) != 0)) p++;
        if (q != di && p == s->nout)
            die("cannot connect %s.%s: %s has no Real output %s, and its %zu Real outputs "
                "(a stamp aside) cannot go in order to %s's %zu Real inputs", NAMES[j],
                d->in_name[q], NAMES[i], d->in_name[q], nsig, NAMES[j], nin);
    }
    for (size_t p = 0; p < s->nout; p++) {  /* or the first output without an input */
        size_t q = 0;
        while (q < d->nin && (q == di || strcmp(s->out_name[p], d->in_name[q]) != 0)) q++;
        if (p != so && q == d->nin)
            die("cannot connect %s.%s: %s has no Real input %s, and %s's %zu Real outputs "
                "(a stamp aside) cannot go in order to its %zu Real inputs", NAMES[i],
                s->out_name[p], NAMES[j], s->out_name[p], NAMES[i], nsig, nin);
    }
    die("cannot connect %s to %s", NAMES[i], NAMES[j]);  /* not reached: names are unique */
}

static double now(void) {
#if defined(_WIN32)
    LARGE_INTEGER count, frequency;
    QueryPerformanceCounter(&count);
    QueryPerformanceFrequency(&frequency);
    return (double)count.QuadPart / (double)frequency.QuadPart;
#else
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
#endif
}

int main(int argc, char **argv) {
    int timing = 0, exact_grid = 0;
    double t0 = 0.0;
    while (argc > 1 && strncmp(argv[1], "--", 2) == 0) {
        char *end;
        if (strcmp(argv[1], "--timing") == 0) timing = 1;
        else if (strcmp(argv[1], "--exact-grid") == 0) exact_grid = 1;
        else if (strncmp(argv[1], "--start=", 8) == 0 &&
                 (t0 = strtod(argv[1] + 8, &end), *end == '\0' && end != argv[1] + 8 &&
                  isfinite(t0))) {}
        else die("unknown option %s (allowed: --timing, --exact-grid, --start=T0)", argv[1]);
        argv++;
        argc--;
    }
    if (argc < 7) die("usage: host [--timing] [--exact-grid] [--start=T0] STOP_TIME H plant=DIR "
                      "meas_delay=DIR controller=DIR input_delay=DIR "
                      "[INSTANCE.VARIABLE=VALUE ...]");
    double stop = strtod(argv[1], NULL), h = strtod(argv[2], NULL);
    if (!(h > 0) || !(stop > t0)) die("H must be > 0 and STOP_TIME > T0");
    static Fmu fmu[NI];
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    for (int i = 0; i < NI; i++) {
        const char *arg = argv[3 + i];
        size_t len = strlen(NAMES[i]);
        if (strncmp(arg, NAMES[i], len) != 0 || arg[len] != '=') die("expected %s=DIR", NAMES[i]);
        snprintf(fmu[i].dir, sizeof fmu[i].dir, "%s", arg + len + 1);
        load(&fmu[i], NAMES[i], &cb);
        CHECK(fmu[i].setup(fmu[i].c, fmi2False, 0.0, t0, fmi2True, stop), "fmi2SetupExperiment");
        CHECK(fmu[i].enter(fmu[i].c), "fmi2EnterInitializationMode");
    }
    static Ports io[NI];
    for (int i = 0; i < NI; i++) {
        io[i].nin = ports(&fmu[i], "input", io[i].in, io[i].in_name, MAXPORTS);
        io[i].nout = ports(&fmu[i], "output", io[i].out, io[i].out_name, MAXPORTS);
    }
    static size_t from[NI][MAXPORTS];  /* from[i][q]: the output of FMU i that input q of
                                          FMU i + 1 receives */
    for (int i = 0; i < NI; i++) wire(i, (i + 1) % NI, &io[i], &io[(i + 1) % NI], from[i]);
    for (int a = 7; a < argc; a++) {  /* INSTANCE.VARIABLE=VALUE */
        char buf[512];
        snprintf(buf, sizeof buf, "%s", argv[a]);
        char *dot = strchr(buf, '.'), *eq = strchr(buf, '=');
        if (!dot || !eq || eq < dot) die("bad setting %s", argv[a]);
        *dot = *eq = '\0';
        int i = 0;
        while (i < NI && strcmp(NAMES[i], buf) != 0) i++;
        if (i == NI) die("no instance %s", buf);
        char type;
        fmi2ValueReference vr = lookup(&fmu[i], dot + 1, &type);
        const char *value = eq + 1;
        if (type == 'r') {
            put(&fmu[i], vr, strtod(value, NULL));
        } else if (type == 'i') {
            char *end;
            long k = strtol(value, &end, 10);
            if (*value == '\0' || *end != '\0' || k < -2147483647L || k > 2147483647L)
                die("%s: %s is not an Integer", argv[a], value);
            fmi2Integer ki = (fmi2Integer)k;
            CHECK(fmu[i].set_integer(fmu[i].c, &vr, 1, &ki), "fmi2SetInteger");
        } else if (type == 'b') {
            fmi2Boolean b = strcmp(value, "true") == 0 || strcmp(value, "1") == 0;
            CHECK(fmu[i].set_boolean(fmu[i].c, &vr, 1, &b), "fmi2SetBoolean");
        } else {
            CHECK(fmu[i].set_string(fmu[i].c, &vr, 1, &value), "fmi2SetString");
        }
    }
    for (int i = 0; i < NI; i++) CHECK(fmu[i].exit_init(fmu[i].c), "fmi2ExitInitializationMode");
    size_t nx = io[0].nout, nu = io[2].nout, width = 1 + nx + nu;
    long ticks = lround((stop - t0) / h);
    double *rows = malloc(width * (size_t)(ticks + 1) * sizeof(double));  /* printed at the end */
    double *v = malloc(MAXPORTS * sizeof(double)), *w = malloc(MAXPORTS * sizeof(double));
    if (rows == NULL || v == NULL || w == NULL) die("out of memory");
    double started = now();
    for (long k = 0;; k++) {
        double t = t0 + (double)k * h;  /* t_k = t0 + k h */
        double *row = rows + width * (size_t)k;
        row[0] = t;
        for (int i = 0; i < NI; i++) {  /* plant, meas_delay, controller, input_delay */
            Fmu *src = &fmu[i], *dst = &fmu[(i + 1) % NI];
            const Ports *ps = &io[i], *pd = &io[(i + 1) % NI];
            CHECK(src->get_real(src->c, ps->out, ps->nout, v), "fmi2GetReal");
            for (size_t q = 0; q < pd->nin; q++) w[q] = v[from[i][q]];
            CHECK(dst->set_real(dst->c, pd->in, pd->nin, w), "fmi2SetReal");
            if (i == 0) memcpy(row + 1, v, nx * sizeof(double));
            if (i == 2) memcpy(row + 1 + nx, v, nu * sizeof(double));
        }
        if (k == ticks) break;
        /* the exact grid: t_{k+1} - t_k with both times computed from their index */
        double step = exact_grid ? (t0 + (double)(k + 1) * h) - t : h;
        for (int i = 0; i < NI; i++)
            CHECK(fmu[i].do_step(fmu[i].c, t, step, fmi2True), "fmi2DoStep");
    }
    if (timing) fprintf(stderr, "host: %ld ticks in %.9f s\n", ticks, now() - started);
    printf("time");
    for (size_t j = 0; j < nx; j++) printf(",plant.%s", io[0].out_name[j]);
    for (size_t j = 0; j < nu; j++) printf(",controller.%s", io[2].out_name[j]);
    printf("\n");
    for (long k = 0; k <= ticks; k++) {
        const double *row = rows + width * (size_t)k;
        printf("%.17g", row[0]);
        for (size_t j = 1; j < width; j++) printf(",%.17g", row[j]);
        printf("\n");
    }
    free(rows);
    free(v);
    free(w);
    for (int i = 0; i < NI; i++) {
        CHECK(fmu[i].terminate(fmu[i].c), "fmi2Terminate");
        fmu[i].free_instance(fmu[i].c);
    }
    for (int i = 0; i < NI; i++) {
        close_library(fmu[i].lib);
        free(fmu[i].xml);
        free(fmu[i].vars);
    }
    return 0;
}
