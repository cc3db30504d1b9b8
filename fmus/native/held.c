/* The sampled controllers' held sample and proposal (held.h): one copy of
 * delaycomp.fmu.sampling.HeldSampleMixin's rules and of the proposal's, for the LTI, the
 * time-stamp and the model controllers. */
#include <string.h>

#include "held.h"

const double *held_sample(int held_sample, int y_held_valid, const double *y_held,
                          const double *y) {
    return held_sample && y_held_valid ? y_held : y;
}

int held_keep(int held_sample, const double *y, size_t n, double *y_held, int *y_held_valid) {
    if (!held_sample) return 0;
    memcpy(y_held, y, n * sizeof(double));
    *y_held_valid = 1;
    return 1;
}

int held_state_ok(const StateView *v, int held_sample, int y_held_valid, const double *y_held,
                  size_t n) {
    if (y_held_valid && !held_sample)
        return state_refuse(v, "y_held_valid = 1: must be 0 with held_sample = false");
    return y_held_valid ? state_finite(v, "y_held", y_held, n)
                        : state_zeros(v, "y_held", y_held, n, "y_held_valid = 0");
}

int proposal_once(Instance *c, ProposeFn propose, const void *ctx, int *proposal_valid,
                  double *proposal, const double *y, double t, const double *refused,
                  const double **u) {
    if (!*proposal_valid) {
        if (propose(c, ctx, proposal) != 0) {
            *u = refused;
            return -1;
        }
        *proposal_valid = 1;
        if (check_control_finite(c, proposal, y, t, "the feedback diverged: overflow") != 0) {
            *u = proposal;
            return -1;
        }
    }
    *u = proposal;
    return 0;
}

int proposal_flag_ok(const StateView *v, int proposal_valid, int at_sample) {
    if (!proposal_valid || at_sample) return 1;
    return state_refuse(v, "proposal_valid = 1: must be 0 between sampling instants "
                        "(at_sample = 0)");
}

int proposal_same(const StateView *v, const double *proposal, const double *u) {
    if (memcmp(u, proposal, NU * sizeof(double)) == 0) return 1;
    return state_refuse(v, "proposal = %s: must be %s, u_i of the current sample "
                        "(proposal_valid = 1)", vector_text(proposal, NU).s,
                        vector_text(u, NU).s);
}
