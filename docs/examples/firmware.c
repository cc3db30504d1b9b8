/* firmware.c: the exported controller of the tutorial's cart in a firmware loop
 * (docs/howto/microcontroller.md). It runs on a PC as it is: the "hardware" below
 * simulates the cart on its rail and the network's two delays, so the loop can be checked
 * against `delaycomp run docs/examples/cart.toml` (tests/test_exportc.py does).
 *
 *   delaycomp export-c docs/examples/cart.toml --prefix cart --out build/
 *   cc -std=c99 -O2 -Ibuild docs/examples/firmware.c build/cart.c -o firmware -lm
 *   ./firmware > cart.csv
 *
 * On a target, the three hardware functions are the board's: a timer that wakes the loop
 * every base step h, the network's receive queue, and the actuator's command. */
#include <stdio.h>

#include "cart.h"

/* ---- the "hardware": the cart, the sensor's network (r late) and the actuator's (tau
 * late), simulated on the base grid; on a target these are the board and the plant ---- */
#define MASS 2.0
#define R_STEPS 10    /* r = 0.5 s = 10 h */
#define TAU_STEPS 20  /* tau = 1 s = 20 h */

static double cart[2] = {1.0, 0.0};                  /* position, velocity */
static double sent[R_STEPS][2], pushed[TAU_STEPS];   /* in flight on the two links */
static long tick;

/* the measurement that arrives at this tick: the cart as it was r ago (the loop file's
 * x0 before that) */
static void receive_measurement(double y[2]) {
    const double *old = sent[tick % R_STEPS];
    y[0] = old[0];
    y[1] = old[1];
}

/* the command leaves now and acts tau later; the cart moves on by one base step under the
 * force that arrives now (u0 = 0 before the first one) */
static void send_command(double u) {
    double force = pushed[tick % TAU_STEPS];
    pushed[tick % TAU_STEPS] = u;
    sent[tick % R_STEPS][0] = cart[0];
    sent[tick % R_STEPS][1] = cart[1];
    double h = cart_H, a = force / MASS;
    cart[0] += cart[1] * h + 0.5 * a * h * h;  /* exact: the force is held over h */
    cart[1] += a * h;
    tick++;
}

/* ---- the firmware ------------------------------------------------------------------ */
int main(void) {
    static cart_state controller;  /* fixed size (cart.h): no heap */
    double y[cart_NY], u[cart_NU];
    for (int k = 0; k < R_STEPS; k++) {  /* the links before t = 0: x0 and u0 */
        sent[k][0] = 1.0;
        sent[k][1] = 0.0;
    }
    cart_init(&controller);
    printf("time,position,velocity,force\n");
    for (long k = 0; k <= 10 * cart_N; k++) {  /* 10 s; on a target: forever */
        double t = k * cart_H;  /* the tick's time t0 + k h (the timer's count) */
        int rc = cart_OK;
        if (k % cart_N == 0) {  /* a sample instant: the measurement of this period */
            receive_measurement(y);
            rc = cart_sample(&controller, t, y);
        }
        if (rc == cart_OK) rc = cart_output(&controller, t, u);
        if (rc != cart_OK) {  /* on a target: a fault handler (safe state) */
            fprintf(stderr, "controller refused tick %ld: code %d\n", k, rc);
            return 1;
        }
        printf("%.17g,%.17g,%.17g,%.17g\n", t, cart[0], cart[1], u[0]);
        send_command(u[0]);
    }
    return 0;
}
