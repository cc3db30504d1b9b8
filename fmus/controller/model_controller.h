/* The native DelaycompController_<model> (model_controller.c): its dimensions, where its
 * inputs and outputs start, and its data without pointers (ModelData, copied as it is
 * into an FMU state). fmus/native/native.h includes this header as config.h's
 * MODEL_HEADER; config.h (generated) gives NIN and NOUT (its Real inputs and outputs),
 * VR_INPUT and VR_OUTPUT (the value references of the first of each) and the VR_* macros
 * of the model's manifest (model_controller.toml beside it). */
#ifndef DELAYCOMP_MODEL_CONTROLLER_H
#define DELAYCOMP_MODEL_CONTROLLER_H

#define NX NIN  /* n measurements in, m controls out */
#define NU NOUT
#define VR_Y VR_INPUT  /* y_<state>, the measurement */
#define VR_UOUT VR_OUTPUT  /* the control */

typedef struct {
    int built;               /* the controller exists (initialized) */
    int branch;              /* the branch of model.c for the String parameters */
    int zoh;                 /* mode: 1 zero-order hold (Theorem 3.2), 0 continuous (2.1) */
    int predictor;           /* 0 closed, 1 numerical, 2 none (PREDICTOR_CHOICES) */
    long N;                  /* base steps per sampling period */
    double h;                /* the base step T / N */
    double tau_eff;          /* zoh: tau padded up to a multiple of T (Remark 3.3(b)) */
    long W;                  /* input history: base steps of the window r + tau */
    long D;                  /* zoh: the output's own delay line (padding), base steps */
    long k_tick;             /* base steps since t0 */
    long hist_head;          /* ring position of the oldest history entry */
    long pad_head;           /* ring position of the oldest padding entry */
    double z[NX];            /* continuous: the predictor state at the current tick */
    double held[NU];         /* zoh: the control held over the current period */
    int cache_valid;         /* cache_* are the evaluation of the current sample */
    double cache_z[NX];
    double cache_u[NU];
    int y_held_valid;        /* held_sample: the input held over the step that ended */
    double y_held[NX];
} ModelData;

#endif
