/* draws.c: the network channel's random draws (draws.h). */
#include "draws.h"

#include <math.h>

static const double PI = 0x1.921fb54442d18p+1;  /* math.pi */

uint64_t mix(uint64_t z) {
    z = (z ^ (z >> 30)) * UINT64_C(0xBF58476D1CE4E5B9);
    z = (z ^ (z >> 27)) * UINT64_C(0x94D049BB133111EB);
    return z ^ (z >> 31);
}

double draw(uint64_t key, uint64_t counter) {
    return (double)(mix(key + counter * GOLDEN) >> 11) * 0x1p-53;
}

double packet_draw(uint64_t key, uint64_t j, unsigned i) {
    return draw(key, (j << 32) + i + 1u);
}

/* Marsaglia and Tsang with a Box-Muller normal; a < 1: G(a + 1) U^(1/a) */
double gamma_draw(uint64_t key, uint64_t j, double shape) {
    unsigned i = DRAW_DELAY;
    double boost = 1.0, a = shape;
    if (a < 1.0) {
        boost = pow(1.0 - packet_draw(key, j, i), 1.0 / a);
        i += 1;
        a = a + 1.0;
    }
    double d = a - 1.0 / 3.0;
    double c = 1.0 / sqrt(9.0 * d);
    for (;;) {  /* accepts with probability > 0.95 */
        double u1 = packet_draw(key, j, i), u2 = packet_draw(key, j, i + 1),
               u3 = packet_draw(key, j, i + 2);
        i += 3;
        double x = sqrt(-2.0 * log(1.0 - u1)) * cos((2.0 * PI) * u2);
        double v = 1.0 + c * x;
        if (v <= 0.0) continue;
        v = v * v * v;
        if (log(1.0 - u3) < 0.5 * x * x + d - d * v + d * log(v)) return d * v * boost;
    }
}
