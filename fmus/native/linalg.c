/* Matrix exponential and the exact flow of x' = A x + B u for the native FMUs.
 *
 * expm: scaling and squaring with a diagonal Pade approximant, the algorithm of
 * N. J. Higham, "The scaling and squaring method for the matrix exponential revisited",
 * SIAM J. Matrix Anal. Appl. 26(4), 2005 (Algorithm 2.3): the degree m in {3, 5, 7, 9} is
 * the smallest with ||A||_1 <= theta_m, else A is scaled by 2^-s so that
 * ||A 2^-s||_1 <= theta_13, the [13/13] approximant is taken and squared s times. The
 * 1 x 1 case is exp(), and the 2 x 2 upper triangular case with a zero in the corner
 * (Van Loan's augmented matrix of a scalar plant) is its closed form, as scipy's expm
 * also computes it exactly. Checked against scipy.linalg.expm in tests/test_native.py.
 * Nothing is allocated: the caller hands the work memory (linalg.h).
 */
#include <math.h>
#include <string.h>

#include "linalg.h"

void matmul(const double *a, const double *b, size_t n, size_t k, size_t m, double *out) {
    for (size_t i = 0; i < n; i++) {
        for (size_t j = 0; j < m; j++) {
            double s = 0.0;
            for (size_t p = 0; p < k; p++) s += a[i * k + p] * b[p * m + j];
            out[i * m + j] = s;
        }
    }
}

static double norm1(const double *a, size_t n) {
    double best = 0.0;
    for (size_t j = 0; j < n; j++) {
        double s = 0.0;
        for (size_t i = 0; i < n; i++) s += fabs(a[i * n + j]);
        if (s > best || isnan(s)) best = s;
    }
    return best;
}

/* Solve P X = Q (n x n, in place: Q becomes X) by Gaussian elimination with partial
 * pivoting. P is overwritten. */
static void solve(double *P, double *Q, size_t n) {
    for (size_t k = 0; k < n; k++) {
        size_t piv = k;
        for (size_t i = k + 1; i < n; i++)
            if (fabs(P[i * n + k]) > fabs(P[piv * n + k])) piv = i;
        if (piv != k) {
            for (size_t j = 0; j < n; j++) {
                double t = P[k * n + j]; P[k * n + j] = P[piv * n + j]; P[piv * n + j] = t;
                t = Q[k * n + j]; Q[k * n + j] = Q[piv * n + j]; Q[piv * n + j] = t;
            }
        }
        double d = P[k * n + k];
        for (size_t i = k + 1; i < n; i++) {
            double f = P[i * n + k] / d;
            if (f == 0.0) continue;
            for (size_t j = k; j < n; j++) P[i * n + j] -= f * P[k * n + j];
            for (size_t j = 0; j < n; j++) Q[i * n + j] -= f * Q[k * n + j];
        }
    }
    for (size_t kk = n; kk-- > 0;) {
        double d = P[kk * n + kk];
        for (size_t j = 0; j < n; j++) {
            double s = Q[kk * n + j];
            for (size_t p = kk + 1; p < n; p++) s -= P[kk * n + p] * Q[p * n + j];
            Q[kk * n + j] = s / d;
        }
    }
}

static const double B3[] = {120.0, 60.0, 12.0, 1.0};
static const double B5[] = {30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0};
static const double B7[] = {17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0,
                            56.0, 1.0};
static const double B9[] = {17643225600.0, 8821612800.0, 2075673600.0, 302702400.0,
                            30270240.0, 2162160.0, 110880.0, 3960.0, 90.0, 1.0};
static const double B13[] = {64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
                             1187353796428800.0, 129060195264000.0, 10559470521600.0,
                             670442572800.0, 33522128640.0, 1323241920.0, 40840800.0,
                             960960.0, 16380.0, 182.0, 1.0};
static const double THETA[] = {1.495585217958292e-2, 2.539398330063230e-1,
                               9.504178996162932e-1, 2.097847961257068e0,
                               5.371920351148152e0};

size_t expm_work_size(size_t n) { return 7 * n * n; }

void expm(const double *a, size_t n, double *out, double *work) {
    if (n == 0) return;
    if (n == 1) {
        out[0] = exp(a[0]);
        return;
    }
    if (n == 2 && a[2] == 0.0 && a[3] == 0.0) {  /* [[x, y], [0, 0]]: closed form */
        double x = a[0], y = a[1];
        out[0] = exp(x);
        out[1] = x == 0.0 ? y : y * (expm1(x) / x);
        out[2] = 0.0;
        out[3] = 1.0;
        return;
    }
    size_t nn = n * n;
    double *w = work;
    double *A = w, *A2 = w + nn, *A4 = w + 2 * nn, *A6 = w + 3 * nn, *U = w + 4 * nn,
           *V = w + 5 * nn, *T = w + 6 * nn;
    memcpy(A, a, nn * sizeof(double));
    double nrm = norm1(A, n);
    int deg = 13, s = 0;
    const double *b = B13;
    if (nrm <= THETA[0]) { deg = 3; b = B3; }
    else if (nrm <= THETA[1]) { deg = 5; b = B5; }
    else if (nrm <= THETA[2]) { deg = 7; b = B7; }
    else if (nrm <= THETA[3]) { deg = 9; b = B9; }
    else if (isfinite(nrm)) {
        s = (int)ceil(log2(nrm / THETA[4]));
        if (s < 0) s = 0;
        if (s > 0) {
            double f = ldexp(1.0, -s);
            for (size_t i = 0; i < nn; i++) A[i] *= f;
        }
    }
    matmul(A, A, n, n, n, A2);
    if (deg == 13) {
        matmul(A2, A2, n, n, n, A4);
        matmul(A4, A2, n, n, n, A6);
        /* U = A [A6 (b13 A6 + b11 A4 + b9 A2) + b7 A6 + b5 A4 + b3 A2 + b1 I] */
        for (size_t i = 0; i < nn; i++) T[i] = b[13] * A6[i] + b[11] * A4[i] + b[9] * A2[i];
        matmul(A6, T, n, n, n, U);
        for (size_t i = 0; i < nn; i++) U[i] += b[7] * A6[i] + b[5] * A4[i] + b[3] * A2[i];
        for (size_t i = 0; i < n; i++) U[i * n + i] += b[1];
        memcpy(T, U, nn * sizeof(double));
        matmul(A, T, n, n, n, U);
        /* V = A6 (b12 A6 + b10 A4 + b8 A2) + b6 A6 + b4 A4 + b2 A2 + b0 I */
        for (size_t i = 0; i < nn; i++) T[i] = b[12] * A6[i] + b[10] * A4[i] + b[8] * A2[i];
        matmul(A6, T, n, n, n, V);
        for (size_t i = 0; i < nn; i++) V[i] += b[6] * A6[i] + b[4] * A4[i] + b[2] * A2[i];
        for (size_t i = 0; i < n; i++) V[i * n + i] += b[0];
    } else {
        /* even powers A^0, A^2, ..., A^(deg-1) built one after another in A4 */
        memset(U, 0, nn * sizeof(double));
        memset(V, 0, nn * sizeof(double));
        memset(A4, 0, nn * sizeof(double));
        for (size_t i = 0; i < n; i++) A4[i * n + i] = 1.0;  /* A^0 */
        for (int k = 0; 2 * k < deg; k++) {
            for (size_t i = 0; i < nn; i++) {
                U[i] += b[2 * k + 1] * A4[i];
                V[i] += b[2 * k] * A4[i];
            }
            if (2 * k + 2 < deg) {
                matmul(A4, A2, n, n, n, A6);
                memcpy(A4, A6, nn * sizeof(double));
            }
        }
        memcpy(T, U, nn * sizeof(double));
        matmul(A, T, n, n, n, U);
    }
    /* (V - U) R = (V + U) */
    for (size_t i = 0; i < nn; i++) {
        T[i] = V[i] - U[i];
        out[i] = V[i] + U[i];
    }
    solve(T, out, n);
    for (int k = 0; k < s; k++) {
        matmul(out, out, n, n, n, T);
        memcpy(out, T, nn * sizeof(double));
    }
}

size_t flow_work_size(size_t n, size_t m) { return 9 * (n + m) * (n + m); }

void flow(const double *A, const double *B, size_t n, size_t m, double s, double *E,
          double *G, double *work) {
    size_t N = n + m;
    double *M = work, *F = M + N * N;
    memset(M, 0, N * N * sizeof(double));
    for (size_t i = 0; i < n; i++) {
        for (size_t j = 0; j < n; j++) M[i * N + j] = A[i * n + j] * s;
        for (size_t j = 0; j < m; j++) M[i * N + n + j] = B[i * m + j] * s;
    }
    expm(M, N, F, F + N * N);
    for (size_t i = 0; i < n; i++) {
        for (size_t j = 0; j < n; j++) E[i * n + j] = F[i * N + j];
        for (size_t j = 0; j < m; j++) G[i * m + j] = F[i * N + n + j];
    }
}
