"""ctypes bindings of the compiled element kernels (``csrc/elastic.c``).

This module owns the boundary between numpy arrays and the C functions: it validates shapes,
converts inputs to C-contiguous float64 once (a no-op for arrays that already are), calls one C
function for all elements, and turns the C status into :class:`InvertedElementError`. The
signatures mirror :mod:`petsoft.fem.kernels.reference`; the results agree with it to rounding.
"""

from __future__ import annotations

import ctypes
import importlib

import numpy as np

from petsoft.carrays import addr
from petsoft.errors import InvertedElementError, PetsoftError
from petsoft.fem.kernels.materials import MODELS, check_model
from petsoft.fem.kernels.reference import check_volumes

_lib = ctypes.CDLL(importlib.import_module("petsoft.fem.kernels._ckernels").__file__)

_ptr = ctypes.c_void_p
_i32, _i64 = ctypes.c_int32, ctypes.c_int64
_lib.petsoft_elastic_energy.argtypes = [_i32, _i64] + [_ptr] * 7
_lib.petsoft_elastic_energy.restype = _i64
_lib.petsoft_elastic_gradient_hessian.argtypes = [_i32, _i64] + [_ptr] * 5 + [_i32] + [_ptr] * 3
_lib.petsoft_elastic_gradient_hessian.restype = _i64
_lib.petsoft_elastic_gradient_indexed.argtypes = [_i32, _i64] + [_ptr] * 8
_lib.petsoft_elastic_gradient_indexed.restype = _i64
_lib.petsoft_elastic_energy_indexed.argtypes = [_i32, _i64] + [_ptr] * 8
_lib.petsoft_elastic_energy_indexed.restype = _i64
_lib.petsoft_material_response.argtypes = [_i32, _i64] + [_ptr] * 7
_lib.petsoft_material_response.restype = _i64
_lib.petsoft_elastic_quadrature.argtypes = ([_i32, _i64, _i32, _i32] + [_ptr] * 5 + [_i32]
                                            + [_ptr] * 4)
_lib.petsoft_elastic_quadrature.restype = _i64
_lib.petsoft_project_spd9.argtypes = [_i64, _ptr]
_lib.petsoft_project_spd9.restype = None

_BAD_MODEL = -2

__all__ = [
    "MODELS",
    "element_energy",
    "element_gradient_hessian",
    "element_gradient_hessian_into",
    "IndexedElements",
    "material_response",
    "project_spd",
    "quadrature_into",
]


def library() -> ctypes.CDLL:
    """The compiled kernels' shared library, for the modules that declare their own functions
    of it (:mod:`petsoft.fem.kernels.tet`)."""
    return _lib


def _ptr_of(a: np.ndarray | None) -> int | None:
    return None if a is None else addr(a)


def _c_array(a, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``a`` as a C-contiguous float64 array of ``shape`` (copying only if needed)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def _per_element(a, n: int, name: str) -> np.ndarray:
    """A scalar or (n,) parameter as a contiguous (n,) float64 array."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 0:
        return np.full(n, float(a))
    return _c_array(a, (n,), name)


def _inputs(dN, volume, u, mu, lam):
    dN = np.asarray(dN)
    if dN.ndim != 3 or dN.shape[1:] != (4, 3):
        raise ValueError(f"dN must have shape (n, 4, 3), got {dN.shape}")
    n = dN.shape[0]
    dN = _c_array(dN, (n, 4, 3), "dN")
    volume = _c_array(volume, (n,), "volume")
    check_volumes(volume)
    u = np.asarray(u)
    if u.shape == (n, 12):
        u = u.reshape(n, 4, 3)
    u = _c_array(u, (n, 4, 3), "u")
    return n, dN, volume, u, _per_element(mu, n, "mu"), _per_element(lam, n, "lam")


def _check_status(status: int, bad_J: ctypes.c_double) -> None:
    if status == -1:
        return
    if status == _BAD_MODEL:  # unreachable after check_model; kept for a C/Python mismatch
        raise PetsoftError("the compiled kernels do not know this material model")
    raise InvertedElementError(status, bad_J.value)


def _check_output(a: np.ndarray, shape: tuple[int, ...], name: str) -> None:
    if not isinstance(a, np.ndarray) or a.dtype != np.float64 or a.shape != shape:
        raise ValueError(f"{name} must be a float64 array of shape {shape}")
    if not a.flags.c_contiguous or not a.flags.writeable:
        raise ValueError(f"{name} must be C-contiguous and writeable")


def element_energy(model: str, dN, volume, u, mu, lam) -> np.ndarray:
    """Element energies ``volume * psi(F)``, shape (n,).

    Same parameters, result and errors as :func:`petsoft.fem.kernels.reference.element_energy`.
    """
    code = check_model(model)
    n, dN, volume, u, mu, lam = _inputs(dN, volume, u, mu, lam)
    W = np.empty(n)
    bad_J = ctypes.c_double(0.0)
    status = _lib.petsoft_elastic_energy(
        code, n, addr(dN), addr(volume), addr(u), addr(mu),
        addr(lam), addr(W), ctypes.addressof(bad_J),
    )  # fmt: skip
    _check_status(status, bad_J)
    return W


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
) -> None:
    """Element gradients and Hessians written into preallocated arrays.

    Parameters
    ----------
    model, dN, volume, u, mu, lam
        As :func:`petsoft.fem.kernels.reference.element_gradient_hessian`.
    g_out : ndarray, shape (n, 12), float64, C-contiguous, or None
        Receives ``dW_e/du``; None skips the gradient.
    H_out : ndarray, shape (n, 12, 12), float64, C-contiguous, or None
        Receives ``d^2 W_e/du^2``; None skips the Hessian.
    project_spd : bool
        Build H from the PSD projection of dP/dF.

    Raises
    ------
    InvertedElementError
        neo-Hookean with det F <= 0 (the first such element; outputs are then partly written).
    """
    code = check_model(model)
    n, dN, volume, u, mu, lam = _inputs(dN, volume, u, mu, lam)
    if g_out is not None:
        _check_output(g_out, (n, 12), "g_out")
    if H_out is not None:
        _check_output(H_out, (n, 12, 12), "H_out")
    bad_J = ctypes.c_double(0.0)
    status = _lib.petsoft_elastic_gradient_hessian(
        code, n, addr(dN), addr(volume), addr(u), addr(mu),
        addr(lam), int(bool(project_spd)), _ptr_of(g_out), _ptr_of(H_out),
        ctypes.addressof(bad_J),
    )  # fmt: skip
    _check_status(status, bad_J)


class IndexedElements:
    """The summed energy and the assembled gradient of a fixed set of 4-node elements at nodal
    displacements: the gather of each element's displacements, the element loop and (for the
    gradient) the scatter into a nodal array in one C call.

    The residual's path: the element arrays are checked here once and their addresses kept
    (they are held, so the addresses stay valid; their values may change in place, as a
    calibration's new Lame parameters do), and a call checks only the two nodal arrays.

    Parameters
    ----------
    model : str
    conn : ndarray (n, 4), int64
        Node indices into the nodal arrays, all below ``nnodes``.
    dN, volume, mu, lam : ndarray (n, 4, 3), (n,), (n,), (n,), float64, C-contiguous
        ``mu`` and ``lam`` are read at every call (not copied).
    nnodes : int
        Number of nodes of the nodal arrays.
    """

    def __init__(self, model: str, conn, dN, volume, mu, lam, nnodes: int):
        self.code = check_model(model)
        self.conn = np.ascontiguousarray(conn, dtype=np.int64)
        n = self.conn.shape[0]
        if self.conn.shape != (n, 4):
            raise ValueError(f"conn must have shape (n, 4), got {self.conn.shape}")
        if n and (int(self.conn.min()) < 0 or int(self.conn.max()) >= nnodes):
            raise ValueError(f"conn names nodes {int(self.conn.min())}..{int(self.conn.max())}"
                             f" of 0..{nnodes - 1}")
        for a, shape, name in ((dN, (n, 4, 3), "dN"), (volume, (n,), "volume"),
                               (mu, (n,), "mu"), (lam, (n,), "lam")):
            if not isinstance(a, np.ndarray) or a.dtype != np.float64 or a.shape != shape \
                    or not a.flags.c_contiguous:
                raise ValueError(f"{name} must be a C-contiguous float64 {shape} array")
        check_volumes(volume)
        self.arrays = (dN, volume, mu, lam)
        self.n, self.size = n, 3 * nnodes
        self._args = (addr(self.conn), addr(dN), addr(volume))
        self._lame = (addr(mu), addr(lam))
        self._bad_J = ctypes.c_double(0.0)

    def add_gradient(self, u_nodes: np.ndarray, out: np.ndarray) -> None:
        """out += sum_e dW_e/du at nodal displacements ``u_nodes``.

        Parameters
        ----------
        u_nodes, out : ndarray (nnodes, 3) or (3 nnodes,), float64, C-contiguous
            (``out`` writeable).

        Raises
        ------
        InvertedElementError
            neo-Hookean with det F <= 0, naming the first such element (of ``conn``); the
            elements before it have been added.
        """
        for a in (u_nodes, out):
            self._check_nodal(a)
        if not out.flags.writeable:
            raise ValueError("out must be writeable")
        status = _lib.petsoft_elastic_gradient_indexed(
            self.code, self.n, *self._args, addr(u_nodes), *self._lame, addr(out),
            ctypes.addressof(self._bad_J))
        _check_status(status, self._bad_J)

    def energy(self, u_nodes: np.ndarray) -> float:
        """sum_e V_e psi(F_e) at nodal displacements ``u_nodes`` (as :meth:`add_gradient`'s).

        Raises
        ------
        InvertedElementError
            As :meth:`add_gradient`.
        """
        self._check_nodal(u_nodes)
        total = ctypes.c_double(0.0)
        status = _lib.petsoft_elastic_energy_indexed(
            self.code, self.n, *self._args, addr(u_nodes), *self._lame,
            ctypes.addressof(total), ctypes.addressof(self._bad_J))
        _check_status(status, self._bad_J)
        return total.value

    def _check_nodal(self, a: np.ndarray) -> None:
        if a.dtype != np.float64 or a.size != self.size or not a.flags.c_contiguous:
            raise ValueError(f"nodal arrays must be C-contiguous float64 of {self.size} "
                             f"values, got {a.dtype} {a.shape}")


def element_gradient_hessian(
    model: str,
    dN,
    volume,
    u,
    mu,
    lam,
    project_spd: bool = False,
    hessian: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Element gradients (n, 12) and Hessians (n, 12, 12) (None if ``hessian`` is False).

    Same parameters, results and errors as
    :func:`petsoft.fem.kernels.reference.element_gradient_hessian`.
    """
    n = np.shape(dN)[0]
    g = np.empty((n, 12))
    H = np.empty((n, 12, 12)) if hessian else None
    element_gradient_hessian_into(model, dN, volume, u, mu, lam, g, H, project_spd)
    return g, H


def material_response(model: str, F, mu, lam) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The C constitutive law at given F: ``(psi (n,), P (n,3,3), dPdF (n,3,3,3,3))``.

    Same contract as :func:`petsoft.fem.kernels.materials.material_response`; exposed so the C
    material models can be tested pointwise.
    """
    code = check_model(model)
    F = np.asarray(F)
    n = F.shape[0] if F.ndim == 3 else -1
    F = _c_array(F, (n, 3, 3), "F")
    mu, lam = _per_element(mu, n, "mu"), _per_element(lam, n, "lam")
    psi, P, dPdF = np.empty(n), np.empty((n, 3, 3)), np.empty((n, 3, 3, 3, 3))
    bad_J = ctypes.c_double(0.0)
    status = _lib.petsoft_material_response(
        code, n, addr(F), addr(mu), addr(lam), addr(psi), addr(P),
        addr(dPdF), ctypes.addressof(bad_J),
    )  # fmt: skip
    _check_status(status, bad_J)
    return psi, P, dPdF


def project_spd(dPdF) -> np.ndarray:
    """The C positive semi-definite projection; same contract as
    :func:`petsoft.fem.kernels.materials.project_spd`."""
    A = np.array(dPdF, dtype=np.float64, order="C")  # always a copy: projected in place
    shape = A.shape
    if A.ndim < 1 or A.size != shape[0] * 81:
        raise ValueError(f"dPdF must have shape (n, 3, 3, 3, 3) or (n, 9, 9), got {shape}")
    _lib.petsoft_project_spd9(shape[0], addr(A))
    return A


def quadrature_into(model: str, dN, weight, u, mu, lam, energy_out: np.ndarray | None,
                    g_out: np.ndarray | None, H_out: np.ndarray | None,
                    project_spd: bool = False) -> None:
    """Energies, gradients and Hessians of elements integrated by quadrature, into buffers.

    Same contract as :func:`petsoft.fem.kernels.reference.quadrature`: ``dN`` (n, nq, k, 3),
    ``weight`` (n, nq), ``u`` (n, k, 3) or (n, 3k); outputs ``energy_out`` (n,), ``g_out``
    (n, 3k), ``H_out`` (n, 3k, 3k), each float64 C-contiguous or None to skip it.

    Raises
    ------
    InvertedElementError
        neo-Hookean with det F <= 0 at a point of an element (the first such element).
    """
    code = check_model(model)
    dN = np.asarray(dN)
    if dN.ndim != 4 or dN.shape[3] != 3 or not 1 <= dN.shape[2] <= 10:
        raise ValueError(f"dN must have shape (n, nq, k, 3) with k <= 10, got {dN.shape}")
    n, nq, k, _ = dN.shape
    dN = _c_array(dN, (n, nq, k, 3), "dN")
    weight = _c_array(weight, (n, nq), "weight")
    u = _c_array(np.reshape(u, (n, k, 3)), (n, k, 3), "u")
    mu, lam = _per_element(mu, n, "mu"), _per_element(lam, n, "lam")
    for out, shape, name in ((energy_out, (n,), "energy_out"), (g_out, (n, 3 * k), "g_out"),
                             (H_out, (n, 3 * k, 3 * k), "H_out")):
        if out is not None:
            _check_output(out, shape, name)
    bad_J = ctypes.c_double(0.0)
    status = _lib.petsoft_elastic_quadrature(
        code, n, k, nq, addr(dN), addr(weight), addr(u), addr(mu), addr(lam),
        int(bool(project_spd)), _ptr_of(energy_out), _ptr_of(g_out), _ptr_of(H_out),
        ctypes.addressof(bad_J),
    )  # fmt: skip
    _check_status(status, bad_J)
