"""Helpers of the static verification tests (tests/test_verification_static.py).

Everything here is collective-safe: functions taking a model work on the rank's local cells and
reduce over the model's communicator, so the returned numbers are the same on every rank.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.experiment import experiment_from_dict
from petsoft.mesh.serial import box_mesh
from petsoft.solvers.static import StaticSolver

BOUNDARY_OF_UNIT_CUBE = " or ".join(
    f"{c} < 1e-9 or {c} > 1 - 1e-9" for c in ("x", "y", "z"))


# ------------------------------------------------------------------------------------------------
# Experiments, meshes, solves


def experiment(material: str = "linear", *, box=((1.0, 1.0, 1.0), (2, 2, 2)), E: float = 1e6,
               nu: float = 0.3, density: float = 1000.0, gravity=(0.0, 0.0, 0.0),
               boundary=(), out: str = "/tmp/petsoft-verification"):
    """A validated experiment on a box mesh with one material."""
    size, cells = box
    return experiment_from_dict({
        "mesh": {"box": {"size": list(size), "cells": list(cells)}},
        "material": {"model": material, "youngs_modulus": E, "poisson_ratio": nu,
                     "density": density},
        "gravity": {"acceleration": list(gravity)},
        "boundary": [dict(b) for b in boundary],
        "output": {"directory": out},
    })


def jittered_unit_cube(n: int, amplitude: float, seed: int = 1):
    """Box mesh of the unit cube (n^3 hexahedra, 6 tets each) with its interior vertices moved
    by uniform random offsets in [-amplitude/n, amplitude/n]^3 (boundary vertices stay)."""
    mesh = box_mesh([1.0, 1.0, 1.0], [n, n, n])
    p = mesh.points.copy()
    interior = np.all((p > 1e-9) & (p < 1 - 1e-9), axis=1)
    rng = np.random.default_rng(seed)
    p[interior] += rng.uniform(-amplitude / n, amplitude / n, (interior.sum(), 3))
    return dataclasses.replace(mesh, points=p, source=f"jittered box {n}^3"), interior


def linear_expressions(G: np.ndarray) -> list[str]:
    """The three components of u = G X as expressions of x, y, z."""
    return [" + ".join(f"({G[i, j]!r})*{c}" for j, c in enumerate("xyz")) for i in range(3)]


def set_options(options: dict[str, str]) -> list[str]:
    opts = PETSc.Options()
    for k, v in options.items():
        opts.setValue(k, v)
    return list(options)


def bcast_gathered(model, vec: PETSc.Vec) -> np.ndarray:
    """(N, 3) field of a global vector in file numbering, on every rank."""
    dm = model.dmesh
    return dm.comm.tompi4py().bcast(dm.gather_global(vec), root=0)


def solve(model, method: str = "snes", load_steps: int = 1, x0=None, options=None):
    """Solve the model (PETSc options set around the solver's construction and solve).

    Returns (u (N, 3) in file numbering on every rank, StaticResult).
    """
    keys = set_options(options or {})
    solver = None
    try:
        solver = StaticSolver(model, method=method, load_steps=load_steps)
        result = solver.solve(x0)
        u = bcast_gathered(model, result.displacement)
    finally:
        from petsoft.solvers.options import clear_options
        clear_options(keys)
        if solver is not None:
            solver.destroy()
    return u, result


# ------------------------------------------------------------------------------------------------
# Quadrature on tetrahedra


def tet_quadrature(n: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Conical-product (collapsed Gauss-Legendre) rule on the reference tetrahedron
    {a, b, c >= 0, a + b + c <= 1}: (n^3, 3) points and weights summing to 1/6; exact for
    polynomials of degree 2n - 3 and above-average accurate for smooth integrands."""
    g, w = np.polynomial.legendre.leggauss(n)
    g, w = 0.5 * (g + 1.0), 0.5 * w
    s, t, r = np.meshgrid(g, g, g, indexing="ij")
    ws, wt, wr = np.meshgrid(w, w, w, indexing="ij")
    a = s
    b = (1.0 - s) * t
    c = (1.0 - s) * (1.0 - t) * r
    weight = ws * wt * wr * (1.0 - s) ** 2 * (1.0 - t)
    return np.stack([a.ravel(), b.ravel(), c.ravel()], axis=1), weight.ravel()


def _cell_quadrature(X: np.ndarray, n: int):
    """Physical points (ne, nq, 3), weights (ne, nq) and shape values (nq, 4) on cells X."""
    ref, w = tet_quadrature(n)
    N = np.column_stack([1.0 - ref.sum(axis=1), ref])                  # (nq, 4)
    D = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=2)
    detJ = np.abs(np.linalg.det(D))                                    # 6 V
    pts = np.einsum("qa,eai->eqi", N, X)
    return pts, detJ[:, None] * w[None, :], N


def add_body_force(model, f, n: int = 3) -> None:
    """Add the consistent nodal loads int f N_a dV of a body force f(points (m, 3)) -> (m, 3)
    over this rank's cells into ``model.external``."""
    dm = model.dmesh
    X = dm.points[dm.cells]
    pts, wq, N = _cell_quadrature(X, n)
    fq = f(pts.reshape(-1, 3)).reshape(pts.shape)                      # (ne, nq, 3)
    fe = np.einsum("eq,qa,eqi->eai", wq, N, fq)                        # (ne, 4, 3)
    local = np.zeros((dm.nvertices, 3))
    np.add.at(local, dm.cells.ravel(), fe.reshape(-1, 3))
    dm.add_to_global(local, model.external)


def l2_error(model, u_file: np.ndarray, exact, n: int = 3) -> tuple[float, float]:
    """(||u_h - u||_L2, ||u||_L2) over the whole mesh for a P1 field u_h given at the vertices
    (file numbering) and an exact field exact(points (m, 3)) -> (m, 3); same on every rank."""
    dm = model.dmesh
    X = dm.points[dm.cells]
    pts, wq, N = _cell_quadrature(X, n)
    uh = np.einsum("qa,eai->eqi", N, np.asarray(u_file)[dm.vertex_ids][dm.cells])
    ue = exact(pts.reshape(-1, 3)).reshape(pts.shape)
    err = float(np.einsum("eq,eqi->", wq, (uh - ue) ** 2))
    ref = float(np.einsum("eq,eqi->", wq, ue ** 2))
    mpi = dm.comm.tompi4py()
    return (np.sqrt(mpi.allreduce(err, op=MPI.SUM)), np.sqrt(mpi.allreduce(ref, op=MPI.SUM)))


# ------------------------------------------------------------------------------------------------
# A manufactured displacement field for linear elasticity


@dataclasses.dataclass(frozen=True)
class ProductField:
    """u_i = amp_i prod_j sin(omega_ij x_j + phase_ij): smooth, with closed-form derivatives
    d^o/dx_j^o sin(w x + p) = w^o sin(w x + p + o pi / 2)."""

    amp: np.ndarray      # (3,)
    omega: np.ndarray    # (3, 3)
    phase: np.ndarray    # (3, 3)

    def derivative(self, i: int, orders, x: np.ndarray) -> np.ndarray:
        """d^(o_x + o_y + o_z) u_i / dx^o_x dy^o_y dz^o_z at points x (m, 3)."""
        out = np.full(len(x), float(self.amp[i]))
        for j, o in enumerate(orders):
            w = self.omega[i, j]
            out *= w ** o * np.sin(w * x[:, j] + self.phase[i, j] + o * np.pi / 2)
        return out

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return np.stack([self.derivative(i, (0, 0, 0), x) for i in range(3)], axis=1)

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """(m, 3, 3) du_i/dx_j."""
        g = np.empty((len(x), 3, 3))
        for i in range(3):
            for j in range(3):
                g[:, i, j] = self.derivative(i, tuple(int(k == j) for k in range(3)), x)
        return g

    def second(self, i: int, j: int, k: int, x: np.ndarray) -> np.ndarray:
        """d^2 u_i / dx_j dx_k."""
        orders = [0, 0, 0]
        orders[j] += 1
        orders[k] += 1
        return self.derivative(i, tuple(orders), x)

    def body_force(self, lam: float, mu: float):
        """f = -div sigma(u) for linear isotropic elasticity:
        div sigma = mu lap u + (lam + mu) grad div u."""
        def f(x):
            out = np.empty((len(x), 3))
            for i in range(3):
                lap = sum(self.second(i, j, j, x) for j in range(3))
                grad_div = sum(self.second(k, k, i, x) for k in range(3))
                out[:, i] = -(mu * lap + (lam + mu) * grad_div)
            return out
        return f

    def stress(self, lam: float, mu: float, x: np.ndarray) -> np.ndarray:
        g = self.gradient(x)
        eps = 0.5 * (g + np.swapaxes(g, 1, 2))
        tr = np.trace(eps, axis1=1, axis2=2)
        return 2 * mu * eps + lam * tr[:, None, None] * np.eye(3)

    def expressions(self) -> list[str]:
        """The components as petsoft expressions of x, y, z."""
        out = []
        for i in range(3):
            factors = [f"sin({self.omega[i, j]!r}*{c} + {self.phase[i, j]!r})"
                       for j, c in enumerate("xyz")]
            out.append(f"{self.amp[i]!r}*" + "*".join(factors))
        return out
