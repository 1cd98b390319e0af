"""The refinements of a model's discretisation that the numerics checks try.

This module owns :data:`REFINEMENTS`, the list of ways a model can be made more accurate
without changing its physics (the time step halved, the mesh size halved), each a value that
says when it applies, makes the refined experiment (an :class:`~petsoft.experiment.Experiment`
that can be written and read back: a box's cells doubled, a file mesh's ``[mesh] refine``
raised by one), describes itself in words a user acts on, and turns the change a refinement
makes into an estimate of the discretisation error (Richardson). ``petsoft diagnose``'s
numerics check (:mod:`petsoft.diagnosis.numerics`) and ``petsoft calibrate --check-mesh``
(:mod:`petsoft.calibration.check_mesh`) use it.

**Adding a refinement** (the hook): append one :class:`Refinement` to :data:`REFINEMENTS`. The
P1 -> P2 raise (``[mesh] order = 2``, :data:`ORDER_RAISED`) is one: it applies to an order-1
continuum model, and its error factors are (1, 0) (``factors``): the P2 model's own error is far
below P1's on the same mesh (h^3 against h^2), so the whole change is the P1 model's error and
almost none remains. Its cost is that of P1 on the 1->8 refined mesh (the same nodes), which is
what the cell limits compare (``cost``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from petsoft.dynamics.factory import system_class
from petsoft.experiment import experiment_from_dict
from petsoft.mesh.refine import refined_cell_count
from petsoft.mesh.serial import read_mesh

#: Tetrahedra of a box cell (Kuhn split).
TETS_PER_BOX_CELL = 6


@functools.lru_cache(maxsize=16)
def _file_cells(path: str, mtime: float) -> int:
    return int(len(read_mesh(Path(path)).tets))


def mesh_cells(experiment) -> int:
    """Tetrahedra of a continuum experiment's mesh as the model uses it (after ``refine``)."""
    spec = experiment.mesh
    if spec.box is not None:
        base = TETS_PER_BOX_CELL * int(np.prod(spec.box.cells))
    else:
        base = _file_cells(str(spec.file), Path(spec.file).stat().st_mtime)
    return refined_cell_count(base, spec.refine)


def _with(experiment, change: Callable[[dict], None]):
    data = experiment.to_dict()
    change(data)
    return experiment_from_dict(data, source=experiment.source, base_dir=experiment.base_dir,
                                path=experiment.path)


@dataclass(frozen=True)
class Refinement:
    """One way to refine a model's discretisation (module docstring).

    Attributes
    ----------
    label : str
        Its key in reports (``"step/2"``, ``"mesh x2"``).
    kind : str
        ``"step"``, ``"mesh"`` or ``"order"``: what it refines, in the user's words.
    make : callable(experiment) -> experiment
        The refined experiment.
    applies : callable(experiment) -> str or None
        None when it applies to this experiment, else why not.
    cells : callable(experiment) -> int or None
        Tetrahedra of the refined model (None: it does not change the mesh).
    describe : callable(experiment) -> str
        What it does, e.g. "1->8 subdivision: 648 -> 5184 tets".
    order : callable(experiment, integrator) -> int
        Convergence order p of the simulated marker positions in the refined quantity.
    ratio : float
        Factor the refined quantity (step, mesh size) is divided by.
    cost : callable(experiment) -> int or None, optional
        The refined model's size as 4-node tetrahedra of the same node count, which the cell
        limits compare (default: ``cells``).
    factors : tuple of float, optional
        Fixed :meth:`error_factors` instead of Richardson's.
    """

    label: str
    kind: str
    make: Callable
    applies: Callable
    cells: Callable
    describe: Callable
    order: Callable
    ratio: float = 2.0
    cost: Callable | None = None
    factors: tuple[float, float] | None = None

    def error_factors(self, experiment, integrator: str | None = None) -> tuple[float, float]:
        """Richardson: (error of the current model, error left in the refined one) per unit of
        the change between them, with k = ratio^p: (k / (k - 1), 1 / (k - 1))."""
        if self.factors is not None:
            return self.factors
        k = self.ratio ** self.order(experiment, integrator)
        return k / (k - 1.0), 1.0 / (k - 1.0)


def _step_order(experiment, integrator=None) -> int:
    # backward Euler and the semi-implicit step are first order, the others second
    return 1 if (integrator or experiment.time.integrator) in ("be", "si") else 2


def _halve_step(experiment):
    def change(d):
        d["time"]["step"] = experiment.time.step / 2.0
    return _with(experiment, change)


def _quarter_step(experiment):
    def change(d):
        d["time"]["step"] = experiment.time.step / 4.0
    return _with(experiment, change)


def _refine_mesh(experiment):
    def change(d):
        if experiment.mesh.box is not None:
            # a box keeps its structured split: twice the cells per axis
            d["mesh"]["box"]["cells"] = [2 * c for c in experiment.mesh.box.cells]
        else:
            d["mesh"]["refine"] = experiment.mesh.refine + 1
    return _with(experiment, change)


def _mesh_applies(experiment) -> str | None:
    body = system_class(experiment)
    if not body.volume_cells:
        return f"a {body.defined_by} model has no volume cells to split: its mesh is not refined"
    return None


def _order_applies(experiment) -> str | None:
    body = system_class(experiment)
    if not body.element_orders:
        return f"a {body.defined_by} model has no finite elements"
    if experiment.mesh.order != 1:
        return "the elements are already quadratic (order 2)"
    return None


def _raise_order(experiment):
    def change(d):
        d["mesh"]["order"] = 2
    return _with(experiment, change)


def _mesh_describe(experiment) -> str:
    n = mesh_cells(experiment)
    if experiment.mesh.box is not None:
        cells = experiment.mesh.box.cells
        return (f"box cells {cells[0]}x{cells[1]}x{cells[2]} -> "
                f"{2 * cells[0]}x{2 * cells[1]}x{2 * cells[2]}: {n} -> {8 * n} tets")
    return f"every tet split 1->8: {n} -> {8 * n} tets"


STEP_HALVED = Refinement(
    label="step/2", kind="step", make=_halve_step, applies=lambda e: None,
    cells=lambda e: None,
    describe=lambda e: f"step {e.time.step:.4g} s -> {e.time.step / 2:.4g} s",
    order=_step_order)

#: The step quartered: not tried on its own (not in :data:`REFINEMENTS`); the numerics check
#: refits at a quarter of the step instead of half when the halved step's own run shows that
#: half would still leave an error to measure (:func:`petsoft.diagnosis.numerics.step_jump`).
STEP_QUARTERED = Refinement(
    label="step/4", kind="step", make=_quarter_step, applies=lambda e: None,
    cells=lambda e: None,
    describe=lambda e: f"step {e.time.step:.4g} s -> {e.time.step / 4:.4g} s",
    order=_step_order, ratio=4.0)


def _nodes_factor(experiment) -> int:
    """Nodes of a model per node of the P1 model on its mesh (about 8 for 10-node tets)."""
    return 1 if not system_class(experiment).element_orders or experiment.mesh.order == 1 else 8


MESH_HALVED = Refinement(
    label="mesh x2", kind="mesh", make=_refine_mesh, applies=_mesh_applies,
    cells=lambda e: 8 * mesh_cells(e), describe=_mesh_describe,
    # displacements converge as h^2 with 4-node tetrahedra, h^3 with 10-node ones
    order=lambda e, integrator=None: 2 if e.mesh.order == 1 else 3,
    cost=lambda e: 8 * mesh_cells(e) * _nodes_factor(e))

ORDER_RAISED = Refinement(
    label="P2", kind="order", make=_raise_order, applies=_order_applies,
    cells=lambda e: mesh_cells(e),
    describe=lambda e: f"4-node -> 10-node tetrahedra on the same {mesh_cells(e)} tets",
    order=lambda e, integrator=None: 2, cost=lambda e: 8 * mesh_cells(e),
    factors=(1.0, 0.0))

#: The refinements the numerics checks try, in order (module docstring: adding one).
REFINEMENTS: list[Refinement] = [STEP_HALVED, MESH_HALVED, ORDER_RAISED]


def _refine_mesh_and_step(experiment):
    return _halve_step(_refine_mesh(experiment))


def _lower_order(e, integrator=None) -> int:
    return min(MESH_HALVED.order(e, integrator), _step_order(e, integrator))


#: The mesh split and the step halved together: never fitted, only simulated once by the
#: numerics check when each refinement alone moved the fit away from the data (a mesh error and
#: a step error of opposite signs offsetting each other; seen on the independent L-bracket,
#: where the user's 10-node model at its step was closer to the data than at step/2 or on the
#: split mesh). Richardson's factors use the lower of the two orders (the larger estimate).
MESH_AND_STEP_HALVED = Refinement(
    label="mesh x2 + step/2", kind="mesh+step", make=_refine_mesh_and_step,
    applies=_mesh_applies, cells=MESH_HALVED.cells,
    describe=lambda e: f"{_mesh_describe(e)}, {STEP_HALVED.describe(e)}",
    order=_lower_order, cost=MESH_HALVED.cost)


def refinement(label: str) -> Refinement:
    """The entry of :data:`REFINEMENTS` (or :data:`MESH_AND_STEP_HALVED`,
    :data:`STEP_QUARTERED`) called ``label``."""
    known = REFINEMENTS + [MESH_AND_STEP_HALVED, STEP_QUARTERED]
    for r in known:
        if r.label == label:
            return r
    raise KeyError(f"unknown refinement {label!r}; known: {', '.join(r.label for r in known)}")


def why_not(r: Refinement, experiment, max_cells: int | None,
            whose: str = "the") -> str | None:
    """Why ``r`` is not tried on ``experiment`` (None: it is): it does not apply, or its
    refined mesh would have more than ``max_cells`` tetrahedra (``whose`` limit, e.g.
    "diagnose's")."""
    reason = r.applies(experiment)
    if reason is not None:
        return reason
    cost = (r.cost or r.cells)(experiment)
    if max_cells is not None and cost is not None and cost > max_cells:
        if r.kind == "order":
            return (f"10-node tetrahedra on {r.cells(experiment)} tets have as many nodes as "
                    f"{cost} 4-node ones, over {whose} limit of {max_cells}")
        if _nodes_factor(experiment) > 1:
            return (f"the refined mesh of 10-node tetrahedra would have as many nodes as "
                    f"{cost} 4-node ones, over {whose} limit of {max_cells}")
        return f"the refined mesh would have {cost} tets, over {whose} limit of {max_cells}"
    return None


def levels_needed(remaining_over_noise: float, order: int = 2) -> int:
    """Further halvings of the mesh size that bring an error of ``remaining_over_noise`` times
    the noise below the noise (the error falls as 2^-order per halving)."""
    if not remaining_over_noise > 1.0:
        return 0
    return int(math.ceil(math.log(remaining_over_noise) / math.log(2.0 ** order)))
