/* Compiled hyperelastic element kernels for linear (P1) tetrahedra, and for any element
 * integrated by quadrature (10-node tetrahedra).
 *
 * The formulas are those of petsoft/kernels/materials.py and reference.py (the numpy
 * specification, which the tests compare against). Every function loops over all n elements
 * itself; arrays are C-contiguous float64, element-major:
 *   dN     (n, 4, 3)  shape-function gradients          u    (n, 4, 3) displacements
 *   volume (n,)       reference volumes (> 0)           mu, lam (n,) Lame parameters
 *   energy (n,)       volume * psi(F)
 *   gradient (n, 12)  dW/du, dof 3a+i                   hessian (n, 12, 12) d2W/du2
 * with F = I + sum_a u_a (x) dN_a.
 *
 * Models: 0 linear, 1 stvk, 2 corotated, 3 neohookean (the order of materials.MODELS).
 *
 * Return status (all functions): -1 success; e >= 0 the first element whose det F <= 0 for the
 * neo-Hookean model (its det F is stored in *bad_jacobian if that is not NULL; elements after
 * it are not computed); PETSOFT_BAD_MODEL for an unknown model code.
 */
#ifndef PETSOFT_ELASTIC_H
#define PETSOFT_ELASTIC_H

#include <stdint.h>

#define PETSOFT_MODEL_LINEAR 0
#define PETSOFT_MODEL_STVK 1
#define PETSOFT_MODEL_COROTATED 2
#define PETSOFT_MODEL_NEOHOOKEAN 3
#define PETSOFT_BAD_MODEL (-2)
#define PETSOFT_BAD_SHAPE (-3)
#define PETSOFT_MAX_NODES 10

/* Element energies. */
int64_t petsoft_elastic_energy(int32_t model, int64_t n, const double *dN, const double *volume,
                               const double *u, const double *mu, const double *lam,
                               double *energy, double *bad_jacobian);

/* Element gradients and Hessians. Either output may be NULL to skip it. With project_spd != 0
 * the Hessian is built from the positive semi-definite projection of dP/dF (viewed as a
 * symmetric 9x9 matrix, negative eigenvalues clamped to zero). */
int64_t petsoft_elastic_gradient_hessian(int32_t model, int64_t n, const double *dN,
                                         const double *volume, const double *u,
                                         const double *mu, const double *lam,
                                         int32_t project_spd, double *gradient, double *hessian,
                                         double *bad_jacobian);

/* Gradients of n elements whose displacements are gathered from u_nodes (nv, 3) through
 * conn (n, 4) (local node indices), added into out_nodes (nv, 3): the assembled dW/du. Elements
 * before a failing one have been added. */
int64_t petsoft_elastic_gradient_indexed(int32_t model, int64_t n, const int64_t *conn,
                                         const double *dN, const double *volume,
                                         const double *u_nodes, const double *mu,
                                         const double *lam, double *out_nodes,
                                         double *bad_jacobian);

/* The summed energy sum_e V_e psi(F_e) of the same elements, into *total. */
int64_t petsoft_elastic_energy_indexed(int32_t model, int64_t n, const int64_t *conn,
                                       const double *dN, const double *volume,
                                       const double *u_nodes, const double *mu,
                                       const double *lam, double *total, double *bad_jacobian);

/* Pointwise constitutive law: psi (n,), P (n, 3, 3), dPdF (n, 3, 3, 3, 3) from F (n, 3, 3).
 * P and dPdF may be NULL. */
int64_t petsoft_material_response(int32_t model, int64_t n, const double *F, const double *mu,
                                  const double *lam, double *psi, double *P, double *dPdF,
                                  double *bad_jacobian);

/* Elements of nnodes nodes integrated by nq quadrature points: dN (n, nq, nnodes, 3) shape
 * gradients at the points, weight (n, nq) their weights times |det J|, u (n, nnodes, 3).
 * Outputs (any may be NULL): energy (n,), gradient (n, 3 nnodes), hessian (n, 3 nnodes, 3 nnodes).
 * Returns -1, the first element with a point where neo-Hookean J <= 0, PETSOFT_BAD_MODEL, or
 * PETSOFT_BAD_SHAPE (nnodes outside 1..PETSOFT_MAX_NODES). */
int64_t petsoft_elastic_quadrature(int32_t model, int64_t n, int32_t nnodes, int32_t nq,
                                   const double *dN, const double *weight, const double *u,
                                   const double *mu, const double *lam, int32_t project_spd,
                                   double *energy, double *gradient, double *hessian,
                                   double *bad_jacobian);

/* In-place positive semi-definite projection of n symmetric 9x9 matrices (n, 81). */
void petsoft_project_spd9(int64_t n, double *A);

#endif
