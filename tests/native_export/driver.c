/* driver.c: runs an exported controller (`delaycomp export-c`) over recorded measurements
 * (tests/test_exportc.py). Compiled with -DPREFIX=<prefix> -include <prefix>.h.
 *
 * stdin: one line per base tick, "t y1 .. yn" (%.17g); y is used at the sample ticks
 * (every PREFIX_N ticks from the first). stdout: one line per tick, "u1 .. um" (%.17g);
 * a refused call prints "error CODE at TICK" and exits 1. C99, the C library only. */
#include <stdio.h>
#include <stdlib.h>

#define CAT2(a, b) a##b
#define CAT(a, b) CAT2(a, b)
#define NAME(x) CAT(PREFIX, x)

int main(void) {
    NAME(_state) state;  /* two of them: the second proves the first is not shared */
    NAME(_state) other;
    NAME(_init)(&state);
    NAME(_init)(&other);
    double y[NAME(_NY)], u[NAME(_NU)], t;
    for (long k = 0; scanf("%lf", &t) == 1; k++) {
        for (int i = 0; i < NAME(_NY); i++)
            if (scanf("%lf", &y[i]) != 1) return 2;
        int rc = 0;
        if (k % NAME(_N) == 0) rc = NAME(_sample)(&state, t, y);
        if (rc == 0) rc = NAME(_output)(&state, t, u);
        if (rc != 0) {
            printf("error %d at %ld\n", rc, k);
            return 1;
        }
        for (int j = 0; j < NAME(_NU); j++) printf(j ? " %.17g" : "%.17g", u[j]);
        printf("\n");
    }
    /* the untouched state still refuses an output before its first sample */
    return NAME(_output)(&other, 0.0, u) == NAME(_E_ORDER) ? 0 : 3;
}
