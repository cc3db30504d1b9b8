/* The native DelaycompPlant_<model> (model_plant.c): its dimensions, where its inputs
 * and outputs start, and its data without pointers (ModelData, copied as it is into an
 * FMU state). fmus/native/native.h includes this header as config.h's MODEL_HEADER;
 * config.h (generated) gives NIN and NOUT (its Real inputs and outputs), VR_INPUT and
 * VR_OUTPUT (the value references of the first of each) and the VR_* macros of the
 * model's manifest (model_plant.toml beside it). */
#ifndef DELAYCOMP_MODEL_PLANT_H
#define DELAYCOMP_MODEL_PLANT_H

#define NX NOUT  /* n states out, m inputs in */
#define NU NIN
#define VR_U VR_INPUT  /* the model's inputs */
#define VR_X VR_OUTPUT  /* its states */

typedef struct {
    int branch;      /* the branch of model.c for the String parameters (model_setup) */
} ModelData;

#endif
