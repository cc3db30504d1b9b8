/* export_timing.c: the time of one step of an exported controller (`delaycomp export-c`),
 * for bench/run.py section 11. Compiled with -DPREFIX=<prefix> -include <prefix>.h.
 *
 * usage: export_timing TICKS < EPISODE
 * EPISODE (stdin): "E", then E lines of the controller's measurement y at each base step
 * of a closed-loop run (delaycomp.formats.exportc.closed_loop_io). The controller runs TICKS base
 * steps as episodes of E steps, each from PREFIX_init (not timed) along the recorded
 * measurements (at a sample tick: PREFIX_sample and PREFIX_output; else PREFIX_output);
 * each step is timed with the monotonic clock. Prints "median p999 max sample_median
 * sample_max" in nanoseconds (p999: the 99.9th percentile of all steps). */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define CAT2(a, b) a##b
#define CAT(a, b) CAT2(a, b)
#define NAME(x) CAT(PREFIX, x)

static double now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e9 * (double)ts.tv_sec + (double)ts.tv_nsec;
}

static int by_value(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double at(const double *sorted, long n, double q) {
    long i = (long)ceil(q * (double)n) - 1;
    return sorted[i < 0 ? 0 : (i >= n ? n - 1 : i)];
}

int main(int argc, char **argv) {
    long ticks = argc > 1 ? atol(argv[1]) : 1000000L, episode;
    if (ticks < NAME(_N) || scanf("%ld", &episode) != 1 || episode < 1) return 2;
    double *ys = malloc((size_t)episode * NAME(_NY) * sizeof(double));
    if (ys == NULL) return 2;
    for (long i = 0; i < episode * NAME(_NY); i++)
        if (scanf("%lf", &ys[i]) != 1) return 2;
    double *all = malloc((size_t)ticks * sizeof(double));
    long samples = ticks;  /* at most one per step */
    double *at_samples = malloc((size_t)samples * sizeof(double));
    if (all == NULL || at_samples == NULL) return 2;
    static NAME(_state) state;
    NAME(_init)(&state);
    double y[NAME(_NY)], u[NAME(_NU)], sink = 0.0;
    long n_samples = 0;
    for (long k = 0; k < ticks; k++) {
        long e = k % episode;
        if (e == 0) NAME(_init)(&state);  /* a new episode: not timed */
        double t = (double)e * NAME(_H);
        int sample = e % NAME(_N) == 0;
        if (sample)
            for (int i = 0; i < NAME(_NY); i++) y[i] = ys[e * NAME(_NY) + i];
        double start = now_ns();
        int rc = sample ? NAME(_sample)(&state, t, y) : 0;
        if (rc == 0) rc = NAME(_output)(&state, t, u);
        double took = now_ns() - start;
        if (rc != 0) {
            fprintf(stderr, "refused at tick %ld: %d\n", k, rc);
            return 1;
        }
        sink += u[0];
        all[k] = took;
        if (sample && n_samples < samples) at_samples[n_samples++] = took;
    }
    qsort(all, (size_t)ticks, sizeof(double), by_value);
    qsort(at_samples, (size_t)n_samples, sizeof(double), by_value);
    printf("%.0f %.0f %.0f %.0f %.0f\n", at(all, ticks, 0.5), at(all, ticks, 0.999),
           all[ticks - 1], at(at_samples, n_samples, 0.5), at_samples[n_samples - 1]);
    fprintf(stderr, "(control sum %g)\n", sink);
    free(all);
    free(at_samples);
    free(ys);
    return 0;
}
