/* linalg.h: the matrix exponential and the exact flow of x' = A x + B u, for the native
 * FMUs (linalg.c). Standalone: the C library and libm; allocates nothing (the caller
 * hands the work memory, so an FMU allocates it once, at initialization). Row-major
 * matrices. */
#ifndef DELAYCOMP_LINALG_H
#define DELAYCOMP_LINALG_H

#include <stddef.h>

/* out (n x m) = a (n x k) b (k x m); out must not alias a or b */
void matmul(const double *a, const double *b, size_t n, size_t k, size_t m, double *out);

/* Doubles of work memory that expm needs for an n x n matrix: 7 n^2. */
size_t expm_work_size(size_t n);
/* out = e^a (n x n): scaling and squaring with a diagonal Pade approximant (Higham 2005).
 * work: expm_work_size(n) doubles, aliasing neither a nor out. Bounded work: at most
 * 6 + s + 1 products of n x n matrices and one solve, s <= 1100 squarings (the scaling of
 * the largest finite norm). */
void expm(const double *a, size_t n, double *out, double *work);

/* Doubles of work memory that flow needs: 9 (n + m)^2. */
size_t flow_work_size(size_t n, size_t m);
/* x(s) = E x(0) + G u for x' = A x + B u, u constant: E = e^{As} (n x n),
 * G = int_0^s e^{Aw} dw B (n x m), from Van Loan's augmented exponential.
 * work: flow_work_size(n, m) doubles, aliasing none of the others. */
void flow(const double *A, const double *B, size_t n, size_t m, double s, double *E,
          double *G, double *work);

#endif
