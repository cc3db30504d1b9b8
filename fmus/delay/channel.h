/* The native DelaycompChannel (channel.c): its dimensions, where its variables start, and
 * its data without pointers (ModelData, copied as it is into an FMU state). native.h
 * includes this header as config.h's MODEL_HEADER; config.h (generated) gives NIN, NOUT,
 * VR_INPUT, VR_OUTPUT and the VR_* macros of the manifest (channel.toml beside it). */
#ifndef DELAYCOMP_CHANNEL_H
#define DELAYCOMP_CHANNEL_H

#define NX NIN  /* n signals in, n out (and the stamp) */
#define NU NIN
#define VR_U VR_INPUT        /* u1 .. un, the signals sent */
#define VR_Y VR_OUTPUT       /* y1 .. yn, the last delivered packet's values */
#define VR_STAMP (VR_OUTPUT + NX)  /* its send time */
/* The trace trace[1..L] lies between seed and u0[1] in the table (the Python twin
 * registers them in that order; tests/test_channel_native.py holds it to it): L = VR_U0 - VR_TRACE, 0 without. */
#define VR_TRACE (VR_SEED + 1)
#define NTRACE (VR_U0 - VR_TRACE)

/* A packet in the buffer: PK_WIDTH doubles (integers held exactly below 2^53). */
#define PK_SEQ 0     /* its number j */
#define PK_SENT 1    /* the step it left, j P */
#define PK_READY 2   /* the step it is seen (lost: the step of its timeout) */
#define PK_LOST 3    /* 1.0 lost, 0.0 not */
#define PK_VALUES 4  /* its n values */
#define PK_WIDTH (PK_VALUES + NX)

typedef struct {
    int has_line;    /* the step, and so P and Q, is known (fixed by the first doStep) */
    double h;        /* the communication step of the first doStep */
    long P;          /* steps between packets */
    long Q;          /* the timeout in steps: steps_up(the largest delay, h) */
    long cap;        /* packet slots after the shown one: Q / P + 3 */
    long long k;     /* the grid index of the current time */
    int bad;         /* the Gilbert-Elliott chain's state */
    int has_current; /* a packet was delivered (buffer slot 0) */
    long count;      /* packets in flight, slots 1 .. count, in the order sent */
} ModelData;

#endif
