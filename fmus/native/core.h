/* The version-free core of the FMI layers (core.c): what fmi2.c and fmi3.c share, each
 * returning a status as both versions number it (STATUS_OK, STATUS_ERROR) and naming the
 * caller's FMI function (fn) in its messages. Included by the FMI layers only. */
#ifndef DELAYCOMP_CORE_H
#define DELAYCOMP_CORE_H

#include "native.h"

#define ANY_STATE (StateInstantiated | StateInitializationMode | StateStepComplete | \
                   StateTerminated | StateError | StateEventMode)
#define MASK_GET (StateInitializationMode | StateStepComplete | StateTerminated | StateError | \
                  StateEventMode)
#define MASK_SET_PARAMETER (StateInstantiated | StateInitializationMode)
#define MASK_SET_INPUT (StateInstantiated | StateInitializationMode | StateStepComplete)
#define MASK_STATE (ANY_STATE)

const char *state_name(FsmState s);
/* Is the call fn allowed in the instance's state (a bit of mask)? Else 0, logged. */
int allowed(Instance *c, const char *fn, int mask);
/* A fault of the model: the error state, STATUS_ERROR. */
int model_fault(Instance *c);
/* A new instance of `size` bytes (an FMI layer's struct that begins with Instance), its
 * variables at their start values; NULL when out of memory. */
Instance *core_new(size_t size, const char *name);
void core_free(Instance *c);
void core_reset(Instance *c);  /* the start values, no buffer */
int core_exit_initialization(Instance *c, const char *fn);
int core_terminate(Instance *c, const char *fn);
/* A Real slot's value (an output through the model) */
int core_get_real(Instance *c, ValueRef slot, double *value);
/* Copy a String into its slot, or refuse one too long (named `name`) */
int core_string_ok(Instance *c, const char *name, const char *value);
/* A step from t to t + h: it starts where the last ended, the model takes it */
int core_do_step(Instance *c, double t, double h);

/* The FMU state: a self-checking snapshot of Data and the model buffer. */
int core_get_state(Instance *c, const char *fn, void **state);
int core_set_state(Instance *c, const char *fn, const void *state);
void core_free_state(void **state);
size_t core_state_size(const void *state);
int core_serialize(Instance *c, const char *fn, const void *state, unsigned char *out,
                   size_t size);
int core_deserialize(Instance *c, const char *fn, const unsigned char *in, size_t size,
                     void **state);

#endif
