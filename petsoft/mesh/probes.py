"""Probe points: locating reference points in the mesh and interpolating nodal fields there."""

from __future__ import annotations

import numpy as np

from petsoft.errors import ExperimentError
from petsoft.mesh.quadratic import shape_values


def locate(points: np.ndarray, tets: np.ndarray, probes: np.ndarray, *, source: str = "probes",
           tol: float = 1e-9, names=None) -> tuple[np.ndarray, np.ndarray]:
    """Cell and barycentric weights of each probe point in a tet mesh.

    Parameters
    ----------
    names : sequence of str, optional
        Names of the probes for the error message (default: their index in ``source``).

    Raises
    ------
    ExperimentError
        Naming the probe (index or name, and coordinates) that lies outside the mesh.
    """
    probes = np.asarray(probes, dtype=float).reshape(-1, 3)
    X = points[tets]
    T = np.transpose(X[:, 1:] - X[:, :1], (0, 2, 1))           # (E, 3, 3) columns = edges
    inv = np.linalg.inv(T)
    cells = np.empty(len(probes), dtype=np.int64)
    weights = np.empty((len(probes), 4))
    for i, p in enumerate(probes):  # few probes; each is vectorised over all cells
        lam = np.einsum("eij,ej->ei", inv, p[None, :] - X[:, 0])
        bary = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
        worst = bary.min(axis=1)
        best = int(np.argmax(worst))
        if worst[best] < -tol:
            label = f"{source}[{i}]" if names is None else f"{source}[\"{names[i]}\"]"
            raise ExperimentError(f"{label} = {p.tolist()} lies outside the mesh "
                                  "(probes are reference-configuration points inside the body)")
        cells[i], weights[i] = best, bary[best]
    return cells, weights


def interpolate(field: np.ndarray, tets: np.ndarray, cells: np.ndarray,
                weights: np.ndarray) -> np.ndarray:
    """Values of a nodal field (N, k) at located probes: (P, k)."""
    return np.einsum("pa,pak->pk", weights, np.asarray(field)[tets[cells]])


def embed(mesh, probes: np.ndarray, *, source: str = "probes", tol: float = 1e-9,
          names=None) -> tuple[np.ndarray, np.ndarray]:
    """Cell and node weights of each probe over ``mesh.cells`` (4 or 10 nodes per cell): the
    barycentric weights for 4-node tetrahedra, the quadratic shape functions for 10-node ones.
    Use with ``interpolate(field, mesh.cells, cells, weights)``; ``names`` as in :func:`locate`."""
    cells, bary = locate(mesh.points, mesh.tets, probes, source=source, tol=tol, names=names)
    return cells, shape_values(mesh.order, bary)
