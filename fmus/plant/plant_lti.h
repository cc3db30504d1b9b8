/* The native DelaycompPlantLTI (plant_lti.c): its dimensions, where its inputs and
 * outputs start, and its data without pointers (ModelData, copied as it is into an FMU
 * state). fmus/native/native.h includes this header as config.h's MODEL_HEADER; config.h
 * (generated) gives NIN and NOUT (its Real inputs and outputs), VR_INPUT and VR_OUTPUT
 * (the value references of the first of each) and the VR_* macros of the model's
 * manifest (plant_lti.toml beside it). */
#ifndef DELAYCOMP_PLANT_LTI_H
#define DELAYCOMP_PLANT_LTI_H

#define NX NOUT  /* n states out, m inputs in */
#define NU NIN
#define VR_U VR_INPUT  /* u1 .. um */
#define VR_X VR_OUTPUT  /* x1 .. xn, the state */

typedef struct {
    int has_h;       /* Ad, Bd are computed for step h */
    double h;
} ModelData;

#endif
