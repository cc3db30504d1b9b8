/* fates.c: the packets a network channel shows, for many runs at once, compiled: the
 * batch engine's draws on the CPU (delaycomp.studies.channel_kernel loads it with ctypes;
 * delaycomp.maths.channel_batch.shown is the same computation in numpy, and the tests hold
 * the two equal bit for bit). Standalone: the C library, libm and draws.c; allocates
 * nothing. Build: cc -std=c11 -O2 -fPIC -shared -ffp-contract=off fates.c draws.c -lm
 * (no fused multiply-add: every double as numpy computes it).
 *
 * For each run (its key and its trace offset) the packets j = 0 .. J - 1, sent at step j P,
 * draw their fates in order (loss by the loss model, the Gilbert-Elliott chain carried
 * from packet to packet; the delay; lost where later than the timeout Q); packet j is
 * delivered at D_j: its arrival s_j + q_j (in order: the running maximum with the packets
 * before it, lost ones at their timeout; play-out: every packet at s_j + Q, in order; drop
 * stale: its arrival alone), and counts from the row ceil(D_j / every) on. A row shows the
 * largest j delivered by then: the packets' writes in increasing j, then a running maximum
 * down the rows. */
#include <math.h>
#include <stdint.h>

#include "draws.h"

#if defined(_WIN32)
#define EXPORT __declspec(dllexport)
#else
#define EXPORT __attribute__((visibility("default")))
#endif

/* delaycomp.maths.channel.DISTRIBUTIONS, LOSS_MODELS, POLICIES, by index */
enum { DIST_CONSTANT, DIST_UNIFORM, DIST_EXPONENTIAL, DIST_GAMMA, DIST_TRACE };
enum { LOSS_NONE, LOSS_BERNOULLI, LOSS_GILBERT_ELLIOTT };
enum { POLICY_IN_ORDER, POLICY_DROP_STALE, POLICY_PLAYOUT };

/* the real parameters, in this order */
enum { P_DELAY, P_JITTER, P_SHAPE, P_LOSS, P_GB, P_BG, P_LOSS_GOOD, P_LOSS_BAD, P_H, P_RTOL,
       NPAR };
/* the integer ones */
enum { I_DIST, I_LOSS_MODEL, I_POLICY, I_Q, I_P, I_J, I_EVERY, I_ROWS, I_NTRACE, NIPAR };

/* delaycomp.maths.channel_batch.steps_up of a value whose ratio to the step is ``ratio``
 * (0 <= ratio < 2^53: there truncation is floor, one instruction, no libm call) */
static int64_t steps_up(double ratio, double rtol) {
    int64_t f = (int64_t)ratio;
    double frac = ratio - (double)f;
    double tol = (ratio > 1.0 ? ratio : 1.0) * rtol;  /* np.maximum(ratio, 1.0) */
    return f + (frac > tol ? 1 : 0);
}

/* packet j's delay [s] (NaN: lost in the trace), as channel_batch.delays */
static double delay_of(const double *par, int dist, uint64_t key, int64_t off, int64_t j,
                       const double *trace, int64_t ntrace) {
    double least = par[P_DELAY], jitter = par[P_JITTER];  /* the channel's delay, jitter */
    if (dist == DIST_CONSTANT || (dist != DIST_TRACE && jitter == 0)) return least;
    if (dist == DIST_UNIFORM) {  /* (jitter 2^-53) m + delay: the same doubles */
        double m = (double)(mix(key + (((uint64_t)j << 32) + DRAW_DELAY + 1u) * GOLDEN) >> 11);
        return m * (jitter * 0x1p-53) + least;
    }
    if (dist == DIST_EXPONENTIAL)
        return least - jitter * log(1.0 - packet_draw(key, (uint64_t)j, DRAW_DELAY));
    if (dist == DIST_GAMMA)
        return least + (jitter / par[P_SHAPE]) * gamma_draw(key, (uint64_t)j, par[P_SHAPE]);
    return ntrace > 0 ? trace[(off + j) % ntrace] : NAN;
}

/* The rows of R runs: best[k R + r] the packet run r shows at row k (-1: none yet), k <
 * rows, row-major as numpy's (rows, R) array; best holds -1 on entry. The runs go in
 * order, so a cache line of a row (eight runs) is written by eight runs in a row while the
 * run's rows (one line each) stay in the cache. Returns 0, or -1 for parameters out of
 * range (the caller checks them first). */
EXPORT int fates_shown(int64_t R, const uint64_t *keys, const int64_t *offsets,
                       const double *par, const int64_t *ipar, const double *trace,
                       int64_t *best) {
    int dist = (int)ipar[I_DIST], loss_model = (int)ipar[I_LOSS_MODEL];
    int policy = (int)ipar[I_POLICY];
    int64_t Q = ipar[I_Q], P = ipar[I_P], J = ipar[I_J], every = ipar[I_EVERY];
    int64_t rows = ipar[I_ROWS], ntrace = ipar[I_NTRACE];
    double h = par[P_H], rtol = par[P_RTOL];
    if (R < 0 || Q < 0 || P < 1 || J < 0 || every < 1 || rows < 0 || ntrace < 0) return -1;
    for (int64_t r = 0; r < R; r++) {
        int64_t *col = best + r;
        uint64_t key = keys[r];
        int bad = 0;
        int64_t before = INT64_MIN;  /* D_{j - 1} */
        for (int64_t j = 0; j < J; j++) {
            int lost = 0;
            if (loss_model == LOSS_BERNOULLI) {
                lost = packet_draw(key, (uint64_t)j, DRAW_LOSS) < par[P_LOSS];
            } else if (loss_model == LOSS_GILBERT_ELLIOTT) {
                double u = packet_draw(key, (uint64_t)j, DRAW_STATE);
                bad = bad ? u >= par[P_BG] : u < par[P_GB];
                lost = packet_draw(key, (uint64_t)j, DRAW_LOSS)
                       < (bad ? par[P_LOSS_BAD] : par[P_LOSS_GOOD]);
            }
            double ratio = delay_of(par, dist, key, offsets[r], j, trace, ntrace) / h;
            int64_t q;
            if (lost || !(ratio <= (double)Q + 1.0)) {  /* NaN, or surely later than Q */
                lost = 1;
                q = Q;
            } else {  /* 0 <= ratio <= Q + 1 (the delays are >= 0, Channel.check) */
                q = steps_up(ratio, rtol);
                if (q > Q) {
                    lost = 1;
                    q = Q;
                }
            }
            if (policy == POLICY_PLAYOUT) q = Q;  /* the play-out buffer: at s_j + Q */
            int64_t ready = q + j * P;
            if (policy != POLICY_DROP_STALE) {  /* in order: D_j = max(ready_j, D_{j-1}) */
                if (ready < before) ready = before;
                before = ready;
            }
            if (!lost) {
                int64_t k = (ready + every - 1) / every;  /* the first row at or after D_j */
                if (k < rows) col[k * R] = j;
            }
        }
        for (int64_t k = 1; k < rows; k++)
            if (col[k * R] < col[(k - 1) * R]) col[k * R] = col[(k - 1) * R];
    }
    return 0;
}
