/* Hyperelastic element kernels for P1 tetrahedra (see elastic.h for the interface).
 *
 * Structure: per element, build F, evaluate the material (psi, P and whatever the tangent needs,
 * kept in a State), then
 *   - the gradient g_a = V P dN_a;
 *   - the Hessian either by a closed form per model (fast path: every model's dP/dF is a few
 *     identity and rank-one terms, so each 3x3 block H_ab is a handful of outer products of
 *     per-node vectors), or, when SPD projection is requested, by building dP/dF as a 9x9
 *     matrix, projecting it, and contracting it with the shape gradients (generic path).
 * Only blocks b >= a are computed; the transpose fills the rest, so H is exactly symmetric.
 *
 * 3x3 matrices are row-major: M[3*i + j]. The 9x9 tangent is A[(3i+j)*9 + 3k+l] = dP_ij/dF_kl.
 */
#include "elastic.h"

#include <float.h>
#include <math.h>
#include <string.h>

/* Must match materials.SIGMA_SUM_MIN: lower bound on sigma_p + sigma_q in dR/dF. */
#define SIGMA_SUM_MIN 1e-12

/* Everything the gradient and the tangent of one element need. */
typedef struct {
    double F[9];
    double P[9];
    double psi;
    double J;
    /* neo-Hookean */
    double FinvT[9]; /* F^{-T} */
    double logJ;
    /* StVK */
    double S[9]; /* second Piola-Kirchhoff stress */
    double B[9]; /* F F^T */
    /* corotated: F = U diag(sig) V^T, R = U V^T, twist modes Q[m] = u_p v_q^T - u_q v_p^T */
    double U[9], V[9], sig[3], R[9];
    double Q[3][9];
    double T[3]; /* 1 / (sig_p + sig_q) */
    double c1;   /* lam (tr S - 3) - 2 mu: coefficient of dR/dF in dP/dF */
} State;

static const int PAIR_P[3] = {0, 0, 1};
static const int PAIR_Q[3] = {1, 2, 2};

/* ------------------------------------------------------------------------------------------ */
/* Small dense linear algebra                                                                 */
/* ------------------------------------------------------------------------------------------ */

static inline void deformation_gradient(const double *dN, const double *u, double *F)
{
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            F[3 * i + j] = (i == j ? 1.0 : 0.0) + u[i] * dN[j] + u[3 + i] * dN[3 + j] +
                           u[6 + i] * dN[6 + j] + u[9 + i] * dN[9 + j];
}

static inline double det3(const double *F)
{
    return F[0] * (F[4] * F[8] - F[5] * F[7]) + F[1] * (F[5] * F[6] - F[3] * F[8]) +
           F[2] * (F[3] * F[7] - F[4] * F[6]);
}

/* F^{-T} = cof(F) / det F. */
static inline void inverse_transpose3(const double *F, double J, double *FinvT)
{
    const double s = 1.0 / J;
    FinvT[0] = (F[4] * F[8] - F[5] * F[7]) * s;
    FinvT[1] = (F[5] * F[6] - F[3] * F[8]) * s;
    FinvT[2] = (F[3] * F[7] - F[4] * F[6]) * s;
    FinvT[3] = (F[2] * F[7] - F[1] * F[8]) * s;
    FinvT[4] = (F[0] * F[8] - F[2] * F[6]) * s;
    FinvT[5] = (F[1] * F[6] - F[0] * F[7]) * s;
    FinvT[6] = (F[1] * F[5] - F[2] * F[4]) * s;
    FinvT[7] = (F[2] * F[3] - F[0] * F[5]) * s;
    FinvT[8] = (F[0] * F[4] - F[1] * F[3]) * s;
}

static inline double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* y_a = M dN_a for the 4 nodes. */
static inline void apply_nodes(const double *M, const double *dN, double y[4][3])
{
    for (int a = 0; a < 4; ++a)
        for (int i = 0; i < 3; ++i)
            y[a][i] = M[3 * i] * dN[3 * a] + M[3 * i + 1] * dN[3 * a + 1] +
                      M[3 * i + 2] * dN[3 * a + 2];
}

/* Rotation-variant SVD F = U diag(sig) V^T with det U = det V = +1, sig0 >= sig1 >= |sig2|
 * (sig2 < 0 iff det F < 0), by one-sided (Hestenes) Jacobi: right rotations orthogonalise the
 * columns of B = F V; then sig_c = |b_c|, u_c = b_c / sig_c. It computes small singular values
 * to high relative accuracy (unlike an eigen-decomposition of F^T F) and U is orthogonal to
 * working precision because u_2 = u_0 x u_1. Same conventions as materials.signed_svd. */
static void signed_svd3(const double *F, double *U, double *sig, double *V)
{
    double B[9];
    memcpy(B, F, sizeof B);
    for (int i = 0; i < 9; ++i) V[i] = (i % 4 == 0) ? 1.0 : 0.0;

    for (int sweep = 0; sweep < 30; ++sweep) {
        int rotated = 0;
        for (int m = 0; m < 3; ++m) {
            const int p = PAIR_P[m], q = PAIR_Q[m];
            double alpha = 0.0, beta = 0.0, gamma = 0.0;
            for (int r = 0; r < 3; ++r) {
                alpha += B[3 * r + p] * B[3 * r + p];
                beta += B[3 * r + q] * B[3 * r + q];
                gamma += B[3 * r + p] * B[3 * r + q];
            }
            if (!(fabs(gamma) > DBL_EPSILON * sqrt(alpha * beta))) continue;
            /* Zero the off-diagonal of the 2x2 Gram matrix [[alpha, gamma], [gamma, beta]]. */
            const double zeta = (beta - alpha) / (2.0 * gamma);
            const double t = fabs(zeta) > 1e150
                                 ? 0.5 / zeta
                                 : copysign(1.0, zeta) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
            const double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
            for (int r = 0; r < 3; ++r) {
                const double bp = B[3 * r + p], bq = B[3 * r + q];
                B[3 * r + p] = c * bp - s * bq;
                B[3 * r + q] = s * bp + c * bq;
                const double vp = V[3 * r + p], vq = V[3 * r + q];
                V[3 * r + p] = c * vp - s * vq;
                V[3 * r + q] = s * vp + c * vq;
            }
            rotated = 1;
        }
        if (!rotated) break;
    }

    double nrm[3];
    for (int c = 0; c < 3; ++c)
        nrm[c] = sqrt(B[c] * B[c] + B[3 + c] * B[3 + c] + B[6 + c] * B[6 + c]);
    /* Sort columns by decreasing norm (3-element sorting network). */
    static const int SWAP_A[3] = {0, 1, 0}, SWAP_B[3] = {1, 2, 1};
    for (int k = 0; k < 3; ++k) {
        const int a = SWAP_A[k], b = SWAP_B[k];
        if (nrm[a] < nrm[b]) {
            double tmp = nrm[a];
            nrm[a] = nrm[b];
            nrm[b] = tmp;
            for (int r = 0; r < 3; ++r) {
                tmp = B[3 * r + a];
                B[3 * r + a] = B[3 * r + b];
                B[3 * r + b] = tmp;
                tmp = V[3 * r + a];
                V[3 * r + a] = V[3 * r + b];
                V[3 * r + b] = tmp;
            }
        }
    }
    /* Make V a proper rotation; negating v_2 negates b_2 = F v_2. */
    if (det3(V) < 0.0)
        for (int r = 0; r < 3; ++r) {
            V[3 * r + 2] = -V[3 * r + 2];
            B[3 * r + 2] = -B[3 * r + 2];
        }

    double u0[3], u1[3];
    if (nrm[0] > 0.0) {
        for (int r = 0; r < 3; ++r) u0[r] = B[3 * r] / nrm[0];
    } else {
        u0[0] = 1.0, u0[1] = 0.0, u0[2] = 0.0;
    }
    if (nrm[1] > 1e-150 * nrm[0]) {
        for (int r = 0; r < 3; ++r) u1[r] = B[3 * r + 1] / nrm[1];
    } else {
        /* Rank <= 1: any unit vector orthogonal to u0 completes the basis. */
        const int k = (fabs(u0[0]) < 0.5) ? 0 : ((fabs(u0[1]) < 0.5) ? 1 : 2);
        double e[3] = {0.0, 0.0, 0.0};
        e[k] = 1.0;
        const double d = u0[k];
        double nn = 0.0;
        for (int r = 0; r < 3; ++r) {
            u1[r] = e[r] - d * u0[r];
            nn += u1[r] * u1[r];
        }
        nn = 1.0 / sqrt(nn);
        for (int r = 0; r < 3; ++r) u1[r] *= nn;
    }
    const double u2[3] = {u0[1] * u1[2] - u0[2] * u1[1], u0[2] * u1[0] - u0[0] * u1[2],
                          u0[0] * u1[1] - u0[1] * u1[0]};
    for (int r = 0; r < 3; ++r) {
        U[3 * r] = u0[r];
        U[3 * r + 1] = u1[r];
        U[3 * r + 2] = u2[r];
    }
    sig[0] = nrm[0];
    sig[1] = nrm[1];
    sig[2] = u2[0] * B[2] + u2[1] * B[5] + u2[2] * B[8]; /* signed */
}

/* Cholesky test: 1 if the symmetric 9x9 A is (numerically) positive definite. */
static int is_positive_definite9(const double *A)
{
    double L[81];
    for (int j = 0; j < 9; ++j) {
        double d = A[9 * j + j];
        for (int k = 0; k < j; ++k) d -= L[9 * j + k] * L[9 * j + k];
        if (!(d > 0.0)) return 0;
        d = sqrt(d);
        L[9 * j + j] = d;
        const double inv = 1.0 / d;
        for (int i = j + 1; i < 9; ++i) {
            double s = A[9 * i + j];
            for (int k = 0; k < j; ++k) s -= L[9 * i + k] * L[9 * j + k];
            L[9 * i + j] = s * inv;
        }
    }
    return 1;
}

/* Cyclic Jacobi eigen-decomposition of the symmetric n x n W (n <= 9; overwritten: its diagonal
 * holds the eigenvalues on return), eigenvectors in the columns of Q. Rotations below
 * 1e-15 |W|_F are skipped: that is the rounding level the rotations themselves leave behind. */
static void jacobi_eigen(int n, double *W, double *Q)
{
    double frob2 = 0.0;
    for (int i = 0; i < n * n; ++i) {
        frob2 += W[i] * W[i];
        Q[i] = (i % (n + 1) == 0) ? 1.0 : 0.0;
    }
    const double tol = 1e-15 * sqrt(frob2);
    for (int sweep = 0; sweep < 50; ++sweep) {
        int rotated = 0;
        for (int p = 0; p < n - 1; ++p)
            for (int q = p + 1; q < n; ++q) {
                const double apq = W[n * p + q];
                if (!(fabs(apq) > tol)) continue;
                const double theta = (W[n * q + q] - W[n * p + p]) / (2.0 * apq);
                const double t =
                    fabs(theta) > 1e150
                        ? 0.5 / theta
                        : copysign(1.0, theta) / (fabs(theta) + sqrt(1.0 + theta * theta));
                const double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
                /* W <- J^T W J with J = I except J_pp = J_qq = c, J_pq = s, J_qp = -s. */
                for (int k = 0; k < n; ++k) {
                    const double wkp = W[n * k + p], wkq = W[n * k + q];
                    W[n * k + p] = c * wkp - s * wkq;
                    W[n * k + q] = s * wkp + c * wkq;
                }
                for (int k = 0; k < n; ++k) {
                    const double wpk = W[n * p + k], wqk = W[n * q + k];
                    W[n * p + k] = c * wpk - s * wqk;
                    W[n * q + k] = s * wpk + c * wqk;
                }
                W[n * p + q] = W[n * q + p] = 0.0;
                for (int k = 0; k < n; ++k) {
                    const double qkp = Q[n * k + p], qkq = Q[n * k + q];
                    Q[n * k + p] = c * qkp - s * qkq;
                    Q[n * k + q] = s * qkp + c * qkq;
                }
                rotated = 1;
            }
        if (!rotated) break;
    }
}

/* A <- A - sum_{lambda_m < 0} lambda_m q_m q_m^T (as materials.project_spd). A positive
 * definite A (the common case) is recognised by a Cholesky factorisation and left untouched,
 * which skips the eigen-decomposition for most elements. */
static void project_psd9(double *A)
{
    for (int i = 0; i < 9; ++i)
        for (int j = i + 1; j < 9; ++j) A[9 * i + j] = A[9 * j + i] =
            0.5 * (A[9 * i + j] + A[9 * j + i]);
    if (is_positive_definite9(A)) return;
    double W[81], Q[81];
    memcpy(W, A, sizeof W);
    jacobi_eigen(9, W, Q);
    for (int m = 0; m < 9; ++m) {
        const double lam = W[9 * m + m];
        if (!(lam < 0.0)) continue;
        for (int i = 0; i < 9; ++i) {
            const double li = lam * Q[9 * i + m];
            for (int j = i; j < 9; ++j) A[9 * i + j] -= li * Q[9 * j + m];
        }
    }
    for (int i = 0; i < 9; ++i)
        for (int j = i + 1; j < 9; ++j) A[9 * j + i] = A[9 * i + j];
}

/* ------------------------------------------------------------------------------------------ */
/* Material models                                                                            */
/* ------------------------------------------------------------------------------------------ */

/* psi, P (if want_P) and the tangent data of s->F. Returns 1 if the element is inverted for a
 * model that is undefined there (neo-Hookean with J <= 0), else 0. */
static inline int evaluate(int model, State *s, double mu, double lam, int want_P)
{
    const double *F = s->F;
    switch (model) {
    case PETSOFT_MODEL_LINEAR: {
        double eps[9];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                eps[3 * i + j] = 0.5 * (F[3 * i + j] + F[3 * j + i]) - (i == j ? 1.0 : 0.0);
        const double tr = eps[0] + eps[4] + eps[8];
        double ee = 0.0;
        for (int i = 0; i < 9; ++i) ee += eps[i] * eps[i];
        s->psi = mu * ee + 0.5 * lam * tr * tr;
        if (want_P)
            for (int i = 0; i < 9; ++i) s->P[i] = 2.0 * mu * eps[i] + (i % 4 == 0 ? lam * tr : 0.0);
        return 0;
    }
    case PETSOFT_MODEL_STVK: {
        double E[9];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                E[3 * i + j] = 0.5 * (F[i] * F[j] + F[3 + i] * F[3 + j] + F[6 + i] * F[6 + j] -
                                      (i == j ? 1.0 : 0.0));
        const double tr = E[0] + E[4] + E[8];
        double ee = 0.0;
        for (int i = 0; i < 9; ++i) ee += E[i] * E[i];
        s->psi = mu * ee + 0.5 * lam * tr * tr;
        if (want_P) {
            for (int i = 0; i < 9; ++i) s->S[i] = 2.0 * mu * E[i] + (i % 4 == 0 ? lam * tr : 0.0);
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) {
                    s->P[3 * i + j] = F[3 * i] * s->S[j] + F[3 * i + 1] * s->S[3 + j] +
                                      F[3 * i + 2] * s->S[6 + j];
                    s->B[3 * i + j] = F[3 * i] * F[3 * j] + F[3 * i + 1] * F[3 * j + 1] +
                                      F[3 * i + 2] * F[3 * j + 2];
                }
        }
        return 0;
    }
    case PETSOFT_MODEL_COROTATED: {
        signed_svd3(F, s->U, s->sig, s->V);
        const double *sg = s->sig;
        const double trS = sg[0] + sg[1] + sg[2];
        s->psi = mu * ((sg[0] - 1.0) * (sg[0] - 1.0) + (sg[1] - 1.0) * (sg[1] - 1.0) +
                       (sg[2] - 1.0) * (sg[2] - 1.0)) +
                 0.5 * lam * (trS - 3.0) * (trS - 3.0);
        if (want_P) {
            const double *U = s->U, *V = s->V;
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j)
                    s->R[3 * i + j] = U[3 * i] * V[3 * j] + U[3 * i + 1] * V[3 * j + 1] +
                                      U[3 * i + 2] * V[3 * j + 2];
            const double cr = lam * (trS - 3.0);
            for (int i = 0; i < 9; ++i) s->P[i] = 2.0 * mu * (F[i] - s->R[i]) + cr * s->R[i];
            for (int m = 0; m < 3; ++m) {
                const int p = PAIR_P[m], q = PAIR_Q[m];
                for (int i = 0; i < 3; ++i)
                    for (int j = 0; j < 3; ++j)
                        s->Q[m][3 * i + j] =
                            U[3 * i + p] * V[3 * j + q] - U[3 * i + q] * V[3 * j + p];
                s->T[m] = 1.0 / fmax(sg[p] + sg[q], SIGMA_SUM_MIN);
            }
            s->c1 = cr - 2.0 * mu;
        }
        return 0;
    }
    default: { /* PETSOFT_MODEL_NEOHOOKEAN */
        s->J = det3(F);
        if (s->J <= 0.0) return 1;
        s->logJ = log(s->J);
        double ff = 0.0;
        for (int i = 0; i < 9; ++i) ff += F[i] * F[i];
        s->psi = 0.5 * mu * (ff - 3.0) - mu * s->logJ + 0.5 * lam * s->logJ * s->logJ;
        if (want_P) {
            inverse_transpose3(F, s->J, s->FinvT);
            const double c = lam * s->logJ - mu;
            for (int i = 0; i < 9; ++i) s->P[i] = mu * F[i] + c * s->FinvT[i];
        }
        return 0;
    }
    }
}

/* dP/dF as a symmetric 9x9 matrix (upper triangle computed, then mirrored). */
static void tangent9(int model, const State *s, double mu, double lam, double *A)
{
    for (int r = 0; r < 9; ++r) {
        const int i = r / 3, j = r % 3;
        for (int c = r; c < 9; ++c) {
            const int k = c / 3, l = c % 3;
            const double d_ik = i == k, d_jl = j == l;
            double v;
            switch (model) {
            case PETSOFT_MODEL_LINEAR:
                v = mu * (d_ik * d_jl + (i == l) * (j == k)) + lam * (i == j) * (k == l);
                break;
            case PETSOFT_MODEL_STVK:
                v = d_ik * s->S[3 * l + j] +
                    mu * (s->F[3 * i + l] * s->F[3 * k + j] + s->B[3 * i + k] * d_jl) +
                    lam * s->F[3 * i + j] * s->F[3 * k + l];
                break;
            case PETSOFT_MODEL_COROTATED:
                v = 2.0 * mu * d_ik * d_jl + lam * s->R[r] * s->R[c] +
                    s->c1 * (s->T[0] * s->Q[0][r] * s->Q[0][c] + s->T[1] * s->Q[1][r] * s->Q[1][c] +
                             s->T[2] * s->Q[2][r] * s->Q[2][c]);
                break;
            default: /* neo-Hookean */
                v = mu * d_ik * d_jl +
                    (mu - lam * s->logJ) * s->FinvT[3 * i + l] * s->FinvT[3 * k + j] +
                    lam * s->FinvT[r] * s->FinvT[c];
                break;
            }
            A[9 * r + c] = A[9 * c + r] = v;
        }
    }
}

/* ------------------------------------------------------------------------------------------ */
/* Element terms                                                                              */
/* ------------------------------------------------------------------------------------------ */

/* g[3a+i] = V sum_j P_ij dN_a[j]. */
static inline void element_gradient(const State *s, const double *dN, double V, double *g)
{
    double y[4][3];
    apply_nodes(s->P, dN, y);
    for (int a = 0; a < 4; ++a)
        for (int i = 0; i < 3; ++i) g[3 * a + i] = V * y[a][i];
}

/* H[3a+i][3b+k] = V sum_jl dN_a[j] A[3i+j][3k+l] dN_b[l] from a (projected) 9x9 tangent. */
static void hessian_from_tangent(const double *A, const double *dN, double V,
                                 double *restrict H)
{
    double T[9][12]; /* T[3i+j][3b+k] = V sum_l A[3i+j][3k+l] dN_b[l] */
    for (int r = 0; r < 9; ++r)
        for (int b = 0; b < 4; ++b)
            for (int k = 0; k < 3; ++k)
                T[r][3 * b + k] = V * (A[9 * r + 3 * k] * dN[3 * b] +
                                       A[9 * r + 3 * k + 1] * dN[3 * b + 1] +
                                       A[9 * r + 3 * k + 2] * dN[3 * b + 2]);
    for (int a = 0; a < 4; ++a)
        for (int i = 0; i < 3; ++i) {
            const int row = 3 * a + i;
            for (int col = row; col < 12; ++col) {
                const double h = dN[3 * a] * T[3 * i][col] + dN[3 * a + 1] * T[3 * i + 1][col] +
                                 dN[3 * a + 2] * T[3 * i + 2][col];
                H[12 * row + col] = H[12 * col + row] = h;
            }
        }
}

/* Closed-form Hessians. Each writes block (a, b) for b >= a and its transpose as block (b, a);
 * within a diagonal block the formulas are symmetric in (i, k) term by term. The derivations
 * contract each model's dP/dF (see materials.py) with dN_a[j] dN_b[l]. */

/* linear: H_ab[i][k] = V (mu (dN_a.dN_b delta_ik + dN_a[k] dN_b[i]) + lam dN_a[i] dN_b[k]). */
static void hessian_linear(const double *dN, double V, double mu, double lam, double *restrict H)
{
    const double vm = V * mu, vl = V * lam;
    for (int a = 0; a < 4; ++a)
        for (int b = a; b < 4; ++b) {
            const double *x = dN + 3 * a, *y = dN + 3 * b;
            const double d = vm * dot3(x, y);
            for (int i = 0; i < 3; ++i)
                for (int k = 0; k < 3; ++k) {
                    const double h = vm * x[k] * y[i] + vl * x[i] * y[k] + (i == k ? d : 0.0);
                    H[12 * (3 * a + i) + 3 * b + k] = H[12 * (3 * b + k) + 3 * a + i] = h;
                }
        }
}

/* StVK, with f_a = F dN_a and B = F F^T:
 * H_ab[i][k] = V (dN_a.S dN_b delta_ik + mu (dN_a.dN_b B_ik + f_a[k] f_b[i]) + lam f_a[i] f_b[k]).
 */
static void hessian_stvk(const State *s, const double *dN, double V, double mu, double lam,
                         double *restrict H)
{
    double f[4][3], Sd[4][3];
    apply_nodes(s->F, dN, f);
    apply_nodes(s->S, dN, Sd);
    const double vm = V * mu, vl = V * lam;
    for (int a = 0; a < 4; ++a)
        for (int b = a; b < 4; ++b) {
            const double *x = dN + 3 * a, *y = dN + 3 * b;
            const double d = V * dot3(x, Sd[b]), e = vm * dot3(x, y);
            for (int i = 0; i < 3; ++i)
                for (int k = 0; k < 3; ++k) {
                    const double h = e * s->B[3 * i + k] + vm * f[a][k] * f[b][i] +
                                     vl * f[a][i] * f[b][k] + (i == k ? d : 0.0);
                    H[12 * (3 * a + i) + 3 * b + k] = H[12 * (3 * b + k) + 3 * a + i] = h;
                }
        }
}

/* corotated, with r_a = R dN_a and twist vectors w_ma = Q_m dN_a:
 * H_ab[i][k] = V (2 mu dN_a.dN_b delta_ik + lam r_a[i] r_b[k]
 *                 + c1 sum_m T_m w_ma[i] w_mb[k]). */
static void hessian_corotated(const State *s, const double *dN, double V, double mu, double lam,
                              double *restrict H)
{
    double r[4][3], w[3][4][3];
    apply_nodes(s->R, dN, r);
    for (int m = 0; m < 3; ++m) apply_nodes(s->Q[m], dN, w[m]);
    const double vm2 = 2.0 * V * mu, vl = V * lam;
    const double ct[3] = {V * s->c1 * s->T[0], V * s->c1 * s->T[1], V * s->c1 * s->T[2]};
    for (int a = 0; a < 4; ++a)
        for (int b = a; b < 4; ++b) {
            const double d = vm2 * dot3(dN + 3 * a, dN + 3 * b);
            for (int i = 0; i < 3; ++i)
                for (int k = 0; k < 3; ++k) {
                    const double h = vl * r[a][i] * r[b][k] + ct[0] * w[0][a][i] * w[0][b][k] +
                                     ct[1] * w[1][a][i] * w[1][b][k] +
                                     ct[2] * w[2][a][i] * w[2][b][k] + (i == k ? d : 0.0);
                    H[12 * (3 * a + i) + 3 * b + k] = H[12 * (3 * b + k) + 3 * a + i] = h;
                }
        }
}

/* neo-Hookean, with spatial gradients g_a = F^{-T} dN_a:
 * H_ab[i][k] = V (mu dN_a.dN_b delta_ik + (mu - lam ln J) g_a[k] g_b[i] + lam g_a[i] g_b[k]). */
static void hessian_neohookean(const State *s, const double *dN, double V, double mu,
                               double lam, double *restrict H)
{
    double g[4][3];
    apply_nodes(s->FinvT, dN, g);
    const double vm = V * mu, vx = V * (mu - lam * s->logJ), vl = V * lam;
    for (int a = 0; a < 4; ++a)
        for (int b = a; b < 4; ++b) {
            const double d = vm * dot3(dN + 3 * a, dN + 3 * b);
            for (int i = 0; i < 3; ++i)
                for (int k = 0; k < 3; ++k) {
                    const double h = vx * g[a][k] * g[b][i] + vl * g[a][i] * g[b][k] +
                                     (i == k ? d : 0.0);
                    H[12 * (3 * a + i) + 3 * b + k] = H[12 * (3 * b + k) + 3 * a + i] = h;
                }
        }
}

/* SPD projection for the isotropic models (StVK, corotated, neo-Hookean), analytically.
 *
 * In the frame of the signed SVD F = U diag(sigma) V^T, the tangent of an energy
 * psi(sigma_0, sigma_1, sigma_2) has the 9 eigenpairs (Smith, de Goes & Kim 2019):
 *   - 3 scaling modes U diag(w) V^T, with (lambda, w) the eigenpairs of d2psi/dsigma2 (3x3);
 *   - per pair p < q, a flip mode U (e_p e_q^T + e_q e_p^T) V^T / sqrt2 with eigenvalue
 *     (psi_p - psi_q) / (sigma_p - sigma_q), and a twist mode U (e_p e_q^T - e_q e_p^T) V^T / sqrt2
 *     with eigenvalue (psi_p + psi_q) / (sigma_p + sigma_q); both are written division-free
 *     (or with the same clamped 1/(sigma_p + sigma_q) as the exact tangent) for each model.
 * This is the eigen-decomposition that materials.project_spd computes numerically, at a fraction
 * of the cost of a 9x9 Jacobi. As there, only the negative part is removed: a mode E with
 * lambda < 0 contributes V lambda z z^T to H, z[3a+i] = (E dN_a)_i, which is subtracted from the
 * exact Hessian already in H (so a definite element keeps its exact Hessian bit for bit). */
static void remove_negative_modes(int model, State *s, const double *dN, double V, double mu,
                                  double lam, double *restrict H)
{
    if (model != PETSOFT_MODEL_COROTATED) signed_svd3(s->F, s->U, s->sig, s->V);
    const double *sg = s->sig, *U = s->U, *Vm = s->V;
    double Hs[9], flip[3], twist[3];
    switch (model) {
    case PETSOFT_MODEL_STVK: {
        /* psi = mu sum E_i^2 + lam/2 (sum E_i)^2 with E_i = (sigma_i^2 - 1)/2. */
        const double trE = 0.5 * (sg[0] * sg[0] + sg[1] * sg[1] + sg[2] * sg[2] - 3.0);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                Hs[3 * i + j] = lam * sg[i] * sg[j] +
                                (i == j ? mu * (sg[i] * sg[i] - 1.0) + lam * trE +
                                              2.0 * mu * sg[i] * sg[i]
                                        : 0.0);
        for (int m = 0; m < 3; ++m) {
            const double sp = sg[PAIR_P[m]], sq = sg[PAIR_Q[m]];
            flip[m] = mu * (sp * sp + sp * sq + sq * sq - 1.0) + lam * trE;
            twist[m] = mu * (sp * sp - sp * sq + sq * sq - 1.0) + lam * trE;
        }
        break;
    }
    case PETSOFT_MODEL_COROTATED:
        /* psi = mu sum (sigma_i - 1)^2 + lam/2 (sum sigma_i - 3)^2. */
        for (int i = 0; i < 9; ++i) Hs[i] = lam + (i % 4 == 0 ? 2.0 * mu : 0.0);
        for (int m = 0; m < 3; ++m) {
            flip[m] = 2.0 * mu;
            twist[m] = 2.0 * mu + 2.0 * s->c1 * s->T[m];
        }
        break;
    default: { /* neo-Hookean: psi = mu/2 sum sigma_i^2 - mu ln J + lam/2 ln^2 J */
        const double c = mu - lam * s->logJ;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                Hs[3 * i + j] = lam / (sg[i] * sg[j]) + (i == j ? mu + c / (sg[i] * sg[i]) : 0.0);
        for (int m = 0; m < 3; ++m) {
            const double r = c / (sg[PAIR_P[m]] * sg[PAIR_Q[m]]);
            flip[m] = mu + r;
            twist[m] = mu - r;
        }
        break;
    }
    }

    double W[9], Q[9];
    memcpy(W, Hs, sizeof W);
    jacobi_eigen(3, W, Q);

    double n[4][3]; /* n_a = V^T dN_a: shape gradients in the right singular frame */
    for (int a = 0; a < 4; ++a)
        for (int i = 0; i < 3; ++i)
            n[a][i] = Vm[i] * dN[3 * a] + Vm[3 + i] * dN[3 * a + 1] + Vm[6 + i] * dN[3 * a + 2];

    const double r2 = sqrt(0.5);
    for (int mode = 0; mode < 9; ++mode) {
        double lambda, z[12];
        if (mode < 3) { /* scaling: E = U diag(w) V^T */
            lambda = W[4 * mode];
            if (!(lambda < 0.0)) continue;
            const double w[3] = {Q[mode], Q[3 + mode], Q[6 + mode]};
            for (int a = 0; a < 4; ++a)
                for (int i = 0; i < 3; ++i)
                    z[3 * a + i] = U[3 * i] * w[0] * n[a][0] + U[3 * i + 1] * w[1] * n[a][1] +
                                   U[3 * i + 2] * w[2] * n[a][2];
        } else { /* flip (sign +1) or twist (sign -1) of pair m */
            const int m = (mode - 3) / 2, is_twist = (mode - 3) % 2;
            lambda = is_twist ? twist[m] : flip[m];
            if (!(lambda < 0.0)) continue;
            const int p = PAIR_P[m], q = PAIR_Q[m];
            const double sgn = is_twist ? -1.0 : 1.0;
            for (int a = 0; a < 4; ++a)
                for (int i = 0; i < 3; ++i)
                    z[3 * a + i] = r2 * (U[3 * i + p] * n[a][q] + sgn * U[3 * i + q] * n[a][p]);
        }
        const double c = V * lambda;
        for (int r = 0; r < 12; ++r) {
            const double cr = c * z[r];
            for (int col = r; col < 12; ++col) {
                const double h = H[12 * r + col] - cr * z[col];
                H[12 * r + col] = H[12 * col + r] = h;
            }
        }
    }
}

/* The element loop. The per-element switches on `model` are perfectly predictable branches
 * (measured: a few instructions per element), so the loop is not specialised per model. */
static int64_t gradient_hessian_loop(int model, int64_t n, const double *dN,
                                            const double *volume, const double *u,
                                            const double *mu, const double *lam, int project,
                                            double *gradient, double *hessian,
                                            double *bad_jacobian)
{
    const int want_P = gradient != NULL || hessian != NULL;
    for (int64_t e = 0; e < n; ++e) {
        const double *dNe = dN + 12 * e;
        const double V = volume[e], m = mu[e], l = lam[e];
        State s;
        deformation_gradient(dNe, u + 12 * e, s.F);
        if (evaluate(model, &s, m, l, want_P)) {
            if (bad_jacobian) *bad_jacobian = s.J;
            return e;
        }
        if (gradient) element_gradient(&s, dNe, V, gradient + 12 * e);
        if (!hessian) continue;
        double *He = hessian + 144 * e;
        if (project && model == PETSOFT_MODEL_LINEAR && !(m >= 0.0 && 3.0 * l + 2.0 * m >= 0.0)) {
            /* The linear tangent (eigenvalues 2 mu, 0, 3 lam + 2 mu) is indefinite only for
             * non-physical parameters: project it numerically. */
            double A[81];
            tangent9(model, &s, m, l, A);
            project_psd9(A);
            hessian_from_tangent(A, dNe, V, He);
            continue;
        }
        switch (model) {
        case PETSOFT_MODEL_LINEAR: hessian_linear(dNe, V, m, l, He); break;
        case PETSOFT_MODEL_STVK: hessian_stvk(&s, dNe, V, m, l, He); break;
        case PETSOFT_MODEL_COROTATED: hessian_corotated(&s, dNe, V, m, l, He); break;
        default: hessian_neohookean(&s, dNe, V, m, l, He); break;
        }
        if (project && model != PETSOFT_MODEL_LINEAR)
            remove_negative_modes(model, &s, dNe, V, m, l, He);
    }
    return -1;
}

int64_t petsoft_elastic_gradient_hessian(int32_t model, int64_t n, const double *dN,
                                         const double *volume, const double *u,
                                         const double *mu, const double *lam,
                                         int32_t project_spd, double *gradient, double *hessian,
                                         double *bad_jacobian)
{
    if (model < PETSOFT_MODEL_LINEAR || model > PETSOFT_MODEL_NEOHOOKEAN) return PETSOFT_BAD_MODEL;
    return gradient_hessian_loop(model, n, dN, volume, u, mu, lam, project_spd != 0, gradient,
                                 hessian, bad_jacobian);
}

/* The residual's path: one call gathers each element's displacements from the nodal array,
 * evaluates P and adds V P dN_a into the nodal output. A Newton iteration of a small model
 * spends more in Python around the element loop (gather, checks, scatter) than in it. */
int64_t petsoft_elastic_gradient_indexed(int32_t model, int64_t n, const int64_t *conn,
                                         const double *dN, const double *volume,
                                         const double *u_nodes, const double *mu,
                                         const double *lam, double *out_nodes,
                                         double *bad_jacobian)
{
    if (model < PETSOFT_MODEL_LINEAR || model > PETSOFT_MODEL_NEOHOOKEAN) return PETSOFT_BAD_MODEL;
    for (int64_t e = 0; e < n; ++e) {
        const int64_t *ce = conn + 4 * e;
        const double *dNe = dN + 12 * e;
        double ue[12], g[12];
        for (int a = 0; a < 4; ++a)
            for (int i = 0; i < 3; ++i) ue[3 * a + i] = u_nodes[3 * ce[a] + i];
        State s;
        deformation_gradient(dNe, ue, s.F);
        if (evaluate(model, &s, mu[e], lam[e], 1)) {
            if (bad_jacobian) *bad_jacobian = s.J;
            return e;
        }
        element_gradient(&s, dNe, volume[e], g);
        for (int a = 0; a < 4; ++a)
            for (int i = 0; i < 3; ++i) out_nodes[3 * ce[a] + i] += g[3 * a + i];
    }
    return -1;
}

/* The summed energy of n elements whose displacements are gathered through conn. */
int64_t petsoft_elastic_energy_indexed(int32_t model, int64_t n, const int64_t *conn,
                                       const double *dN, const double *volume,
                                       const double *u_nodes, const double *mu,
                                       const double *lam, double *total, double *bad_jacobian)
{
    if (model < PETSOFT_MODEL_LINEAR || model > PETSOFT_MODEL_NEOHOOKEAN) return PETSOFT_BAD_MODEL;
    double sum = 0.0;
    for (int64_t e = 0; e < n; ++e) {
        const int64_t *ce = conn + 4 * e;
        double ue[12];
        for (int a = 0; a < 4; ++a)
            for (int i = 0; i < 3; ++i) ue[3 * a + i] = u_nodes[3 * ce[a] + i];
        State s;
        deformation_gradient(dN + 12 * e, ue, s.F);
        if (evaluate(model, &s, mu[e], lam[e], 0)) {
            if (bad_jacobian) *bad_jacobian = s.J;
            return e;
        }
        sum += volume[e] * s.psi;
    }
    *total = sum;
    return -1;
}

int64_t petsoft_elastic_energy(int32_t model, int64_t n, const double *dN, const double *volume,
                               const double *u, const double *mu, const double *lam,
                               double *energy, double *bad_jacobian)
{
    if (model < PETSOFT_MODEL_LINEAR || model > PETSOFT_MODEL_NEOHOOKEAN) return PETSOFT_BAD_MODEL;
    for (int64_t e = 0; e < n; ++e) {
        State s;
        deformation_gradient(dN + 12 * e, u + 12 * e, s.F);
        if (evaluate(model, &s, mu[e], lam[e], 0)) {
            if (bad_jacobian) *bad_jacobian = s.J;
            return e;
        }
        energy[e] = volume[e] * s.psi;
    }
    return -1;
}

int64_t petsoft_material_response(int32_t model, int64_t n, const double *F, const double *mu,
                                  const double *lam, double *psi, double *P, double *dPdF,
                                  double *bad_jacobian)
{
    if (model < PETSOFT_MODEL_LINEAR || model > PETSOFT_MODEL_NEOHOOKEAN) return PETSOFT_BAD_MODEL;
    for (int64_t e = 0; e < n; ++e) {
        State s;
        memcpy(s.F, F + 9 * e, sizeof s.F);
        if (evaluate(model, &s, mu[e], lam[e], 1)) {
            if (bad_jacobian) *bad_jacobian = s.J;
            return e;
        }
        psi[e] = s.psi;
        if (P) memcpy(P + 9 * e, s.P, sizeof s.P);
        if (dPdF) tangent9(model, &s, mu[e], lam[e], dPdF + 81 * e);
    }
    return -1;
}

void petsoft_project_spd9(int64_t n, double *A)
{
    for (int64_t e = 0; e < n; ++e) project_psd9(A + 81 * e);
}

/* ------------------------------------------------------------------------------------------ */
/* Elements integrated by quadrature (10-node tetrahedra)                                     */
/* ------------------------------------------------------------------------------------------ */

/* Per element e and quadrature point q the deformation gradient is F = I + sum_a u_a (x) dN_qa,
 * and the energy, gradient and Hessian are the weighted sums over q of the pointwise
 * W psi(F), W P dN_a and W dN_a . dP/dF . dN_b. The Hessian uses the generic 9x9 tangent (the
 * closed forms of the P1 loop pay off only for 4 nodes); with project_spd the tangent is
 * projected at every point, which keeps each point's contribution, hence H, PSD. */
int64_t petsoft_elastic_quadrature(int32_t model, int64_t n, int32_t nnodes, int32_t nq,
                                   const double *dN, const double *weight, const double *u,
                                   const double *mu, const double *lam, int32_t project_spd,
                                   double *energy, double *gradient, double *hessian,
                                   double *bad_jacobian)
{
    if (model < PETSOFT_MODEL_LINEAR || model > PETSOFT_MODEL_NEOHOOKEAN) return PETSOFT_BAD_MODEL;
    if (nnodes < 1 || nnodes > PETSOFT_MAX_NODES) return PETSOFT_BAD_SHAPE;
    const int nd = 3 * nnodes;
    const int want_P = gradient != NULL || hessian != NULL;
    double T[9][3 * PETSOFT_MAX_NODES];
    for (int64_t e = 0; e < n; ++e) {
        const double *ue = u + (int64_t)nd * e;
        double *ge = gradient ? gradient + (int64_t)nd * e : NULL;
        double *He = hessian ? hessian + (int64_t)nd * nd * e : NULL;
        if (energy) energy[e] = 0.0;
        if (ge) memset(ge, 0, sizeof(double) * nd);
        if (He) memset(He, 0, sizeof(double) * nd * nd);
        for (int q = 0; q < nq; ++q) {
            const double *d = dN + ((int64_t)e * nq + q) * nd;
            const double W = weight[(int64_t)e * nq + q];
            State s;
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) {
                    double f = (i == j) ? 1.0 : 0.0;
                    for (int a = 0; a < nnodes; ++a) f += ue[3 * a + i] * d[3 * a + j];
                    s.F[3 * i + j] = f;
                }
            if (evaluate(model, &s, mu[e], lam[e], want_P)) {
                if (bad_jacobian) *bad_jacobian = s.J;
                return e;
            }
            if (energy) energy[e] += W * s.psi;
            if (ge)
                for (int a = 0; a < nnodes; ++a)
                    for (int i = 0; i < 3; ++i)
                        ge[3 * a + i] += W * (s.P[3 * i] * d[3 * a] + s.P[3 * i + 1] * d[3 * a + 1] +
                                              s.P[3 * i + 2] * d[3 * a + 2]);
            if (!He) continue;
            double A[81];
            tangent9(model, &s, mu[e], lam[e], A);
            if (project_spd) project_psd9(A);
            for (int r = 0; r < 9; ++r)
                for (int b = 0; b < nnodes; ++b)
                    for (int k = 0; k < 3; ++k)
                        T[r][3 * b + k] = W * (A[9 * r + 3 * k] * d[3 * b] +
                                               A[9 * r + 3 * k + 1] * d[3 * b + 1] +
                                               A[9 * r + 3 * k + 2] * d[3 * b + 2]);
            for (int a = 0; a < nnodes; ++a)
                for (int i = 0; i < 3; ++i) {
                    const int row = 3 * a + i;
                    double *Hrow = He + (int64_t)nd * row;
                    for (int col = row; col < nd; ++col)
                        Hrow[col] += d[3 * a] * T[3 * i][col] + d[3 * a + 1] * T[3 * i + 1][col] +
                                     d[3 * a + 2] * T[3 * i + 2][col];
                }
        }
        if (He)
            for (int row = 0; row < nd; ++row)
                for (int col = row + 1; col < nd; ++col) He[nd * col + row] = He[nd * row + col];
    }
    return -1;
}
