/* The native stepping core: delaycomp's master (orchestrator/master.py) stepping a loop of
 * native FMUs from C, as a library that Python loads with ctypes
 * (delaycomp.orchestrator.native_core).
 *
 * Python instantiates, sets up and initializes every FMU (the master's setup() and
 * initialize(), through fmpy, unchanged), and terminates them at the end; in between it
 * hands this library each instance's pointer and its getter, setter and doStep functions,
 * and the master's per-tick plan: the list of reads and writes of one tick's propagation
 * (the outputs of the components without feedthrough; the feedthrough chain in
 * topological order, each component's inputs set, then its outputs read; the inputs of
 * the first ones set last), each with its value references and its slots in the value
 * vector. core_run then does what Master.step() does, tick after tick: every component
 * steps from t_k to t_{k+1} (doStep(t_k, h), in the master's order), then the plan runs at
 * t_{k+1}, the value vector is checked finite, and the tick is recorded where the
 * recorder would (every `every`-th tick, and the final one). The same functions are
 * called with the same arguments in the same order as the Python master calls them, so
 * the rows are the same, bit for bit.
 *
 * Time is the master's: t_k = t0 + (k / N) T + (k % N) h, computed as Python computes
 * it (built with -ffp-contract=off: no fused multiply-add).
 *
 * core_run returns after `stop` ticks, or when its row buffer is full, or at the first
 * failure, which it describes (the Python master then raises the same error). It calls
 * nothing but the FMUs: their logger (Python's, through fmpy) may run meanwhile.
 *
 * A run replayed from its recipe (delaycomp.orchestrator.replay) sets the FMUs up itself,
 * from ctypes, without fmpy: it takes this library's callbacks for them (core_callbacks2,
 * core_logger3: a logger that only counts the messages and keeps the worst status) and
 * the first tick's propagation (core_propagate) as well.
 */
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#if defined(_WIN32)
#define EXPORT __declspec(dllexport)
#else
#define EXPORT __attribute__((visibility("default")))
#endif

typedef int (*Get2)(void *, const unsigned int *, size_t, double *);
typedef int (*Set2)(void *, const unsigned int *, size_t, const double *);
typedef int (*Step2)(void *, double, double, int);
typedef int (*Get3)(void *, const unsigned int *, size_t, double *, size_t);
typedef int (*Set3)(void *, const unsigned int *, size_t, const double *, size_t);
typedef int (*Step3)(void *, double, double, bool, bool *, bool *, bool *, double *);

typedef void (*AnyFunction)(void);  /* a function pointer of no type: cast to its own */

typedef struct {
    void *instance;              /* the fmi2Component / fmi3Instance */
    AnyFunction get, set, step;  /* fmi2GetReal, fmi2SetReal, fmi2DoStep (or FMI 3.0's) */
    int32_t fmi;                 /* 2 or 3 */
    const int32_t *worst;        /* the worst status its log has shown (the host's logger
                                    keeps it): a read after a logged error is refused */
} CoreComponent;

enum { OP_GET = 0, OP_SET = 1 };

typedef struct {
    int32_t kind;                /* OP_GET: outputs into slots; OP_SET: slots into inputs */
    int32_t comp;                /* index into the components */
    int64_t n;                   /* how many variables */
    const unsigned int *vrs;     /* their value references */
    const int64_t *slots;        /* their slots in the value vector */
} CoreOp;

typedef struct {
    int64_t ncomp;
    const CoreComponent *comps;  /* in the master's stepping order */
    int64_t nops;
    const CoreOp *ops;           /* one tick's propagation, in order */
    int64_t nslots;
    double *slots;               /* the value vector (the master's _slots) */
    double *scratch;             /* at least the largest n of an op */
    double t0, T, h;
    int64_t N;
    int64_t ncols;
    const int64_t *cols;         /* the recorded slots, in column order */
    int64_t every, final;        /* record tick k when k % every == 0 or k == final */
} CoreLoop;

/* what stopped a run early */
enum {
    CORE_DONE = 0,       /* the stop tick reached */
    CORE_FULL = 1,       /* the row buffer is full: call again */
    CORE_STEP = 2,       /* a doStep returned status > warning (status, comp) */
    CORE_STEP3 = 3,      /* an fmi3DoStep asked to terminate or returned early (flag) */
    CORE_CALL = 4,       /* a read or write of the propagation returned > warning (op) */
    CORE_LOGGED = 5,     /* a read after the component logged an error (op) */
    CORE_NONFINITE = 6,  /* a value of the vector is NaN or infinite */
    CORE_BAD = 7         /* the plan is malformed (a bug of the caller) */
};

typedef struct {
    int32_t code;
    int32_t comp;                /* the component (CORE_STEP, CORE_STEP3, CORE_CALL, CORE_LOGGED) */
    int32_t op;                  /* the op (CORE_CALL, CORE_LOGGED) */
    int32_t status;              /* the FMI status returned */
    int32_t flag;                /* CORE_STEP3: 1 terminateSimulation, 2 earlyReturn */
} CoreFailure;

static double time_of(const CoreLoop *L, int64_t k) {
    int64_t i = k / L->N, j = k % L->N;
    return L->t0 + (double)i * L->T + (double)j * L->h;  /* Master.time_of */
}

static int call_op(const CoreLoop *L, const CoreOp *op) {
    const CoreComponent *c = &L->comps[op->comp];
    size_t n = (size_t)op->n;
    if (op->kind == OP_GET) {
        int status = c->fmi == 3 ? ((Get3)c->get)(c->instance, op->vrs, n, L->scratch, n)
                                 : ((Get2)c->get)(c->instance, op->vrs, n, L->scratch);
        if (status > 1) return status;
        for (size_t q = 0; q < n; q++) L->slots[op->slots[q]] = L->scratch[q];
        return 0;
    }
    for (size_t q = 0; q < n; q++) L->scratch[q] = L->slots[op->slots[q]];
    int status = c->fmi == 3 ? ((Set3)c->set)(c->instance, op->vrs, n, L->scratch, n)
                             : ((Set2)c->set)(c->instance, op->vrs, n, L->scratch);
    return status > 1 ? status : 0;
}

/* One tick's propagation (Master._propagate): the plan in order, then the value vector
 * checked finite. CORE_DONE, or the failure (described in *fail). */
static int32_t propagate(const CoreLoop *L, CoreFailure *fail) {
    for (int64_t o = 0; o < L->nops; o++) {
        const CoreOp *op = &L->ops[o];
        int status = call_op(L, op);
        if (status > 1 || (op->kind == OP_GET && *L->comps[op->comp].worst >= 3)) {
            fail->comp = op->comp;
            fail->op = (int32_t)o;
            fail->status = status;
            return fail->code = status > 1 ? CORE_CALL : CORE_LOGGED;
        }
    }
    for (int64_t s = 0; s < L->nslots; s++)
        if (!isfinite(L->slots[s])) return fail->code = CORE_NONFINITE;
    return fail->code = CORE_DONE;
}

/* Step from tick *k to at most tick `stop` (Master.step() each time), recording the
 * ticks due into times[] and rows[] (ncols values a row; at most `capacity` rows, their
 * count in *nrows). *k is the tick reached (the master's k: on a failure in a step, the
 * tick it started from; in the propagation, the tick it reached). */
EXPORT int32_t core_run(const CoreLoop *L, int64_t *k, int64_t stop, double *times,
                        double *rows, int64_t capacity, int64_t *nrows, CoreFailure *fail) {
    fail->code = CORE_DONE;
    fail->comp = fail->op = fail->status = fail->flag = -1;
    *nrows = 0;
    if (L->N < 1 || L->every < 1 || capacity < 1) return fail->code = CORE_BAD;
    while (*k < stop) {
        double t = time_of(L, *k);
        for (int64_t c = 0; c < L->ncomp; c++) {
            const CoreComponent *cc = &L->comps[c];
            int status;
            if (cc->fmi == 3) {
                bool event = false, terminate = false, early = false;
                double last = 0.0;
                status = ((Step3)cc->step)(cc->instance, t, L->h, true, &event, &terminate,
                                           &early, &last);
                if (status <= 1 && (terminate || early)) {
                    fail->comp = (int32_t)c;
                    fail->status = status;
                    fail->flag = terminate ? 1 : 2;
                    return fail->code = CORE_STEP3;
                }
            } else {
                status = ((Step2)cc->step)(cc->instance, t, L->h, 1);
            }
            if (status > 1) {
                fail->comp = (int32_t)c;
                fail->status = status;
                return fail->code = CORE_STEP;
            }
        }
        *k += 1;
        if (propagate(L, fail) != CORE_DONE) return fail->code;
        if (*k % L->every == 0 || *k == L->final) {
            times[*nrows] = time_of(L, *k);
            double *row = rows + *nrows * L->ncols;
            for (int64_t j = 0; j < L->ncols; j++) row[j] = L->slots[L->cols[j]];
            if (++*nrows == capacity && *k < stop) return fail->code = CORE_FULL;
        }
    }
    return fail->code = CORE_DONE;
}

/* The propagation of the current tick alone (what Master.initialize() does at tick 0
 * once every component has left initialization mode), for a host that set the FMUs up
 * itself (delaycomp.orchestrator.replay). CORE_DONE, or the failure. */
EXPORT int32_t core_propagate(const CoreLoop *L, CoreFailure *fail) {
    fail->code = CORE_DONE;
    fail->comp = fail->op = fail->status = fail->flag = -1;
    return propagate(L, fail);
}

/* --- the callbacks of a host that instantiates the FMUs itself (the replay) ----------
 * Its logger formats nothing and keeps nothing but, per instance, the worst status
 * logged and how many messages came: the replay needs only to know that an FMU said
 * something (then it gives way to the Python master, which reports it in its words). */
typedef struct {
    int32_t worst;               /* the worst status logged (CoreComponent.worst) */
    int32_t count;               /* messages logged */
} CoreLog;

static void note(CoreLog *log, int status) {
    if (log == NULL) return;
    if (status > log->worst) log->worst = status;
    log->count += 1;
}

static void logger2(void *env, const char *instance, int status, const char *category,
                 const char *message, ...) {
    (void)instance; (void)category; (void)message;
    note((CoreLog *)env, status);
}

static void logger3(void *env, int status, const char *category, const char *message) {
    (void)category; (void)message;
    note((CoreLog *)env, status);
}

typedef struct {                 /* fmi2CallbackFunctions */
    void (*logger)(void *, const char *, int, const char *, const char *, ...);
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(void *, int);
    void *componentEnvironment;
} Callbacks2;

/* An FMI 2.0 instance's callbacks: this logger (its environment: `log`), calloc, free. */
EXPORT void core_callbacks2(Callbacks2 *cb, CoreLog *log) {
    cb->logger = logger2;
    cb->allocateMemory = calloc;
    cb->freeMemory = free;
    cb->stepFinished = NULL;
    cb->componentEnvironment = log;
}

/* FMI 3.0's fmi3LogMessageCallback of the same logger (its instance environment: a
 * CoreLog). */
EXPORT void core_logger3(void (**logger)(void *, int, const char *, const char *)) {
    *logger = logger3;
}

/* The layout this library was built with, for the caller to check its own against:
 * the sizes of CoreComponent, CoreOp, CoreLoop, CoreFailure, CoreLog and Callbacks2. */
EXPORT void core_layout(int64_t *sizes) {
    sizes[0] = (int64_t)sizeof(CoreComponent);
    sizes[1] = (int64_t)sizeof(CoreOp);
    sizes[2] = (int64_t)sizeof(CoreLoop);
    sizes[3] = (int64_t)sizeof(CoreFailure);
    sizes[4] = (int64_t)sizeof(CoreLog);
    sizes[5] = (int64_t)sizeof(Callbacks2);
}
