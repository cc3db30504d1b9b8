/* ode.c: Dormand-Prince 8(5,3), "DOP853", for x' = f(x) over one segment of time.
 *
 * The method of E. Hairer, S. P. Norsett and G. Wanner, "Solving Ordinary Differential
 * Equations I: Nonstiff Problems", 2nd ed., Springer 1993, section II.10: an explicit
 * Runge-Kutta method of order 8 with 12 stages, whose error estimate combines a 5th
 * order and a 3rd order embedded formula, err = |h| E5 / sqrt(n (E5^2 + 0.01 E3^2)) E5
 * in the RMS norm scaled by sk_i = atol + rtol max(|y_i|, |y_new_i|). The step size
 * control and the initial step are those of Hairer's code as scipy's
 * ode(...).set_integrator("dop853") runs it, so the two take the same steps:
 *  - initial step (Hairer's HINIT, order 8): h0 = 0.01 sqrt(sum (y/sk)^2 / sum (f/sk)^2)
 *    (1e-6 if either sum is <= 1e-10), one Euler step estimates the second derivative,
 *    h = min(100 h0, (0.01 / max(|f''|, |f|))^(1/8), hmax), hmax = the segment;
 *  - new step h / fac, fac = max(1/6, min(1/0.3, err^(1/8) / 0.9)) (safety 0.9, the step
 *    grows at most 6 times and shrinks at most to 0.3 of itself; scipy's defaults, beta
 *    = 0: no Lund stabilization); after a rejection the next accepted step does not grow;
 *  - failures: more than max_steps steps (accepted and rejected) "larger nsteps is
 *    needed"; 0.1 |h| <= |t| uround (uround = 2.3e-16) "step size becomes too small";
 *    stiffness detection (every 1000 accepted steps, then every step while suspected:
 *    |h| |f(y_new) - k12| / |y_new - y12| > 6.1 fifteen times) "problem is probably stiff
 *    (interrupted)"; our own: f returned non-zero "the model's f failed", an accepted
 *    state is not finite "the state is not finite".
 * A step whose error estimate is NaN (f gave NaN or an overflow inside the step) is
 * rejected and the step shrinks to 0.3 of itself (fmin and fmax ignore a NaN).
 * The sums are taken in the order of Hairer's code (stages ascending), so the results
 * agree with scipy's to rounding (tests/test_native_ode.py measures how closely).
 *
 * A rejected step is retried with h / min(1/0.3, err^(1/8) / 0.9), Hairer's rule. scipy
 * 1.17's C translation of DOP853 (ode(...).set_integrator("dop853"), which
 * delaycomp.maths.predictors uses) writes min(facc1, facc1 / safe) there, so it always retries
 * with 0.3 h: same accepted results within the tolerance, but other steps after the first
 * rejection. Compiled with -DODE_REJECT_LIKE_SCIPY_1_17 this file does the same (the
 * tests use it to check step-for-step agreement with scipy); the default is Hairer's.
 *
 * Tiny states: when the state and the input are all below ODE_TINY = 1e-100 in absolute
 * value (and not all zero), the segment is solved for y = x / s, s the power of two
 * nearest their largest magnitude: y' = f(s y) / s is the same ODE (a power of two
 * multiplies and divides exactly above the subnormals), and the tolerances applied to y
 * are tighter than on x. Without it the squared scaled errors of a state near 1e-150
 * underflow to 0 and the step control breaks down. This is delaycomp.maths.predictors'
 * _scaled_segment.
 *
 * The coefficients are the published ones (Hairer's DOP853), as decimal literals.
 * No heap allocation: the caller hands ode_work_size(n) doubles.
 */
#include "ode.h"

#include <math.h>
#include <string.h>

#define STAGES 12
#define UROUND 2.3e-16
#define SAFE 0.9
#define FAC1 0.3  /* smallest ratio hnew / h */
#define FAC2 6.0  /* largest ratio hnew / h */
#define NSTIFF 1000

/* a[s][j]: stage s (0-based; stage 0 is f(y)) from the slopes j < s */
static const double A[STAGES][STAGES] = {
    {0},
    {5.26001519587677318785587544488e-2},
    {1.97250569845378994544595329183e-2, 5.91751709536136983633785987549e-2},
    {2.95875854768068491816892993775e-2, 0.0, 8.87627564304205475450678981324e-2},
    {2.41365134159266685502369798665e-1, 0.0, -8.84549479328286085344864962717e-1,
     9.24834003261792003115737966543e-1},
    {3.7037037037037037037037037037e-2, 0.0, 0.0, 1.70828608729473871279604482173e-1,
     1.25467687566822425016691814123e-1},
    {3.7109375e-2, 0.0, 0.0, 1.70252211019544039314978060272e-1,
     6.02165389804559606850219397283e-2, -1.7578125e-2},
    {3.70920001185047927108779319836e-2, 0.0, 0.0, 1.70383925712239993810214054705e-1,
     1.07262030446373284651809199168e-1, -1.53194377486244017527936158236e-2,
     8.27378916381402288758473766002e-3},
    {6.24110958716075717114429577812e-1, 0.0, 0.0, -3.36089262944694129406857109825,
     -8.68219346841726006818189891453e-1, 2.75920996994467083049415600797e1,
     2.01540675504778934086186788979e1, -4.34898841810699588477366255144e1},
    {4.77662536438264365890433908527e-1, 0.0, 0.0, -2.48811461997166764192642586468,
     -5.90290826836842996371446475743e-1, 2.12300514481811942347288949897e1,
     1.52792336328824235832596922938e1, -3.32882109689848629194453265587e1,
     -2.03312017085086261358222928593e-2},
    {-9.3714243008598732571704021658e-1, 0.0, 0.0, 5.18637242884406370830023853209,
     1.09143734899672957818500254654, -8.14978701074692612513997267357,
     -1.85200656599969598641566180701e1, 2.27394870993505042818970056734e1,
     2.49360555267965238987089396762, -3.0467644718982195003823669022},
    {2.27331014751653820792359768449, 0.0, 0.0, -1.05344954667372501984066689879e1,
     -2.00087205822486249909675718444, -1.79589318631187989172765950534e1,
     2.79488845294199600508499808837e1, -2.85899827713502369474065508674,
     -8.87285693353062954433549289258, 1.23605671757943030647266201528e1,
     6.43392746015763530355970484046e-1},
};

/* the weights of the 8th order solution (stages 1, 6 .. 12; 1-based as in the book) */
static const double B[STAGES] = {
    5.42937341165687622380535766363e-2, 0.0, 0.0, 0.0, 0.0,
    4.45031289275240888144113950566, 1.89151789931450038304281599044,
    -5.8012039600105847814672114227, 3.1116436695781989440891606237e-1,
    -1.52160949662516078556178806805e-1, 2.01365400804030348374776537501e-1,
    4.47106157277725905176885569043e-2};

/* the 3rd order embedded weights (stages 1, 9, 12): E3 = B - BHH */
#define BHH1 0.244094488188976377952755905512
#define BHH2 0.733846688281611857341361741547
#define BHH3 0.220588235294117647058823529412e-1

/* the 5th order error weights (stages 1, 6 .. 12) */
static const double ER[STAGES] = {
    0.1312004499419488073250102996e-1, 0.0, 0.0, 0.0, 0.0,
    -0.1225156446376204440720569753e+1, -0.4957589496572501915214079952,
    0.1664377182454986536961530415e+1, -0.3503288487499736816886487290,
    0.3341791187130174790297318841, 0.8192320648511571246570742613e-1,
    -0.2235530786388629525884427845e-1};

ODE_API size_t ode_work_size(size_t n) { return (STAGES + 5) * n; }

ODE_API const char *ode_reason(int code) {
    switch (code) {
    case ODE_OK: return "";
    case ODE_BAD_INPUT: return "input is not consistent";
    case ODE_MAX_STEPS: return "larger nsteps is needed";
    case ODE_STEP_TOO_SMALL: return "step size becomes too small";
    case ODE_STIFF: return "problem is probably stiff (interrupted)";
    case ODE_NOT_FINITE: return "the state is not finite";
    case ODE_RHS_FAILED: return "the model's f failed";
    default: return "unknown failure";
    }
}

typedef struct {
    ode_rhs f;
    void *ctx;
    size_t n;
    double scale;  /* solve for y = x / scale */
    double *arg;   /* n doubles: scale * y for f */
    OdeReport *report;
} Rhs;

static int eval(Rhs *r, const double *y, double *dy) {
    r->report->evaluations++;
    if (r->scale == 1.0) return r->f(r->ctx, y, dy) != 0;
    for (size_t i = 0; i < r->n; i++) r->arg[i] = y[i] * r->scale;
    if (r->f(r->ctx, r->arg, dy) != 0) return 1;
    for (size_t i = 0; i < r->n; i++) dy[i] /= r->scale;
    return 0;
}

/* Hairer's HINIT for order 8 (f0 = f(y) given; y1, f1: n doubles of scratch). */
static int initial_step(Rhs *r, const double *y, const double *f0, double hmax,
                        double rtol, double atol, double *y1, double *f1, double *h) {
    size_t n = r->n;
    double dnf = 0.0, dny = 0.0;
    for (size_t i = 0; i < n; i++) {
        double sk = atol + rtol * fabs(y[i]);
        dnf += (f0[i] / sk) * (f0[i] / sk);
        dny += (y[i] / sk) * (y[i] / sk);
    }
    double h0 = (dnf <= 1e-10 || dny <= 1e-10) ? 1e-6 : sqrt(dny / dnf) * 0.01;
    h0 = fmin(h0, hmax);
    for (size_t i = 0; i < n; i++) y1[i] = y[i] + h0 * f0[i];
    if (eval(r, y1, f1)) return 1;
    double der2 = 0.0;
    for (size_t i = 0; i < n; i++) {
        double sk = atol + rtol * fabs(y[i]);
        der2 += ((f1[i] - f0[i]) / sk) * ((f1[i] - f0[i]) / sk);
    }
    der2 = sqrt(der2) / h0;
    double der12 = fmax(fabs(der2), sqrt(dnf));
    double h1 = der12 <= 1e-15 ? fmax(1e-6, fabs(h0) * 1e-3) : pow(0.01 / der12, 1.0 / 8.0);
    *h = fmin(fmin(100.0 * fabs(h0), h1), hmax);
    return 0;
}

/* DOP853 over [0, xend] from y (updated in place on success). */
static int dop853(Rhs *r, double *y, double xend, double rtol, double atol, long max_steps,
                  double *work) {
    size_t n = r->n;
    OdeReport *rep = r->report;
    double *k[STAGES];
    for (int s = 0; s < STAGES; s++) k[s] = work + (size_t)s * n;
    double *ytmp = work + STAGES * n, *ynew = ytmp + n, *fnew = ynew + n;
    const double facc1 = 1.0 / FAC1, facc2 = 1.0 / FAC2, hmax = xend;
    double t = 0.0, h;
    int reject = 0, last = 0, iasti = 0, nonsti = 0;

    if (eval(r, y, k[0])) return ODE_RHS_FAILED;
    if (initial_step(r, y, k[0], hmax, rtol, atol, ytmp, fnew, &h)) return ODE_RHS_FAILED;
    for (;;) {
        rep->t = t;
        rep->h = h;
        if (rep->steps > max_steps) return ODE_MAX_STEPS;
        if (0.1 * fabs(h) <= fabs(t) * UROUND) return ODE_STEP_TOO_SMALL;
        if (t + 1.01 * h - xend > 0.0) {
            h = xend - t;
            last = 1;
        }
        rep->steps++;
        rep->h = h;
        for (int s = 1; s < STAGES; s++) {
            for (size_t i = 0; i < n; i++) {
                double sum = 0.0;
                int first = 1;
                for (int j = 0; j < s; j++) {
                    if (A[s][j] == 0.0) continue;
                    sum = first ? A[s][j] * k[j][i] : sum + A[s][j] * k[j][i];
                    first = 0;
                }
                ytmp[i] = y[i] + h * sum;
            }
            if (eval(r, ytmp, k[s])) return ODE_RHS_FAILED;
        }
        /* ytmp now holds the argument of the last stage (y12), kept for stiffness */
        double err = 0.0, err2 = 0.0;
        for (size_t i = 0; i < n; i++) {
            double b = 0.0, e5 = 0.0;
            int first = 1;
            for (int j = 0; j < STAGES; j++) {
                if (B[j] == 0.0) continue;
                b = first ? B[j] * k[j][i] : b + B[j] * k[j][i];
                e5 = first ? ER[j] * k[j][i] : e5 + ER[j] * k[j][i];
                first = 0;
            }
            ynew[i] = y[i] + h * b;
            double sk = atol + rtol * fmax(fabs(y[i]), fabs(ynew[i]));
            double e3 = b - BHH1 * k[0][i] - BHH2 * k[8][i] - BHH3 * k[11][i];
            err2 += (e3 / sk) * (e3 / sk);
            err += (e5 / sk) * (e5 / sk);
        }
        double deno = err + 0.01 * err2;
        if (deno <= 0.0) deno = 1.0;
        err = fabs(h) * err * sqrt(1.0 / ((double)n * deno));
        double fac11 = pow(err, 1.0 / 8.0);
        double hnew = h / fmax(facc2, fmin(facc1, fac11 / SAFE));
        if (err <= 1.0) {
            rep->accepted++;
            for (size_t i = 0; i < n; i++)
                if (!isfinite(ynew[i])) return ODE_NOT_FINITE;
            if (eval(r, ynew, fnew)) return ODE_RHS_FAILED;
            if (rep->accepted % NSTIFF == 0 || iasti > 0) {
                double stnum = 0.0, stden = 0.0, hlamb = 0.0;
                for (size_t i = 0; i < n; i++) {
                    stnum += (fnew[i] - k[11][i]) * (fnew[i] - k[11][i]);
                    stden += (ynew[i] - ytmp[i]) * (ynew[i] - ytmp[i]);
                }
                if (stden > 0.0) hlamb = fabs(h) * sqrt(stnum / stden);
                if (hlamb > 6.1) {
                    nonsti = 0;
                    if (++iasti == 15) return ODE_STIFF;
                } else if (++nonsti == 6) {
                    iasti = 0;
                }
            }
            memcpy(k[0], fnew, n * sizeof *fnew);
            memcpy(y, ynew, n * sizeof *ynew);
            t += h;
            rep->t = t;
            if (last) {
                rep->h = hnew;
                return ODE_OK;
            }
            if (fabs(hnew) > hmax) hnew = hmax;
            if (reject) hnew = fmin(fabs(hnew), fabs(h));
            reject = 0;
        } else {
#ifdef ODE_REJECT_LIKE_SCIPY_1_17
            hnew = h / facc1;  /* scipy 1.17's C translation: min(facc1, facc1 / safe) */
#else
            hnew = h / fmin(facc1, fac11 / SAFE);
#endif
            reject = 1;
            rep->rejected++;
            last = 0;
        }
        h = hnew;
    }
}

ODE_API int ode_solve(ode_rhs f, void *ctx, size_t n, double *x, double duration, double rtol,
              double atol, long max_steps, double u_size, double *work, OdeReport *report) {
    OdeReport local;
    if (report == NULL) report = &local;
    memset(report, 0, sizeof *report);
    report->scale = 1.0;
    report->reason = "";
    int code = ODE_OK;
    if (isnan(duration) || !(rtol > 10.0 * UROUND) || !(atol > 0.0) || max_steps < 1 ||
        isnan(u_size) || f == NULL || (n > 0 && (x == NULL || work == NULL))) {
        code = ODE_BAD_INPUT;
    } else if (duration > 0.0 && n > 0) {
        double size = fabs(u_size);
        for (size_t i = 0; i < n; i++) {
            if (!isfinite(x[i])) code = ODE_NOT_FINITE;
            size = fmax(size, fabs(x[i]));
        }
        if (code == ODE_OK && !isfinite(duration)) code = ODE_BAD_INPUT;
        if (code == ODE_OK) {
            Rhs r = {f, ctx, n, 1.0, work + (STAGES + 3) * n, report};
            double *y = work + (STAGES + 4) * n;
            if (size > 0.0 && size < ODE_TINY)
                r.scale = ldexp(1.0, (int)nearbyint(log2(size)));
            report->scale = r.scale;
            for (size_t i = 0; i < n; i++) y[i] = x[i] / r.scale;
            code = dop853(&r, y, duration, rtol, atol, max_steps, work);
            if (code == ODE_OK) {
                for (size_t i = 0; i < n; i++)
                    if (!isfinite(y[i] * r.scale)) code = ODE_NOT_FINITE;
            }
            if (code == ODE_OK)
                for (size_t i = 0; i < n; i++) x[i] = y[i] * r.scale;
        }
    }
    report->code = code;
    report->reason = ode_reason(code);
    return code;
}
