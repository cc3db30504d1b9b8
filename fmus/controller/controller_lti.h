/* The native DelaycompControllerLTI (controller_lti.c): its dimensions, where its inputs
 * and outputs start, and its data without pointers (ModelData, copied as it is into an
 * FMU state). fmus/native/native.h includes this header as config.h's MODEL_HEADER;
 * config.h (generated) gives NIN and NOUT (its Real inputs and outputs), VR_INPUT and
 * VR_OUTPUT (the value references of the first of each) and the VR_* macros of the
 * model's manifest (controller_lti.toml beside it). */
#ifndef DELAYCOMP_CONTROLLER_LTI_H
#define DELAYCOMP_CONTROLLER_LTI_H

#define NX NIN  /* n measurements in, m controls out */
#define NU NOUT
#define VR_Y VR_INPUT  /* y1 .. yn, the measurement */
#define VR_UOUT VR_OUTPUT  /* u1 .. um, the control */

typedef struct {
    int built;               /* the predictor matrices exist (initialized) */
    long l, q, L;            /* tau_eff = l T, q = [r/T], L = l + q + 1 */
    double r_tilde;
    double padding;          /* pad: tau_eff - tau (Remark 3.3(b)), 0 without */
    int released;            /* pad: the time is at or after t_{next-1} + padding */
    double pad_line[NU];     /* pad: the output held before the last commit, shown until
                              * t_{next-1} + padding */
    long next;               /* index of the next sampling instant t0 + i T */
    int at_sample;           /* the current time is a sampling instant not yet committed */
    int proposal_valid;      /* proposal[] = u_i from the current y */
    double proposal[NU];
    int y_held_valid;        /* held_sample: the input held over the step that ended */
    double y_held[NX];
    double held[NU];         /* the output held over the current period */
    long hist_head;          /* ring position of u_{i-1} in the input history */
} ModelData;

#endif
