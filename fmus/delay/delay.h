/* The native DelaycompDelay (delay.c): its dimensions, where its inputs and outputs
 * start, and its data without pointers (ModelData, copied as it is into an FMU state).
 * fmus/native/native.h includes this header as config.h's MODEL_HEADER; config.h
 * (generated) gives NIN and NOUT (its Real inputs and outputs), VR_INPUT and VR_OUTPUT
 * (the value references of the first of each) and the VR_* macros of the model's
 * manifest (delay.toml beside it). */
#ifndef DELAYCOMP_DELAY_H
#define DELAYCOMP_DELAY_H

#define NX NIN  /* n channels in, n out */
#define NU NIN
#define VR_U VR_INPUT  /* u1 .. un, the delayed signal */
#define VR_Y VR_OUTPUT  /* y1 .. yn */

typedef struct {
    int has_line;    /* the step, and so D, is known (fixed by the first doStep) */
    long D;          /* delay in steps */
    double h;        /* the communication step of the first doStep */
    long head;       /* ring position of the oldest value u_{k-D} */
} ModelData;

#endif
