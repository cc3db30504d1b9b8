/* The base grid's rules (grid.h): delaycomp.maths.grid's arithmetic, once for every native
 * model that asks whether a value lies on a grid (the delay, the channel, the LTI and the
 * model controllers). */
#include <math.h>

#include "native.h"  /* GRID_RTOL */
#include "grid.h"

int nearest_multiple(double value, double step, double *k) {
    double ratio = value / step;
    if (!isfinite(ratio)) return 0;
    double nearest = nearbyint(ratio);  /* Python's round: to even on ties */
    if (!(fabs(ratio - nearest) <= GRID_RTOL * fmax(1.0, fabs(ratio)))) return 0;
    *k = nearest;
    return 1;
}

double steps_up(double value, double step) {
    double k;
    return nearest_multiple(value, step, &k) ? k : ceil(value / step);
}

void split(double value, double period, double *q, double *rest) {
    if (nearest_multiple(value, period, q)) {
        *rest = 0.0;
        return;
    }
    *q = floor(value / period);
    *rest = fmax(value - *q * period, 0.0);
}

double padded_delay(double tau, double T) {
    double q, rest;
    split(tau, T, &q, &rest);
    return rest == 0.0 ? tau : (q + 1) * T;
}
