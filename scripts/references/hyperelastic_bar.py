"""Independent large-deformation reference solutions for petsoft's StVK and neo-Hookean laws,
made by DOLFINx 0.5 (UFL), P1 and P2 (issue 36, item 1).

Run with the system python (DOLFINx is a Debian package there, not petsoft's)::

    OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \\
        nice /usr/bin/python3 scripts/references/hyperelastic_bar.py [--dry]

(serial, well under a minute plus FFCx's one-time JIT compilation). It writes
``tests/data/hyperelastic_bar.npz`` (``--dry``: prints only). Nothing here imports petsoft.

The problem: a bar [0, L] x [0, B] x [0, B] (L = 1, B = 0.2 m, DOLFINx ``create_box``, 6 x 2 x 2
hexahedra split into 6 tetrahedra each, P1 geometry), E = 1e6 Pa, nu = 0.3 (mu, lam from the
usual formulas), no body force. The face x = 0 is clamped; every node of the face x = L is moved
to

    x = c + R_x(THETA) (X - c) + (STRETCH L, 0, 0),   c = (L, B/2, B/2),

a rigid twist by THETA = 60 degrees about the bar's axis plus an axial stretch of 20 % (the
shear strain at the corners is ~0.15 and the axial ~0.2: finite strain, not a small strain
rotated). The other faces are free. The laws, written here from their textbook definitions:

* StVK: E = (F^T F - I)/2, psi = mu E:E + lam/2 tr(E)^2;
* compressible neo-Hookean: psi = mu/2 (tr(F^T F) - 3) - mu ln J + lam/2 (ln J)^2;

with P = d psi / d F by UFL (``ufl.diff``), the residual int P : grad v dX, Newton
(``dolfinx.nls.petsc.NewtonSolver``, MUMPS LU, residual atol 1e-8 N, rtol 1e-12) on the boundary
twist and stretch ramped in 8 equal increments of angle and stretch (the last solve is at the full
load; intermediate states differ from petsoft's linear ramp of the end displacement, but the
final equilibrium is the one reached by both: checked in the tests by the agreement).

Quadrature (``ufl.dx(metadata={"quadrature_degree": q})``):

* P1: q = 1 (the integrand is constant on an affine P1 tet: every rule is exact);
* P2: q = 2, basix's 4-point rule, the same points and weights as petsoft's default P2 rule
  (Keast's 4 points; checked here), and q = 6 (basix's degree-6 rule), which integrates StVK's
  degree-4 integrand exactly and the neo-Hookean one far better than the degree-2 rule. The
  difference between the two P2 solutions is the quadrature error of petsoft's default rule on
  this problem (printed; both solutions are stored).

Arrays of the file (float64 unless said):

* ``points`` (N, 3), ``tets`` (E, 4) int64: the mesh (tets reoriented to positive volume where
  DOLFINx's were negative; ``reoriented`` counts them);
* ``E``, ``nu``, ``L``, ``B``, ``theta``, ``stretch``;
* for ``law`` in (stvk, neohookean): ``{law}_p1_x`` (N1, 3) the P1 dof coordinates and
  ``{law}_p1_u`` (N1, 3) the displacement there; ``{law}_p2_x`` (N2, 3) the P2 node coordinates,
  ``{law}_p2_q2_u`` and ``{law}_p2_q6_u`` (N2, 3) the displacements at quadrature degree 2 and
  6; ``{law}_p1_energy``, ``{law}_p2_q2_energy``, ``{law}_p2_q6_energy`` the stored energy
  int psi dX at the solution (same rule as the solve).

The node order is DOLFINx's; match by coordinate.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

L, B = 1.0, 0.2
CELLS = (6, 2, 2)
E_MOD, NU = 1.0e6, 0.3
THETA = np.pi / 3.0
STRETCH = 0.2
INCREMENTS = 8
OUT = Path(__file__).resolve().parents[2] / "tests" / "data" / "hyperelastic_bar.npz"


def lame():
    mu = E_MOD / (2.0 * (1.0 + NU))
    lam = E_MOD * NU / ((1.0 + NU) * (1.0 - 2.0 * NU))
    return mu, lam


def end_displacement(x: np.ndarray, fraction: float) -> np.ndarray:
    """Displacement (3, m) of the end-face points x (3, m) at a fraction of the load."""
    th, s = fraction * THETA, fraction * STRETCH
    y, z = x[1] - B / 2, x[2] - B / 2
    out = np.zeros_like(x)
    out[0] = s * L
    out[1] = np.cos(th) * y - np.sin(th) * z - y
    out[2] = np.sin(th) * y + np.cos(th) * z - z
    return out


def psi_of(law: str, F, mu, lam):
    import ufl
    Id = ufl.Identity(3)
    if law == "stvk":
        Eg = 0.5 * (F.T * F - Id)
        return mu * ufl.inner(Eg, Eg) + 0.5 * lam * ufl.tr(Eg) ** 2
    J = ufl.det(F)
    return 0.5 * mu * (ufl.tr(F.T * F) - 3.0) - mu * ufl.ln(J) + 0.5 * lam * ufl.ln(J) ** 2


def mesh_arrays(msh):
    x = np.array(msh.geometry.x[:, :3], dtype=np.float64)
    tets = np.array(msh.geometry.dofmap.array, dtype=np.int64).reshape(-1, 4)
    vol = np.linalg.det(np.stack([x[tets[:, k]] - x[tets[:, 0]] for k in (1, 2, 3)], axis=1))
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return x, tets, int(flip.sum())


def solve(law: str, order: int, degree: int):
    import dolfinx.fem.petsc  # noqa: F401  (registers fem.petsc)
    import dolfinx.nls.petsc  # noqa: F401
    import ufl
    from dolfinx import fem, nls
    from dolfinx import mesh as dmesh
    from mpi4py import MPI
    from petsc4py import PETSc

    msh = dmesh.create_box(MPI.COMM_SELF, [np.zeros(3), np.array([L, B, B])], list(CELLS),
                           dmesh.CellType.tetrahedron)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", order))
    u, v = fem.Function(V), ufl.TestFunction(V)
    mu, lam = lame()
    F = ufl.variable(ufl.Identity(3) + ufl.grad(u))
    psi = psi_of(law, F, mu, lam)
    dx = ufl.dx(metadata={"quadrature_degree": degree})
    residual = ufl.inner(ufl.diff(psi, F), ufl.grad(v)) * dx

    clamp = fem.locate_dofs_geometrical(V, lambda x: np.isclose(x[0], 0.0))
    end = fem.locate_dofs_geometrical(V, lambda x: np.isclose(x[0], L))
    zero, moved = fem.Function(V), fem.Function(V)
    bcs = [fem.dirichletbc(zero, clamp), fem.dirichletbc(moved, end)]
    problem = fem.petsc.NonlinearProblem(residual, u, bcs)
    solver = nls.petsc.NewtonSolver(MPI.COMM_SELF, problem)
    solver.atol, solver.rtol, solver.max_it = 1e-8, 1e-12, 50
    solver.convergence_criterion = "residual"
    ksp = solver.krylov_solver
    opts = PETSc.Options()
    pre = ksp.getOptionsPrefix()
    opts[f"{pre}ksp_type"] = "preonly"
    opts[f"{pre}pc_type"] = "lu"
    opts[f"{pre}pc_factor_mat_solver_type"] = "mumps"
    ksp.setFromOptions()
    its = []
    for k in range(1, INCREMENTS + 1):
        moved.interpolate(lambda x, f=k / INCREMENTS: end_displacement(x, f))
        n, converged = solver.solve(u)
        assert converged, (law, order, degree, k)
        its.append(int(n))
    energy = fem.assemble_scalar(fem.form(psi * dx))
    X = V.tabulate_dof_coordinates()
    U = u.x.array.reshape(-1, 3).copy()
    # the residual at the free dofs, recomputed: the solution is an equilibrium
    b = fem.petsc.assemble_vector(fem.form(residual))
    r = b.array.reshape(-1, 3)
    free = np.ones(len(X), bool)
    free[clamp] = False
    free[end] = False
    res = float(np.abs(r[free]).max())
    return msh, np.array(X, dtype=np.float64), U, float(energy), its, res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dry", action="store_true", help="print, write nothing")
    args = ap.parse_args()
    import basix
    pts, w = basix.make_quadrature(basix.CellType.tetrahedron, 2)
    a, b = (5.0 + 3.0 * np.sqrt(5.0)) / 20.0, (5.0 - np.sqrt(5.0)) / 20.0
    keast = {tuple(np.round(p, 12)) for p in ([a, b, b], [b, a, b], [b, b, a], [b, b, b])}
    assert {tuple(np.round(p, 12)) for p in pts} == keast and np.allclose(w, 1 / 24), \
        "basix's degree-2 rule is not Keast's 4 points"
    print("basix degree-2 tet rule == Keast's 4-point rule (petsoft's default P2 rule)")

    data: dict[str, np.ndarray] = {}
    for law in ("stvk", "neohookean"):
        msh, X1, U1, W1, its, res = solve(law, 1, 1)
        print(f"{law} P1 q1: {len(X1)} nodes, max |u| {np.abs(U1).max():.6f}, energy {W1:.9e}, "
              f"Newton {its}, max free residual {res:.1e}")
        data[f"{law}_p1_x"], data[f"{law}_p1_u"] = X1, U1
        data[f"{law}_p1_energy"] = np.float64(W1)
        sols = {}
        for q in (2, 6):
            _, X2, U2, W2, its, res = solve(law, 2, q)
            sols[q] = U2
            print(f"{law} P2 q{q}: {len(X2)} nodes, max |u| {np.abs(U2).max():.6f}, energy "
                  f"{W2:.9e}, Newton {its}, max free residual {res:.1e}")
            data[f"{law}_p2_q{q}_u"] = U2
            data[f"{law}_p2_q{q}_energy"] = np.float64(W2)
            data[f"{law}_p2_x"] = X2
        qerr = np.abs(sols[2] - sols[6]).max() / np.abs(sols[6]).max()
        print(f"{law}: P2 quadrature error of the degree-2 rule, max |u_q2 - u_q6| / max |u| = "
              f"{qerr:.2e}")
    points, tets, flipped = mesh_arrays(msh)
    data.update(points=points, tets=tets, reoriented=np.int64(flipped), E=np.float64(E_MOD),
                nu=np.float64(NU), L=np.float64(L), B=np.float64(B), theta=np.float64(THETA),
                stretch=np.float64(STRETCH))
    print(f"mesh: {len(points)} vertices, {len(tets)} tets ({flipped} reoriented)")
    if not args.dry:
        OUT.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(OUT, **data)
        print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
