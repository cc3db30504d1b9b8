/* draws.h: the network channel's counter-based random draws (delaycomp.maths.channel):
 * SplitMix64 of a key and a counter, no state to carry. Shared by the channel FMU
 * (fmus/delay/channel.c) and the batch engine's compiled fates (fates.c). Standalone: libm
 * alone; the same doubles as the scalar Python code (integer arithmetic; gamma's log, sqrt,
 * cos and pow are libm's, in CPython's order of operations). */
#ifndef DELAYCOMP_DRAWS_H
#define DELAYCOMP_DRAWS_H

#include <stdint.h>

#define GOLDEN UINT64_C(0x9E3779B97F4A7C15)     /* SplitMix64's increment */
#define KEY_XOR UINT64_C(0x6A09E667F3BCC909)    /* the fractional bits of sqrt(2) */
/* the draws of a packet, by index (delaycomp.maths.channel.DRAW_*) */
#define DRAW_LOSS 0u
#define DRAW_STATE 1u
#define DRAW_DELAY 2u

/* SplitMix64's finalizer (delaycomp.maths.channel.mix) */
uint64_t mix(uint64_t z);
/* draw `counter` of a key: a double in [0, 1), a multiple of 2^-53 */
double draw(uint64_t key, uint64_t counter);
/* the i-th draw of packet j: counter j 2^32 + i + 1 (counter 0: a trace's offset) */
double packet_draw(uint64_t key, uint64_t j, unsigned i);
/* gamma of shape a, scale 1 (delaycomp.maths.channel.gamma_draw) */
double gamma_draw(uint64_t key, uint64_t j, double shape);

#endif
