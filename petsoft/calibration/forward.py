"""The forward model of a calibration: parameters -> simulated marker positions, and gradients.

:class:`ForwardModel` runs one of the implicit integrators ``be``, ``si`` or ``alpha`` (petsoft's
own generalized-alpha step, started from the consistent acceleration) on a system whose
parameters are changed in place, and observes the markers at the frame times (linear
interpolation between the two neighbouring steps). It differentiates the *discrete* time
stepping exactly (to the solver tolerances), in two ways:

* forward sensitivities (:meth:`ForwardModel.jacobian`): the tangent of every parameter is
  carried along the run, one linear solve per parameter and step; cheap for few parameters;
* a discrete adjoint (:meth:`ForwardModel.gradient`): one forward run that stores the
  trajectory, then one backward sweep with one linear solve per step, whatever the number of
  parameters (P dot products per step).

Both solve with the step's Jacobian, reassembled at the state the step's equation is linearised
at (BE: q1; SI: the predictor q0 + h v0, the very matrix of the SI step; alpha: q_f); it is
symmetric, so the adjoint solves with the same operator. A solver of their own (prefix
``fm_grad_``; the system's default: a direct solve for small systems, else CG + GAMG at rtol
1e-12) is used rather than the integrator's KSP: Newton assembles its last Jacobian at the
previous iterate, and the derivative needs it at the converged state. Where that solver is the
default direct one, the forward sensitivities do not factor every step's Jacobian: they solve
with it by GMRES preconditioned with the factors of an earlier step's, renewed when a solve
needs more than a few iterations (:mod:`petsoft.solvers.lagged_factors`, to a relative error
of ~1e-11 a solve; :attr:`ForwardModel.lags_factors` = False factors every step), and lend
those factors to the next step's Newton chord (:mod:`petsoft.solvers.borrowed_chord`).
``stats["tangent_solves"]`` counts their factorisations and GMRES iterations.

The formulas of one step's tangent and adjoint live beside each scheme, behind one protocol
(:class:`petsoft.dynamics.step_derivatives.StepDerivatives`, built by the registry's
``Scheme.derivatives``): :mod:`petsoft.dynamics.implicit_derivatives` (be; si with its
third-derivative term T_w) and :mod:`petsoft.dynamics.alpha_derivatives` (generalized-alpha).
This module runs the steps, stores or recomputes the states, calls the scheme's
``linearize``/``tangent_step``/``adjoint_step`` with its own solver of the step's Jacobian, and
contracts the parameter derivatives R_p = d r/d p (:meth:`DynamicSystem.parameter_derivatives`)
into the gradient. The initial state's derivatives are its own: the consistent initial
acceleration M a0 = f - grad W(q0) - D v0 (alpha's start, and what ``observe="acceleration"``
reports at t = 0) gives M da0 = -R_p(t0) (- K(q0) dq0 from a static start, below).

A viscoelastic branch (``[viscoelastic]`` ratio > 0, or its parameters among the names) is
simulated by be, si and alpha (:meth:`ForwardModel.simulate`, :meth:`~ForwardModel.fd_jacobian`).
Backward Euler's forward sensitivities carry its internal variable z as one more state: with
c = g/(1 + r), r = h/tau, the step's residual gains c K0 (q1 - z0) and

* J dq1 = (the BE right-hand side, with d/dp of c K0 (q1 - z0) in R_p) + c K0 dz0,
  J including c K0; dz0 = dq0 at t = 0 (the branch starts relaxed, z0 = q0);
* dz1 = (dz0 + r dq1 + dr (q1 - z1))/(1 + r), dr = -r/tau for ``viscoelastic.relaxation_time``;
* d R/d g = K0 (q1 - z0)/(1 + r), d R/d tau = g (r/tau)/(1 + r)^2 K0 (q1 - z0).

When the branch's parameters are among the names, z is tracked also at ratio 0 (the force is
then zero and the trajectory exactly the elastic one), so d sim/d ratio exists at 0, the null
hypothesis of a diagnosis.

Generalized-alpha's forward sensitivities carry z too (:mod:`petsoft.dynamics.alpha_derivatives`).
The adjoint (:meth:`~ForwardModel.gradient`, :meth:`~ForwardModel.cell_gradient`) and the si
sensitivities do not include z: they raise an ExperimentError pointing to ``--gradient fd`` (or
``sensitivity`` with be or alpha).

Also: :meth:`ForwardModel.cell_gradient` (the adjoint gradient plus d value/d E and d value/d rho
of every cell, sensitivity maps, from the same sweep), :meth:`ForwardModel.fd_jacobian` (central
differences), and ``observe="acceleration"`` (marker accelerations instead of positions).

Memory: the adjoint needs every step's state, (N + 1) x (2 vectors, 3 for alpha) x ndof x 8 bytes
(e.g. 1000 steps of a 30 000-dof mesh: 0.7 GB for alpha). It keeps them all while they fit
:data:`ADJOINT_MEMORY` per rank (or ``checkpoints``, if given); beyond that it holds ``s``
snapshots and recomputes the states between them on the way back, on Griewank's binomial schedule
(:mod:`petsoft.calibration.checkpointing`): with r the least number with C(s + r, s) >= N, no
step is recomputed more than r times. The recomputed steps are the first run's steps from the same
state (alpha from the stored acceleration), so the gradient is the same to the solver tolerance
(``stats["adjoint"]`` counts recomputed steps and the peak of states held).

Initial states: expression initial conditions do not depend on parameters; ``[initial]
from = "static"`` does: the equilibrium grad W(q0) = f_g + f_t(0) is solved tightly (SNES rtol
1e-13, prefix ``fm_static_``) and differentiated, K(q0) dq0/dp = -d r_static/dp (and for alpha
the consistent acceleration's derivative gains -K(q0) dq0).
"""

from __future__ import annotations

import functools
import math
import re
from contextlib import contextmanager
from contextvars import ContextVar

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.checkpointing import SweepStats, reverse_sweep, spine
from petsoft.calibration.observation import MarkerObserver, time_interpolation
from petsoft.dynamics.alpha import GeneralizedAlpha, consistent_acceleration
from petsoft.dynamics.factory import build_system
from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.initial import initial_from_expressions
from petsoft.dynamics.integrators import check_viscoelastic, scheme, with_gradients
from petsoft.dynamics.interfaces import length_scale
from petsoft.dynamics.parameters import VISCOELASTIC
from petsoft.dynamics.step_derivatives import mass_solver, parameter_derivatives
from petsoft.errors import ExperimentError, SolverError
from petsoft.experiment import get_parameter
from petsoft.io.progress import beat
from petsoft.physics.viscoelastic import RATIO
from petsoft.solvers.convergence import check_converged
from petsoft.solvers.lagged_factors import LaggedFactors
from petsoft.solvers.linear import is_direct, solver_chosen, symmetric_factorisation
from petsoft.solvers.options import FORWARD_KEYS, GRADIENT_KEYS, SolverOptions
from petsoft.solvers.static import StaticSolver

#: The schemes with gradients (the registry says which).
INTEGRATORS = with_gradients()
PREFIX = "fm_"
GRAD_PREFIX = "fm_grad_"
#: Newton of the forward run: gradients are only as accurate as the solves (user options win).
FORWARD_OPTIONS = {"snes_rtol": "1e-12"}
#: Newton of a static initial state, solved tightly: its derivative holds at the exact solution
STATIC_OPTIONS = {"snes_rtol": "1e-13"}
#: a caller's defaults of the forward runs' options (:func:`forward_defaults`)
_CALLER_DEFAULTS: ContextVar[dict[str, str] | None] = ContextVar("forward_defaults",
                                                                default=None)


@contextmanager
def forward_defaults(**defaults: str):
    """Defaults (names without the ``fm_`` prefix) of the forward models built inside the
    block, over :data:`FORWARD_OPTIONS` and under the experiment's ``[petsc]`` table and the
    command line: diagnose's Newton tolerance for every forward run it makes
    (``forward_defaults(snes_rtol="1e-06")``). Nothing enters PETSc's options database here."""
    token = _CALLER_DEFAULTS.set({**(_CALLER_DEFAULTS.get() or {}),
                                  **{k: str(v) for k, v in defaults.items()}})
    try:
        yield
    finally:
        _CALLER_DEFAULTS.reset(token)


def forward_options(table=None) -> SolverOptions:
    """The options of a forward run's solvers (prefix ``fm_``) from an experiment's ``[petsc]``
    table: see :class:`ForwardModel`'s ``solver_options``."""
    return SolverOptions(PREFIX, table, FORWARD_KEYS,
                         defaults={**FORWARD_OPTIONS, **(_CALLER_DEFAULTS.get() or {})})
#: Bytes of stored states the adjoint may hold per rank before it checkpoints (binomial).
ADJOINT_MEMORY = 1 << 30
_GROUP = re.compile(r"#(\d+)$")


def _collects_garbage(method):
    """Run PETSc's garbage cleanup (collective on the model's communicator) after ``method``.

    petsc4py defers destroying the PETSc objects Python frees (temporary vectors, the per-step
    solvers) to a garbage list that only ``PETSc.garbage_cleanup`` empties; a calibration makes
    thousands of runs, and without this their objects accumulated by the gigabyte.
    """

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        finally:
            PETSc.garbage_cleanup(self.comm)

    return wrapper


class ForwardModel:
    """Parameters -> marker positions at frame times, with forward and adjoint gradients.

    Parameters
    ----------
    experiment : Experiment
        Needs ``[time]`` (step, and the integrator unless given).
    names : sequence of str
        Parameter names (:meth:`DynamicSystem.parameter_names`; ``material.youngs_modulus#k``
        defines a stiffness field of 1 + max k Morton-chunk cell groups).
    observer : MarkerObserver or callable(system) -> MarkerObserver
        ``observe(q) -> (M, 3)`` = reference + B q (same on every rank), ``adjoint(w) -> Vec``
        = B^T w. A callable is called with this model's system (the observer must be built on
        the system whose vectors it observes).
    frame_times : (K,) array
        Times of the observed frames, within [0, N h]; the run lasts ceil(max / h) steps.
    comm : PETSc.Comm, optional
    integrator : {"be", "si", "alpha"}, optional
        Default: ``[time] integrator``.
    h : float, optional
        Step (default ``[time] step``).
    solver_options : dict, optional
        An experiment's ``[petsc]`` table. Its ``ksp_``, ``pc_``, ``mat_`` and ``snes_`` keys
        without prefix (``ksp_type``) reach the forward run's solvers under the prefix ``fm_``,
        its ``ksp_``, ``pc_`` and ``mat_`` keys the gradient solves' under ``fm_grad_``; keys
        written with one of those prefixes (or ``fm_static_``) reach that solver only and win
        over the copied ones; the command line wins over both. Each solver pushes them while it
        is set up and solves (:class:`~petsoft.solvers.options.SolverOptions`).
    recording : Recording or path, optional
        The recording whose ``/inputs`` drive ``series`` supports (a model driven by a measured
        input is fitted to the recording that holds that input).
    system : System, optional
        A prebuilt system offering the same interface; default: the experiment's
        (:func:`petsoft.dynamics.factory.build_system`). The initial state is
        ``system.initial_state()``, except a static one (``initial.from = "static"``), which is
        solved here, tightly, on ``system.model``.
    mesh : petsoft.mesh.serial.Mesh, optional
        Use this mesh instead of the experiment's (a computed rest shape,
        :mod:`petsoft.calibration.rest_shape`).
    checkpoints : int, optional
        The most states the adjoint holds at once (>= 2; None or 0: all of them while they fit
        :data:`ADJOINT_MEMORY`, else as many as fit).
    observe : {"position", "acceleration"}
        What the markers report: positions X + B q, or accelerations B a (``/frames/acceleration``
        of a recording): alpha's own a_n, (v_n - v_{n-1})/h for be and si, and the consistent
        acceleration M^-1 (f - grad W - D v) at t = 0 for all three.
    """

    def __init__(self, experiment, names, observer, frame_times, comm=None, integrator=None,
                 h=None, system=None, observe: str = "position",
                 solver_options: dict | None = None, recording=None,
                 checkpoints: int | None = None, mesh=None):
        exp = self.experiment = experiment
        self.checkpoints = checkpoints
        if observe not in ("position", "acceleration"):
            raise ExperimentError(f"observe = {observe!r}: valid are position, acceleration")
        self.accel = observe == "acceleration"
        if exp.time is None and (h is None or integrator is None):
            raise ExperimentError(f"{exp.source}: [time] is missing: the forward model needs "
                                  "its step and integrator")
        self.method = integrator or exp.time.integrator
        if self.method not in INTEGRATORS:
            raise ExperimentError(
                f"{exp.source}: time.integrator = {self.method!r}: gradients are implemented for "
                f"{', '.join(INTEGRATORS)} only")
        self.scheme = scheme(self.method)
        # accelerations are part of the state (alpha) or observed (a_n = (v_n - v_n-1)/h for
        # be/si, the consistent acceleration at t = 0)
        self.has_a = self.scheme.carries_acceleration or self.accel
        self.static = exp.initial.from_ == "static"
        self.h = float(h if h is not None else exp.time.step)
        self.options = forward_options(solver_options)
        self.grad_options = SolverOptions(GRAD_PREFIX, solver_options, GRADIENT_KEYS)
        self.static_options = SolverOptions(PREFIX + "static_", solver_options,
                                            defaults=STATIC_OPTIONS)
        if system is None:
            # a mass-spring system offers the same parameter interface (names, in-place
            # set_parameters, residual_parameter_derivatives): the generic derivative path
            system = build_system(exp, comm, recording, mesh=mesh)
        self.system = s = system
        self.model = s.model
        if self.static and self.model is None:
            raise ExperimentError(f"{exp.source}: initial.from = \"static\": the forward model "
                                  "solves the static equilibrium on the system's model, and the "
                                  "given system has none")
        self.comm = s.comm
        #: the heartbeat's lines come from the first rank of the run's communicator only
        self._speaks = self.comm.getRank() == 0
        self.names = list(names)
        groups = [int(m.group(1)) for n in self.names if (m := _GROUP.search(n))]
        if groups:
            s.define_stiffness_groups(max(groups) + 1)
        pnames = s.parameter_names()
        if s.viscoelastic is not None:
            pnames = pnames + list(VISCOELASTIC)   # simulate / fd only (see the docstring)
        bad = [n for n in self.names if n not in pnames]
        if bad:
            raise ExperimentError(f'{exp.source}: "{bad[0]}" is not a differentiable parameter; '
                                  f"valid: {', '.join(pnames)} (and material.youngs_modulus#k)")
        if any(n in VISCOELASTIC for n in self.names):
            # z evolves also at ratio 0, so that d sim/d ratio exists there (be sensitivities)
            s.viscoelastic.track = True
        if s.parameters is not None:
            self.p0 = np.array([s.parameters.values[n] for n in self.names])
        else:
            self.p0 = np.array([get_parameter(exp, n) for n in self.names])
        self._own_observer = not isinstance(observer, MarkerObserver)   # else a factory
        self.observer = observer(s) if self._own_observer else observer
        # the marker reference positions: observe(0) (the contract is observe(q) = X + B q)
        zero = s.create_vec()
        zero.zeroEntries()
        self.reference = np.array(self.observer.observe(zero), dtype=float).reshape(-1, 3)
        zero.destroy()
        self.frame_times = np.asarray(frame_times, dtype=float)
        self.nsteps = max(1, math.ceil(self.frame_times.max() / self.h - 1e-9))
        steps = self.h * np.arange(self.nsteps + 1)
        self.frame_index, self.frame_weight = time_interpolation(
            self.frame_times, steps, source=f"{exp.source}: frame_times")
        # which frames each step contributes to, with its weight
        self.uses: dict[int, list[tuple[int, float]]] = {}
        for k in range(len(self.frame_times)):
            for i, w in zip(self.frame_index[k], self.frame_weight[k], strict=True):
                if w != 0.0:
                    self.uses.setdefault(int(i), []).append((k, float(w)))
        if self.scheme.carries_acceleration:
            self.integrator = GeneralizedAlpha(s, exp.time.alpha_radius if exp.time else 0.5,
                                               options=self.options)
        else:
            self.integrator = ImplicitIntegrator(s, self.method, options=self.options)
        self.J = s.create_matrix()
        modes = s.near_nullspace()
        if modes is not None:
            self.J.setNearNullSpace(modes)
        # the scheme's tangent and adjoint steps (petsoft.dynamics.step_derivatives)
        self.step_derivatives = self.scheme.derivatives(s, self.integrator, self.h, self.accel)
        # the length scale of the generic parameter derivatives' difference (initial state)
        self.cell_size = length_scale(s)
        self.stats = {}

    # -- parameters and the forward run -----------------------------------------------------------
    def _set(self, p) -> None:
        p = np.asarray(p, dtype=float).reshape(-1)
        if len(p) != len(self.names):
            raise ValueError(f"{len(p)} parameter values for {len(self.names)} names")
        if not np.isfinite(p).all():
            raise ExperimentError(f"{self.experiment.source}: non-finite parameter values "
                                  f"{dict(zip(self.names, p.tolist(), strict=True))}")
        self.system.set_parameters(dict(zip(self.names, p.tolist(), strict=True)))
        check_viscoelastic(self.system.viscoelastic, self.method,
                         where=f"{self.experiment.source}: the forward model's integrator")

    def _refuse_derivatives(self, p, sensitivities: bool = False) -> None:
        """Raise (on every rank) when the run has a viscoelastic branch or its parameters are
        requested: the adjoint (and the forward sensitivities of si) do not include the
        branch's internal variable; backward Euler's and generalized-alpha's forward
        sensitivities do."""
        if sensitivities and self.scheme.branch_sensitivities:
            return

        asked = [n for n in self.names if n in VISCOELASTIC]
        branch = self.system.viscoelastic
        ratio = branch.ratio if branch is not None else 0.0
        if RATIO in self.names:
            ratio = float(np.asarray(p, dtype=float).reshape(-1)[self.names.index(RATIO)])
        if asked or ratio > 0.0:
            what = (f'parameter "{asked[0]}" is requested' if asked
                    else f"[viscoelastic] ratio = {ratio:g} (the branch is on)")
            raise ExperimentError(
                f"{self.experiment.source}: {what}: the adjoint gradient (and the forward "
                "sensitivities of si) do not include the viscoelastic branch's "
                "internal variable; use --gradient fd (finite differences), --gradient "
                "sensitivity with integrator be or alpha, or ratio = 0")

    def _initial(self):
        s = self.system
        if not self.static:
            return s.initial_state()

        # the static equilibrium under the current parameters, solved tightly: its derivative
        # K(q0) dq0/dp = -d r_static/dp holds at the exact solution
        solver = StaticSolver(self.model, options=self.static_options)
        try:
            q0 = solver.solve().displacement.copy()
        finally:
            solver.destroy()
        return initial_from_expressions(s, self.experiment.initial, q0)

    def _static_setup(self, q0):
        """(K(q0) in self.J, a solver on it, d r_static/dp at q0) for the static initial state.

        r_static = grad W(q0) - f_g - f_t(0): the residual at v = a = 0.
        """
        s = self.system
        zero = q0.duplicate()
        zero.zeroEntries()
        s.assemble_combination(q0, 0.0, 1.0, 0.0, self.J)
        deriv = self._derivatives(q0, zero, zero)
        zero.destroy()
        return self._solver(), deriv

    def _run(self, p, store: bool, on_step=None, keep=()):
        """Forward run; returns the states and the frames.

        The states are [(q, v, a or None)] of every step if ``store``; otherwise the last one,
        and those whose step is in ``keep`` (the adjoint's checkpoints) as ``{step: state}``
        with step 0 always kept.
        """
        s = self.system
        self._set(p)
        q, v = self._initial()
        branch = s.viscoelastic
        if branch is not None:
            branch.reset(q)     # every run starts with the branch relaxed
        a = None
        self.integrator.new_run()
        if self.has_a:
            a = s.create_vec()
            if self.scheme.carries_acceleration:
                self.integrator.forget()
            # the integrator's own formula (alpha recomputes the same a0 on its first step)
            consistent_acceleration(s, 0.0, q, v, a)
        states = [(q.copy(), v.copy(), a.copy() if a is not None else None)]
        kept = {0: states[0]} if keep else None
        obs = {}
        self._observe(0, a if self.accel else q, obs)
        q1, v1 = q.duplicate(), v.duplicate()
        for n in range(self.nsteps):
            a1 = self._step(n, q, v, q1, v1, p)
            if on_step is not None:
                on_step(n, states[-1], (q1, v1, a1))
            if store:
                states.append((q1.copy(), v1.copy(), a1))
            else:
                if kept is None or states[-1] is not kept.get(n):
                    self._free_state(states[-1])
                states[-1] = (q1.copy(), v1.copy(), a1)
                if kept is not None and n + 1 in keep:
                    kept[n + 1] = states[-1]
            q1.copy(q)
            v1.copy(v)
            self._observe(n + 1, states[-1][2] if self.accel else q, obs)
        for x in (q, v, q1, v1, a):
            if x is not None:
                x.destroy()
        if kept is not None:
            if states[-1] is not kept.get(self.nsteps):
                self._free_state(states[-1])
            return kept, self._frames(obs)
        return states, self._frames(obs)

    def _step(self, n, q, v, q1, v1, p):
        """Step n -> n+1 from (q, v) into (q1, v1); returns a1 (a new vector) or None."""
        h = self.h
        if self._speaks:
            beat(lambda: f"still simulating: step {n + 1} of {self.nsteps} "
                         f"({q.getSize()} dofs, {self.method})")
        report = self.integrator.step(n * h, q, v, h, q1, v1)
        if not report.converged:
            raise SolverError(
                f"{self.experiment.source}: forward model ({self.method}) step {n + 1} at "
                f"t = {n * h:.6g} s (h = {h:.3g} s) failed: {report.reason}; parameters "
                f"{dict(zip(self.names, np.asarray(p).tolist(), strict=True))}. No retry "
                "with a smaller step in calibration runs: use a smaller [time] step or "
                "tighter parameter bounds")
        if self.scheme.carries_acceleration:
            return self.integrator.a0.copy()
        if self.accel:
            a1 = v1.copy()
            a1.axpy(-1.0, v)
            a1.scale(1.0 / h)
            return a1
        return None

    def _advance(self, state, n0: int, n1: int, p):
        """The state of step n1 recomputed from ``state`` of step n0 (the adjoint's
        checkpoints): the same steps as the first run took, from the same start, so the same
        numbers (alpha restarts from the stored acceleration, exactly as a checkpoint restart)."""
        q0, v0, a0 = state
        q, v = q0.copy(), v0.copy()
        q1, v1 = q.duplicate(), v.duplicate()
        self.integrator.new_run()
        if self.scheme.carries_acceleration:
            self.integrator.forget()
            self.integrator.restore(n0 * self.h, q, v, {"acceleration": a0})
        a1 = None
        for n in range(n0, n1):
            if a1 is not None:
                a1.destroy()
            a1 = self._step(n, q, v, q1, v1, p)
            q1.copy(q)
            v1.copy(v)
        q1.destroy()
        v1.destroy()
        return q, v, a1

    @staticmethod
    def _free_state(state) -> None:
        for x in state:
            if x is not None:
                x.destroy()

    def _observe(self, n, q, obs) -> None:
        if n in self.uses:
            obs[n] = self._apply_B(q)

    def _apply_B(self, x) -> np.ndarray:
        """B x (M, 3) through the observer's observe(x) = X + B x, scaled so that subtracting X
        loses no digits when x is tiny (a tangent dq/dE ~ 1e-8 next to X ~ 0.3 would keep only
        ~8 digits)."""
        size = x.norm(PETSc.NormType.INFINITY)
        if size == 0.0:
            return np.zeros_like(self.reference)
        y = x.copy()
        y.scale(1.0 / size)
        out = (self.observer.observe(y) - self.reference) * size
        y.destroy()
        return out

    def _frames(self, obs) -> np.ndarray:
        """(K, M, 3) positions (or accelerations) from the observed steps."""
        ref = self.reference
        out = np.repeat(ref[None], len(self.frame_times), axis=0)
        if self.accel:
            out[:] = 0.0
        for n, uses in self.uses.items():
            for k, w in uses:
                out[k] += w * obs[n]
        return out

    #: whether :meth:`simulate` keeps the chord's factors across steps (False: every step
    #: factors its own, as ``petsoft simulate`` does)
    keeps_factors = True
    #: whether :meth:`jacobian`'s tangent solves keep a factorisation across steps (GMRES on
    #: the exact step Jacobian, preconditioned by an earlier step's factors,
    #: :class:`~petsoft.solvers.lagged_factors.LaggedFactors`) where their solver is the
    #: default direct one; False: every step factors its own Jacobian
    lags_factors = True

    @_collects_garbage
    def simulate(self, p) -> np.ndarray:
        """Marker positions (K, M, 3) at the frame times (identical on every rank).

        The steps keep their chord's factorisation for later steps
        (:meth:`~petsoft.solvers.borrowed_chord.ChordBorrower.keep_factors`; unless
        :attr:`keeps_factors` is False): a run that is neither differentiated nor checkpointed
        need not factor at every step."""
        # (both integrators are ChordBorrowers)
        keep = self.keeps_factors
        if keep:
            self.integrator.keep_factors(True)
        try:
            states, sim = self._run(p, store=False)
        finally:
            if keep:
                self.integrator.keep_factors(False)
        self._free(states)
        return sim

    # -- shared pieces of the derivative ----------------------------------------------------------
    def _free(self, states) -> None:
        for st in states:
            for x in st:
                if x is not None:
                    x.destroy()

    def _solver(self, lag: bool = False):
        """The KSP of the sensitivity/adjoint solves on ``self.J``; with ``lag``, where it is
        the default direct solve (not chosen by options or the experiment's ``[petsc]``), a
        :class:`~petsoft.solvers.lagged_factors.LaggedFactors` on it (its ``.ksp``)."""
        ksp = PETSc.KSP().create(comm=self.comm)
        ksp.setOptionsPrefix(GRAD_PREFIX)
        # with the options pushed: the experiment's [petsc] choice of solver replaces the
        # default whole
        with self.grad_options.pushed():
            self.system.linear_defaults(ksp)
            ksp.setFromOptions()
            chosen = solver_chosen(ksp)
            symmetric_factorisation(ksp, self.J)
        ksp.setOperators(self.J)
        if lag and is_direct(ksp) and not chosen:
            return LaggedFactors(ksp)
        return ksp

    def _solve(self, ksp, rhs, out) -> None:
        # (with the options pushed: PETSc reads some when the solve sets the factors up)
        with self.grad_options.pushed():
            ksp.solve(rhs, out)
        check_converged(ksp.last_solver if isinstance(ksp, LaggedFactors) else ksp,
                        f"{self.experiment.source}: a sensitivity/adjoint linear solve",
                        hint=f"try -{GRAD_PREFIX}pc_type lu")

    def _branch(self):
        """The system's viscoelastic branch when it is on or tracked, else None."""
        branch = self.system.viscoelastic
        return branch if branch is not None and branch.stepping else None

    def _derivatives(self, q, v, a):
        """d r/d p of the system at (q, v, a) (the initial state's): ``.vectors``,
        ``.contract``."""
        return parameter_derivatives(self.system, q, v, a, size=self.cell_size)

    # -- forward sensitivities --------------------------------------------------------------------
    @_collects_garbage
    def jacobian(self, p, watch=None):
        """(sim (K, M, 3), dsim/dp (K, M, 3, P)) by forward sensitivities (one run).

        ``watch(n, state, dq)``, optional, is called with every step's state (q, v, a or None)
        and displacement tangents dq_j (P vectors), from n = 0 (the initial state): the run's
        own vectors, to copy what is kept (e.g. a reduced model's snapshots,
        :mod:`petsoft.diagnosis.reduced_trials`)."""
        self._refuse_derivatives(p, sensitivities=True)
        s, P = self.system, len(self.names)
        K_frames = len(self.frame_times)
        nm = len(self.reference)
        dsim = np.zeros((K_frames, nm, 3, P))
        tangents = {"q": [s.create_vec() for _ in range(P)],
                    "v": [s.create_vec() for _ in range(P)],
                    "a": [s.create_vec() for _ in range(P)] if self.has_a else None}
        for x in tangents["q"] + tangents["v"]:
            x.zeroEntries()
        # the tangent solves: on factors kept across steps (LaggedFactors) unless
        # lags_factors is off or the solver is not the default direct one
        solver = self._solver(lag=self.lags_factors)
        lagged = solver if isinstance(solver, LaggedFactors) else None
        ksp = solver.ksp if lagged is not None else solver

        def solve(rhs, out):
            self._solve(solver, rhs, out)

        # with a viscoelastic branch (be, alpha): z is one more state (dz0 = dq0: z0 = q0)
        tangents["z"] = ([s.create_vec() for _ in range(P)]
                         if self.scheme.branch_sensitivities else None)

        def observe_tangents(n):
            for k, w in self.uses.get(n, []):
                for j in range(P):
                    x = tangents["a" if self.accel else "q"][j]
                    dsim[k, :, :, j] += w * self._apply_B(x)

        started = []
        failed_chords = [0]

        def on_step(n, st0, st1):
            if not started:
                self._initial_tangents(st0, tangents)
                observe_tangents(0)
                if watch is not None:
                    watch(0, st0, tangents["q"])
                started.append(True)
            steps = self.step_derivatives
            lin = steps.linearize(n, st0, st1, self.J)
            ksp.setOperators(self.J)
            if lagged is not None:
                if self.integrator.borrowed_failed:
                    # the step's chord failed on the kept factors (its own solver solved it):
                    # renewed here, or the next steps' chords would fail on them too
                    lagged.renew()
                    failed_chords[0] += 1
                with self.grad_options.pushed():
                    lagged.operator_changed()
            Rp = self._residual_derivatives(lin.deriv, st1[0])
            rhs, tmp = s.create_vec(), s.create_vec()
            for j in range(P):
                steps.tangent_step(lin, Rp[j], tangents["q"][j], tangents["v"][j],
                                   tangents["a"][j] if tangents["a"] is not None else None,
                                   tangents["z"][j] if tangents["z"] is not None else None,
                                   solve, rhs, tmp, st1[0], self.names[j])
            for x in Rp + [rhs, tmp]:
                x.destroy()
            lin.free()
            observe_tangents(n + 1)
            if watch is not None:
                watch(n + 1, st1, tangents["q"])
            if lend:
                # the next step's Newton chord iterates on these factors (borrowed_chord)
                self.integrator.borrow_chord(lagged.factors if lagged is not None else ksp)

        # (not to si: its one Newton step is the method, not a solve to convergence)
        lend = (not self.scheme.one_newton_step
                and (lagged is not None or is_direct(ksp)))
        try:
            states, sim = self._run(p, store=False, on_step=on_step)
        finally:
            if lend:
                self.integrator.borrow_chord(None)
        self._free(states)
        if lagged is not None:
            self.stats["tangent_solves"] = {**lagged.stats(), "failed_chords": failed_chords[0]}
            lagged.destroy()
        ksp.destroy()
        for x in tangents["q"] + tangents["v"] + (tangents["a"] or []) + (tangents["z"] or []):
            x.destroy()
        return sim, dsim

    def _split_names(self) -> tuple[list[int], list[int]]:
        """(indices of the viscoelastic branch's parameters, of the others)."""
        visco = [j for j, n in enumerate(self.names) if n in VISCOELASTIC]
        return visco, [j for j in range(len(self.names)) if j not in visco]

    def _residual_derivatives(self, deriv, q1) -> list:
        """R_p of every parameter (new vectors) at a step's linearisation: ``deriv``'s, the
        branch's own for its parameters (be and alpha only: _refuse_derivatives; the branch is
        tracked) at the step's end ``q1``."""
        visco, others = self._split_names()
        Rp = [None] * len(self.names)
        for j, r in zip(others, deriv.vectors([self.names[j] for j in others]), strict=True):
            Rp[j] = r
        branch = self._branch() if self.scheme.branch_sensitivities else None
        for j in visco:
            Rp[j] = branch.residual_derivative(self.names[j], q1, self.system.create_vec())
        return Rp

    def _initial_tangents(self, state0, tangents) -> None:
        """The tangents of the initial state (q0, v0, a0), in place: dq0 of a static start,
        dz0 = dq0, da0 of the consistent acceleration."""
        s = self.system
        visco, others = self._split_names()
        q0, v0, a0 = state0
        if self.static:
            # K(q0) dq0 = -P d r_static/dp
            sksp, sderiv = self._static_setup(q0)
            # (the relaxed branch does not act on the static equilibrium: dq0 = 0 for its
            # parameters)
            for j, r in zip(others, sderiv.vectors([self.names[j] for j in others]),
                            strict=True):
                r.scale(-1.0)
                s.zero_prescribed(r)
                self._solve(sksp, r, tangents["q"][j])
                r.destroy()
            sksp.destroy()
        if tangents["z"] is not None:
            for dq, dz in zip(tangents["q"], tangents["z"], strict=True):
                dq.copy(dz)
        if self.has_a:
            # M da0 = -P (R_p + K(q0) dq0)   (self.J holds K(q0) when static); the relaxed
            # branch's force g K0 (q0 - z0) and its tangents are zero at t = 0 (dz0 = dq0)
            deriv = self._derivatives(q0, v0, a0)
            mksp = mass_solver(s)
            for j in visco:
                tangents["a"][j].zeroEntries()
            for j, r in zip(others, deriv.vectors([self.names[j] for j in others]),
                            strict=True):
                if self.static:
                    r.axpy(1.0, self.J * tangents["q"][j])
                r.scale(-1.0)
                s.zero_prescribed(r)
                mksp.solve(r, tangents["a"][j])
                r.destroy()
            mksp.destroy()

    # -- discrete adjoint -------------------------------------------------------------------------
    @_collects_garbage
    def gradient(self, p, dphi):
        """(value, d value/d p (P,)) of value = phi(simulate(p)) by the discrete adjoint.

        ``dphi(sim) -> (value, d value/d sim (K, M, 3))`` is called once, identically on every
        rank. One forward run (trajectory kept in memory) and one backward sweep.
        """
        value, grad, _ = self._adjoint(p, dphi, cell_map=False)
        return value, grad

    @_collects_garbage
    def cell_gradient(self, p, dphi):
        """The gradient and the per-cell sensitivity maps, from the same adjoint sweep.

        Returns
        -------
        (float, ndarray (P,), dict)
            value, its gradient, and ``{"youngs_modulus": d value / d E_cell, "density":
            d value / d rho_cell}``, each (ncells,) in file numbering on every rank (the maps
            cost one contraction per step).
        """
        if self.system.parameter_derivatives is None:
            raise ExperimentError("per-cell sensitivity maps need a continuum (FEM) system")
        value, grad, local = self._adjoint(p, dphi, cell_map=True)
        dm = self.system.dmesh
        parts = dm.comm.tompi4py().allgather((dm.cell_ids, local))
        out = np.zeros((len(dm.mesh.tets), 2))
        for ids, vals in parts:
            out[ids] = vals
        return value, grad, {"youngs_modulus": out[:, 0], "density": out[:, 1]}

    def _adjoint(self, p, dphi, cell_map: bool):
        self._refuse_derivatives(p)
        s, P = self.system, len(self.names)
        N = self.nsteps
        snapshots = self._snapshots(N)
        stats = SweepStats()
        if snapshots is None:
            states, sim = self._run(p, store=True)
            stats.hold(len(states))
            start, stored = states[0], None
        else:
            stored, sim = self._run(p, store=False, keep=set(spine(N, snapshots)))
            stats.hold(len(stored))
            start = stored.pop(0)
        value, wsim = dphi(sim)
        wsim = np.asarray(wsim, dtype=float).reshape(sim.shape)
        grad = np.zeros(P)
        cells = np.zeros((len(s.dmesh.cells), 2)) if cell_map else None

        def contract(deriv, mu):
            nonlocal grad
            grad -= deriv.contract(self.names, mu)
            if cells is not None:
                cells[:] -= deriv.cell_sensitivity(mu)

        loads = {}
        for n, uses in self.uses.items():
            w = sum(wt * wsim[k] for k, wt in uses)
            loads[n] = self.observer.adjoint(w)
        gq, gv = s.create_vec(), s.create_vec()
        gq.zeroEntries()
        gv.zeroEntries()
        ga = None
        if self.has_a:
            ga = s.create_vec()
            ga.zeroEntries()
        if N in loads:
            (ga if self.accel else gq).axpy(1.0, loads.pop(N))
        ksp = self._solver()
        mu, rhs, tmp = s.create_vec(), s.create_vec(), s.create_vec()

        def solve(rhs, out):
            self._solve(ksp, rhs, out)

        def backward(n, st0, st1) -> None:
            """The adjoint of step n -> n+1 (states n and n+1): (gq, gv, ga) of n+1 -> of n."""
            nonlocal gq, gv, ga
            if self._speaks:
                beat(lambda: f"still computing the gradient: adjoint step {N - n} of {N}")
            lin = self.step_derivatives.linearize(n, st0, st1, self.J)
            ksp.setOperators(self.J)
            gq, gv, ga = self.step_derivatives.adjoint_step(lin, gq, gv, ga, solve, contract, mu,
                                                            rhs, tmp)
            lin.free()
            if n in loads:
                (ga if self.accel else gq).axpy(1.0, loads.pop(n))

        if stored is None:
            for n in range(N - 1, -1, -1):
                backward(n, states[n], states[n + 1])
        else:
            reverse_sweep(N, snapshots, start, stored,
                          lambda state, n0, n1: self._advance(state, n0, n1, p), backward,
                          self._free_state, stats)
        self.stats["adjoint"] = {"steps": N, "snapshots": snapshots,
                                 "recomputed_steps": stats.recomputed_steps,
                                 "peak_states": stats.peak_states,
                                 "peak_bytes": stats.peak_states * self._state_bytes()}
        self._initial_adjoint(start, gq, ga, mu, tmp, contract)
        for x in (gq, gv, ga, mu, rhs, tmp):
            if x is not None:
                x.destroy()
        ksp.destroy()
        if stored is None:
            self._free(states)
        else:
            self._free_state(start)
        return float(value), grad, cells

    def _initial_adjoint(self, state0, gq, ga, mu, tmp, contract) -> None:
        """The adjoint sweep's end: the initial state's dependence on the parameters (the
        consistent acceleration's, a static start's) contracted; ``gq``, ``ga`` the adjoints of
        q0 and a0 (used up)."""
        s = self.system
        q0, v0, a0 = state0
        if self.static:
            sksp, sderiv = self._static_setup(q0)       # self.J = K(q0)
        if self.has_a:
            # M da0 = -P (R_p(t0) + K(q0) dq0): grad -= R_p(t0) . nu, gq0 -= K(q0) nu,
            # nu = M^-1 P ga0
            mksp = mass_solver(s)
            s.zero_prescribed(ga)
            mksp.solve(ga, mu)
            mksp.destroy()
            contract(self._derivatives(q0, v0, a0), mu)
            if self.static:
                self.J.mult(mu, tmp)
                gq.axpy(-1.0, tmp)
        if self.static:
            # K(q0) dq0 = -P d r_static/dp: grad -= d r_static/dp . K^-1 P gq0
            s.zero_prescribed(gq)
            self._solve(sksp, gq, mu)
            contract(sderiv, mu)
            sksp.destroy()

    def _state_bytes(self) -> int:
        """Bytes of one stored state on this rank (q, v and, if carried, a)."""
        local = self.system.create_vec()
        size = local.getLocalSize()
        local.destroy()
        return (3 if self.has_a else 2) * size * 8

    def _snapshots(self, steps: int) -> int | None:
        """How many states the adjoint may hold (None: all N + 1, the trajectory fits).

        ``self.checkpoints`` when set (0 = decide); otherwise all while (N + 1) states fit
        :data:`ADJOINT_MEMORY` bytes on this rank, else as many as fit (at least 2). Every
        rank takes the same decision (the largest state counts).
        """
        if self.checkpoints:
            return None if self.checkpoints >= steps + 1 else max(int(self.checkpoints), 2)
        fit = ADJOINT_MEMORY // max(self._state_bytes(), 1)
        fit = self.comm.tompi4py().allreduce(int(fit), op=MPI.MIN)
        return None if fit >= steps + 1 else max(int(fit), 2)

    # -- finite differences -----------------------------------------------------------------------
    def fd_jacobian(self, p, rel_step: float = 1e-6) -> np.ndarray:
        """dsim/dp (K, M, 3, P) by central differences, step rel_step * max(|p_j|, 1)."""
        p = np.asarray(p, dtype=float)
        cols = []
        for j in range(len(p)):
            e = rel_step * max(abs(p[j]), 1.0)
            hi, lo = p.copy(), p.copy()
            hi[j] += e
            lo[j] -= e
            cols.append((self.simulate(hi) - self.simulate(lo)) / (2.0 * e))
        self._set(p)
        return np.stack(cols, axis=-1)

    def destroy(self) -> None:
        self.integrator.destroy()
        self.J.destroy()
        if self._own_observer:
            self.observer.destroy()

