"""``foundation.bilinear``: the body rests on an elastic foundation stiffer in compression.

A term of a user's own package (petsoft's formats.md, "Terms from other packages"): this one
module declares the term (:data:`TERM`: its ``[foundation]`` keys, its parameters, how
``petsoft diagnose`` proposes it) and builds its force (:func:`build`). The package's
pyproject.toml registers it::

    [project.entry-points."petsoft.terms"]
    foundation = "petsoft_foundation.term"

The foundation is a Winkler bed under the boundary faces selected by ``where`` (a region name or
a condition of x, y, z; without it, the boundary faces that face the ``direction``: whose
outward unit normal n has n . d > 0.99). Each node i of them carries the lumped area A_i of
those faces and a spring along the unit ``direction`` d (pointing from the body into the
foundation). With s_i = d . u_i the node's push into the bed,

    W(u) = sum_i 1/2 A_i k(s_i) s_i^2,   k(s) = k_c (s > 0, compression), k_t (s <= 0, tension),

so the traction is -k(s) s d per unit area: k_c, k_t in Pa/m (N/m^3). W is continuously
differentiable (its gradient A k(s) s d is continuous at s = 0) and piecewise quadratic: the
Hessian A k(s) d d^T jumps at s = 0, so the term is state-dependent and not part of the
reference stiffness K0 (``in_reference = False``). Its parameter derivatives are
d grad W / dk_c = A [s > 0] s d (and [s <= 0] for k_t); with the Hessian's action on w added,
d/dk_c (grad W + H w) = A [s > 0] (s + d . w) d.

This module is imported while petsoft's term registry loads: at the top it imports only numpy
and :mod:`petsoft.terms`; :func:`build` imports the rest of petsoft when called.
"""

from __future__ import annotations

import numpy as np

from petsoft.terms import Key, Parameter, Proposal, Term

NAME = "foundation.bilinear"
COMPRESSION, TENSION = "foundation.compression", "foundation.tension"

TERM = Term(
    name=NAME,
    meaning="the body rests on an elastic foundation, stiffer in compression than in tension",
    keys=(Key("foundation", "compression", unit="Pa/m", minimum=0.0),
          Key("foundation", "tension", unit="Pa/m", minimum=0.0),
          # the faces it supports (None: those facing the direction)
          Key("foundation", "where", type="where", default=None),
          Key("foundation", "direction", type="vector", default=(0.0, 0.0, -1.0))),
    # both moduli from 0; upper: a bed whose stiffness over the body's surface is 100x the
    # body's mass times its dominant angular frequency squared
    proposal=Proposal(
        kind="value",
        parameters=(Parameter(COMPRESSION, "Pa/m", lower="0",
                              upper="100 * mass * (2 * pi * frequency)**2 / area"),
                    Parameter(TENSION, "Pa/m", lower="0",
                              upper="100 * mass * (2 * pi * frequency)**2 / area")),
        settings=((COMPRESSION, "0"), (TENSION, "0")),
        note=" (a Winkler bed under the foundation faces, both moduli from 0)",
        continuum_only=True),
)


class BilinearFoundation:
    """The foundation's springs on this rank's owned nodes (module docstring).

    A petsoft :class:`~petsoft.physics.term.NodalTerm` and
    :class:`~petsoft.physics.term.ParametricTerm`.

    Parameters
    ----------
    nodes : ndarray (n,)
        Local vertex indices.
    areas : ndarray (n,)
        Lumped foundation area of each node (m^2).
    direction : array (3,)
        Unit vector from the body into the foundation.
    compression, tension : float
        k_c, k_t (Pa/m).
    """

    kind = NAME
    in_reference = False

    def __init__(self, nodes, areas, direction, compression: float, tension: float):
        self.nodes = np.asarray(nodes, dtype=np.int64)
        self.areas = np.asarray(areas, dtype=float)
        self.direction = np.asarray(direction, dtype=float)
        self.k = {COMPRESSION: float(compression), TENSION: float(tension)}

    def _push(self, u_local):
        """(s, k(s)) per node: the push into the bed and the modulus of its side."""
        s = u_local[self.nodes] @ self.direction
        return s, np.where(s > 0.0, self.k[COMPRESSION], self.k[TENSION])

    def energy(self, u_local: np.ndarray) -> float:
        s, k = self._push(u_local)
        return 0.5 * float(np.sum(self.areas * k * s * s))

    def gradient(self, u_local: np.ndarray) -> np.ndarray:
        s, k = self._push(u_local)
        return (self.areas * k * s)[:, None] * self.direction[None, :]

    def hessian(self, u_local: np.ndarray) -> np.ndarray:
        _, k = self._push(u_local)
        return (self.areas * k)[:, None, None] * np.outer(self.direction, self.direction)

    # -- the ParametricTerm interface ----------------------------------------------------------
    def parameters(self) -> dict[str, float]:
        return dict(self.k)

    def set_parameter(self, name: str, value: float) -> None:
        if name not in self.k:
            raise KeyError(name)
        self.k[name] = float(value)

    def add_parameter_derivative(self, name: str, u_local: np.ndarray, out: np.ndarray,
                                 w_local: np.ndarray | None = None) -> None:
        """Add d/dp (grad W(u) + H(u) w) into the local (nv, 3) ``out`` (w = 0 when None)."""
        if name not in self.k:
            raise KeyError(name)
        s, _ = self._push(u_local)
        side = s > 0.0 if name == COMPRESSION else s <= 0.0
        y = s if w_local is None else s + w_local[self.nodes] @ self.direction
        out[self.nodes] += (self.areas * side * y)[:, None] * self.direction[None, :]


def facing(mesh, direction: np.ndarray) -> np.ndarray:
    """(F, 3) the mesh's boundary faces whose outward unit normal n has n . direction > 0.99."""
    from petsoft.mesh.topology import exterior_faces

    faces = exterior_faces(mesh.tets)[0]
    p = mesh.points[faces]                                   # (F, 3 corners, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return faces[n @ direction > 0.99]


def build(experiment, dmesh, resolver, dirichlet) -> BilinearFoundation:
    """The foundation of ``experiment`` (its ``[foundation]`` table) on this rank (all ranks
    call, with the same replicated mesh: errors are raised everywhere)."""
    from petsoft.errors import ExperimentError
    from petsoft.physics.support import lumped_face_areas

    values = experiment.terms["foundation"]
    d = np.asarray(values["direction"], dtype=float)
    norm = float(np.linalg.norm(d))
    if norm == 0.0:
        raise ExperimentError(f"{experiment.source}: foundation.direction = {list(d)}: the "
                              "direction into the foundation must not be zero")
    if values["where"] is not None:
        faces = resolver.faces(values["where"], "foundation.where")
    else:
        faces = facing(dmesh.mesh, d / norm)
    lumped = lumped_face_areas(dmesh.mesh, faces)       # the whole mesh's: same on every rank
    if not lumped.any():
        raise ExperimentError(f"{experiment.source}: foundation.where: selects no boundary face "
                              "(a face belongs when all its vertices do); the foundation "
                              "needs a surface to support")
    areas = lumped[dmesh.vertex_ids]
    areas[~dmesh.owned] = 0.0                        # each node once over the ranks
    areas[np.any(dirichlet.owner >= 0, axis=1)] = 0.0   # a prescribed node stays prescribed
    nodes = np.flatnonzero(areas > 0.0)
    return BilinearFoundation(nodes, areas[nodes], d / norm, values["compression"],
                              values["tension"])
