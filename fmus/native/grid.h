/* The base grid's rules, written once for the native models: whether a value is a whole
 * number of a step, and the rules built on that answer. The mirror of
 * delaycomp.maths.grid (nearest_multiple, steps_up, split, padded_delay), with its
 * arithmetic, so a native FMU accepts and refuses exactly the values its Python twin does
 * and sizes its buffers alike. (same_step, drift and grid_step, the rules every FMU's
 * stepping needs, are native.c's.) */
#ifndef DELAYCOMP_GRID_H
#define DELAYCOMP_GRID_H

/* delaycomp.maths.grid.nearest_multiple: 1 with *k the integer (a whole double: Python's
 * round, ties to even) with value = k step up to GRID_RTOL max(1, |value / step|); 0 where
 * there is none, a ratio that is not finite included (*k untouched). */
int nearest_multiple(double value, double step, double *k);

/* delaycomp.maths.grid.steps_up: the first grid point at or after value, the least k with
 * k step >= value, a whole multiple up to GRID_RTOL taken as it is (else ceil). */
double steps_up(double value, double step);

/* delaycomp.maths.grid.split: *q = [value / period] and *rest = value - q period in
 * [0, period); a whole multiple up to GRID_RTOL gives it exactly (rest 0), where the floor
 * of the raw quotient would put almost a whole period into rest. q is a whole double. */
void split(double value, double period, double *q, double *rest);

/* delaycomp.maths.grid.padded_delay: ceil(tau / T) T, a tau that is a multiple of T up to
 * round-off kept as it is (Remark 3.3(b)). */
double padded_delay(double tau, double T);

#endif
