"""Public entry point of the elastic element kernels, used by the assembly.

This module owns the choice of backend: ``"c"`` (default, :mod:`petsoft.fem.kernels.compiled`) or
``"numpy"`` (:mod:`petsoft.fem.kernels.reference`, the specification). Both compute, for P1
tetrahedra, the element energy ``W_e = volume * psi(F)``, its gradient ``g = dW_e/du`` (the
internal force is ``-g``) and Hessian ``H = d^2 W_e/du^2``, dof order ``3 * node + component``.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import PetsoftError
from petsoft.fem.kernels import reference
from petsoft.fem.kernels.materials import MODELS, lame_parameters

__all__ = [
    "BACKENDS",
    "MODELS",
    "element_energy",
    "element_gradient_hessian",
    "element_gradient_hessian_into",
    "IndexedElements",
    "lame_parameters",
    "quadrature_into",
]

BACKENDS = ("c", "numpy")


def _backend(name: str):
    if name == "c":
        # Imported on first use so that the numpy backend works without the compiled library.
        from petsoft.fem.kernels import compiled

        return compiled
    if name == "numpy":
        return reference
    raise PetsoftError(f"unknown kernel backend {name!r}; valid backends are {', '.join(BACKENDS)}")


def element_energy(model: str, dN, volume, u, mu, lam, *, backend: str = "c") -> np.ndarray:
    """Elastic energy of each element.

    Parameters
    ----------
    model : str
        One of :data:`MODELS`.
    dN : ndarray, shape (n, 4, 3)
        Shape-function gradients from :func:`petsoft.fem.kernels.tet.shape_gradients`.
    volume : ndarray, shape (n,)
        Reference volumes (> 0).
    u : ndarray, shape (n, 4, 3) or (n, 12)
        Element nodal displacements.
    mu, lam : float or ndarray, shape (n,)
        Lamé parameters (see :func:`lame_parameters`).
    backend : {"c", "numpy"}

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    InvertedElementError
        neo-Hookean with det F <= 0, naming the first such element (in this array's numbering).
    MeshError
        A volume <= 0.
    PetsoftError
        Unknown model or backend.
    """
    return _backend(backend).element_energy(model, dN, volume, u, mu, lam)


def element_gradient_hessian(
    model: str,
    dN,
    volume,
    u,
    mu,
    lam,
    project_spd: bool = False,
    hessian: bool = True,
    *,
    backend: str = "c",
) -> tuple[np.ndarray, np.ndarray | None]:
    """Gradient (n, 12) and Hessian (n, 12, 12) of each element energy.

    Parameters
    ----------
    model, dN, volume, u, mu, lam, backend
        As :func:`element_energy`.
    project_spd : bool
        Build H from the positive semi-definite projection of dP/dF, so each H is PSD (for
        Newton on non-convex energies). The gradient is unaffected.
    hessian : bool
        If False only the gradient is computed and H is None.

    Returns
    -------
    g : ndarray, shape (n, 12)
    H : ndarray, shape (n, 12, 12), or None

    Raises
    ------
    InvertedElementError, MeshError, PetsoftError
        As :func:`element_energy`.
    """
    return _backend(backend).element_gradient_hessian(
        model, dN, volume, u, mu, lam, project_spd=project_spd, hessian=hessian
    )


def element_gradient_hessian_into(
    model: str,
    dN,
    volume,
    u,
    mu,
    lam,
    g_out: np.ndarray | None,
    H_out: np.ndarray | None,
    project_spd: bool = False,
    *,
    backend: str = "c",
) -> None:
    """As :func:`element_gradient_hessian`, writing into preallocated arrays.

    The assembly calls this every Newton step with the same buffers, so no (n, 12, 12) array is
    allocated per step (with the C backend nothing of size n*144 is allocated at all).

    Parameters
    ----------
    g_out : ndarray, shape (n, 12), float64, C-contiguous, or None
        Receives the gradients; None skips them.
    H_out : ndarray, shape (n, 12, 12), float64, C-contiguous, or None
        Receives the Hessians; None skips them.
    others
        As :func:`element_gradient_hessian`.
    """
    if backend == "numpy":
        g, H = reference.element_gradient_hessian(
            model, dN, volume, u, mu, lam, project_spd=project_spd, hessian=H_out is not None
        )
        if g_out is not None:
            g_out[...] = g
        if H_out is not None:
            H_out[...] = H
        return
    _backend(backend).element_gradient_hessian_into(
        model, dN, volume, u, mu, lam, g_out, H_out, project_spd=project_spd
    )


class IndexedElements:
    """The summed energy and the assembled gradient ``sum_e dW_e/du`` of a fixed set of
    4-node elements at nodal displacements.

    What :func:`element_energy` and :func:`element_gradient_hessian_into` (followed by a
    scatter of the element vectors) compute; the C backend gathers the element displacements,
    loops and scatters in one compiled call (the residual's path: for small models the Python
    around the element loop cost more than the loop).

    Parameters
    ----------
    model : str
        One of :data:`MODELS`.
    conn : ndarray (n, 4), int
        Node indices of each element into the nodal arrays.
    dN, volume, mu, lam : ndarray (n, 4, 3), (n,), (n,), (n,), float64, C-contiguous
        As :func:`element_energy` (per element); ``mu`` and ``lam`` are read at each call, so
        changing them in place changes the law.
    nnodes : int
        Number of nodes of the nodal arrays.
    backend : {"c", "numpy"}
    """

    def __init__(self, model: str, conn, dN, volume, mu, lam, nnodes: int, *,
                 backend: str = "c"):
        self._numpy = backend == "numpy"
        self._model, self._conn = model, np.asarray(conn)
        self._arrays = (dN, volume, mu, lam)
        self._c = None if self._numpy else _backend(backend).IndexedElements(
            model, conn, dN, volume, mu, lam, nnodes)

    def add_gradient(self, u_nodes: np.ndarray, out: np.ndarray) -> None:
        """``out += sum_e dW_e/du`` at nodal displacements ``u_nodes`` ((nnodes, 3) or
        (3 nnodes,), float64, C-contiguous; ``out`` of the same size, writeable).

        Raises
        ------
        InvertedElementError
            neo-Hookean with det F <= 0, naming the first such element (of ``conn``).
        """
        if not self._numpy:
            self._c.add_gradient(u_nodes, out)
            return
        dN, volume, mu, lam = self._arrays
        u = np.asarray(u_nodes).reshape(-1, 3)
        g, _ = reference.element_gradient_hessian(self._model, dN, volume, u[self._conn], mu,
                                                  lam, hessian=False)
        np.add.at(out.reshape(-1, 3), self._conn, g.reshape(-1, 4, 3))

    def energy(self, u_nodes: np.ndarray) -> float:
        """``sum_e V_e psi(F_e)`` at nodal displacements ``u_nodes`` (as :meth:`add_gradient`).

        Raises
        ------
        InvertedElementError
            As :meth:`add_gradient`.
        """
        if not self._numpy:
            return self._c.energy(u_nodes)
        dN, volume, mu, lam = self._arrays
        u = np.asarray(u_nodes).reshape(-1, 3)
        return float(reference.element_energy(self._model, dN, volume, u[self._conn], mu,
                                              lam).sum())


def quadrature_into(model: str, dN, weight, u, mu, lam, energy_out: np.ndarray | None,
                    g_out: np.ndarray | None, H_out: np.ndarray | None,
                    project_spd: bool = False, *, backend: str = "c") -> None:
    """Energies, gradients and Hessians of elements integrated by quadrature (10-node
    tetrahedra), written into preallocated arrays (any may be None to skip it).

    Parameters
    ----------
    model : str
        One of :data:`MODELS`.
    dN : ndarray (n, nq, k, 3)
        Shape gradients at the points (:func:`petsoft.fem.element.quadratic_geometry`).
    weight : ndarray (n, nq)
        Quadrature weights times det J.
    u : ndarray (n, k, 3) or (n, 3k)
    mu, lam : float or ndarray (n,)
    energy_out, g_out, H_out : ndarray (n,), (n, 3k), (n, 3k, 3k), float64 C-contiguous
    project_spd : bool
        Project dP/dF to PSD at every point (then H is PSD).
    backend : {"c", "numpy"}

    Raises
    ------
    InvertedElementError
        neo-Hookean with det F <= 0 at a point (the first such element).
    """
    if backend == "numpy":
        W, g, H = reference.quadrature(model, dN, weight, u, mu, lam, project_spd=project_spd,
                                       hessian=H_out is not None)
        for out, value in ((energy_out, W), (g_out, g), (H_out, H)):
            if out is not None:
                out[...] = value
        return
    _backend(backend).quadrature_into(model, dN, weight, u, mu, lam, energy_out, g_out, H_out,
                                      project_spd=project_spd)
