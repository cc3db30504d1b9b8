/* The sampled controllers' held sample and proposal, written once for the three native
 * controllers (the LTI, the time-stamp and a user model's). The mirror of
 * delaycomp.fmu.sampling.HeldSampleMixin (_sample, _hold, _checked_held) and of the proposal
 * the Python controllers keep (_proposed: u_i computed once per sample, committed by the
 * step that leaves the sampling instant).
 *
 * With held_sample = true a controller samples at t_i the input held over the step that
 * ended at t_i (before the first step: the input itself), so its output does not depend on
 * its input at the same instant: for masters that read every output right after doStep and
 * only then set inputs. The fields (y_held_valid, y_held, proposal_valid, proposal) stay in
 * each controller's ModelData, which an FMU state copies as it is: these functions take
 * them by pointer, and the parameter held_sample by value (the shared C addresses no
 * model's value reference). */
#ifndef DELAYCOMP_HELD_H
#define DELAYCOMP_HELD_H

#include <stddef.h>

#include "native.h"

/* HeldSampleMixin._sample: the measurement sampled now, y, or with held_sample, y_held once
 * a step held one (y_held_valid). */
const double *held_sample(int held_sample, int y_held_valid, const double *y_held,
                          const double *y);

/* HeldSampleMixin._hold, at the end of a step: with held_sample, y (n values) kept as
 * y_held and 1 (a proposal made from the sample before is stale); else 0, nothing kept. */
int held_keep(int held_sample, const double *y, size_t n, double *y_held, int *y_held_valid);

/* HeldSampleMixin._checked_held, a restored state's held input: none without held_sample;
 * n finite numbers where one is held (y_held_valid), else n zeros. */
int held_state_ok(const StateView *v, int held_sample, int y_held_valid, const double *y_held,
                  size_t n);

/* What computes u_i (NU values) from the sample the controller's ctx describes: 0, or -1
 * (logged) where the sample is refused. */
typedef int (*ProposeFn)(Instance *c, const void *ctx, double *u);

/* u_i of the current sample (*u): computed into proposal by propose once per sample (while
 * *proposal_valid), then checked finite where the measurement y is (the proposal is kept
 * before the check, as the Python FMUs keep it). 0; -1 (logged) with *u = refused where
 * propose refuses the sample, or *u = proposal where the control overflows at time t. */
int proposal_once(Instance *c, ProposeFn propose, const void *ctx, int *proposal_valid,
                  double *proposal, const double *y, double t, const double *refused,
                  const double **u);

/* A restored proposal: proposal_valid only at a sampling instant not yet committed. */
int proposal_flag_ok(const StateView *v, int proposal_valid, int at_sample);

/* A restored proposal (proposal_valid = 1) and u, the same one recomputed from the
 * restored state (the same arithmetic gives the same bits): equal, bit for bit (NU
 * values). */
int proposal_same(const StateView *v, const double *proposal, const double *u);

#endif
