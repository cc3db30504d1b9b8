/* The native DelaycompControllerStamped (controller_stamped.c): its dimensions, where its
 * inputs and outputs start, and its data without pointers (ModelData, copied as it is into
 * an FMU state). fmus/native/native.h includes this header as config.h's MODEL_HEADER;
 * config.h (generated) gives NIN and NOUT (its Real inputs and outputs: y1 .. yn and the
 * stamp; u1 .. um), VR_INPUT and VR_OUTPUT and the VR_* macros of the model's manifest
 * (controller_stamped.toml beside it). */
#ifndef DELAYCOMP_CONTROLLER_STAMPED_H
#define DELAYCOMP_CONTROLLER_STAMPED_H

#define NX (NIN - 1)  /* n measurements and their stamp in, m controls out */
#define NU NOUT
#define VR_Y VR_INPUT          /* y1 .. yn, the sample */
#define VR_STAMP (VR_INPUT + NX)  /* stamp, the time it was taken */
#define VR_UOUT VR_OUTPUT      /* u1 .. um, the control */

typedef struct {
    int built;               /* the history and work memory exist (initialized) */
    long L;                  /* outputs stored: floor((age_max + tau) / T) + 2 */
    long next;               /* i, the index of the next sampling instant t0 + i T */
    int at_sample;           /* the current time is a sampling instant not yet committed */
    int proposal_valid;      /* proposal[] = u_i from the current sample */
    double proposal[NU];
    int y_held_valid;        /* held_sample: the sample held over the step that ended */
    double y_held[NX];
    double stamp_held;       /* and its stamp */
    double held[NU];         /* the output held over the current period */
    long hist_head;          /* ring position of u_{i-1} in the output history */
    double z[NX];            /* the estimate of x(t_{i-1}) (next >= 1; zeros before) */
    double stamp;            /* the stamp of the newest sample used (next >= 1; 0 before) */
} ModelData;

#endif
