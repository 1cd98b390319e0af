"""The time integrators: one registry of the schemes and what each can do.

The experiment file names a scheme by a string (``[time] integrator``; the vocabulary is
:data:`petsoft.experiment.INTEGRATORS`, the public format). Below the reader, code asks this
registry about the scheme -- how to build it, its order, whether calibration has gradients
through it, how the viscoelastic branch steps with it -- instead of comparing names.

The builders import their integrator module when called: the integrator modules themselves read
this registry (a Maxwell branch's rule), so importing them here would be a cycle.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from petsoft.errors import ExperimentError
from petsoft.physics.viscoelastic import MaxwellRule
from petsoft.solvers.options import SolverOptions


@dataclass(frozen=True)
class IntegratorOptions:
    """The run options some schemes take (the ``petsoft simulate`` flags), and the
    experiment's ``[petsc]`` table, which each builder hands its integrator's solvers under
    their prefixes."""

    solver: str = "snes"
    explicit_scheme: str = "verlet"
    alpha_radius: float = 0.5
    alpha_backend: str = "petsoft"
    imex_slow_modes: int = 6
    petsc: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Scheme:
    """One time integrator.

    Attributes
    ----------
    name : str
        Its name in ``[time] integrator``.
    description : str
    order : int
        Order of accuracy (for smooth motion).
    implicit : bool
        Solves a (non)linear system per step.
    derivatives : callable(system, integrator, h, observe_acceleration) -> StepDerivatives, or None
        The tangent and adjoint steps beside the scheme's step
        (:class:`~petsoft.dynamics.step_derivatives.StepDerivatives`): calibration's forward
        model differentiates through the scheme (sensitivities and adjoint); None: it does not.
    maxwell : MaxwellRule or None
        How the viscoelastic branch's internal variable steps with it; None: the scheme does
        not include the branch.
    build : callable(system, IntegratorOptions) -> integrator
    one_newton_step : bool
        Takes one Newton step per time step instead of solving to convergence (semi-implicit).
    force_at : {"end", "midpoint", "trapezoidal", "alpha"}
        Where an implicit step evaluates the internal force: at the step's end, at the
        midpoint (a discrete gradient), averaged over both ends, or at t_{n+1-alpha_f}.
    carries_acceleration : bool
        The acceleration is part of the state carried from step to step (generalized-alpha).
    branch_sensitivities : bool
        Calibration's forward sensitivities include the viscoelastic branch's internal variable.
    minimization : bool
        A step is the minimum of an incremental potential (``--solver tao``, and the
        local/global solver, apply).
    continuum_only : bool
        Needs a continuum's reference stiffness (not for ``[springs]`` models).
    ts_backend : bool
        Also has a PETSc TS implementation (``--alpha-backend ts``; without the viscoelastic
        branch).
    """

    name: str
    description: str
    order: int
    implicit: bool
    derivatives: Callable | None
    maxwell: MaxwellRule | None
    build: Callable
    one_newton_step: bool = False
    force_at: str = "end"
    carries_acceleration: bool = False
    branch_sensitivities: bool = False
    minimization: bool = False
    continuum_only: bool = False
    ts_backend: bool = False

    @property
    def gradients(self) -> bool:
        """Calibration's forward model differentiates through it (sensitivities and adjoint)."""
        return self.derivatives is not None


def _implicit(name: str):
    def build(system, options: IntegratorOptions):
        from petsoft.dynamics.implicit import ImplicitIntegrator

        return ImplicitIntegrator(system, name, solver=options.solver,
                                  options=SolverOptions("", options.petsc))
    return build


def _implicit_derivatives(one_newton_step: bool):
    def build(system, integrator, h: float, observe_acceleration: bool):
        from petsoft.dynamics.implicit_derivatives import ImplicitStepDerivatives

        return ImplicitStepDerivatives(system, h, one_newton_step, observe_acceleration)
    return build


def _alpha_derivatives(system, integrator, h: float, observe_acceleration: bool):
    from petsoft.dynamics.alpha_derivatives import AlphaStepDerivatives

    # (the accelerations are the scheme's own: observing them adds nothing to its tangent)
    return AlphaStepDerivatives(system, h, integrator.radius,
                                branch_sensitivities=SCHEMES["alpha"].branch_sensitivities)


def _alpha(system, options: IntegratorOptions):
    from petsoft.dynamics.alpha import AlphaTSIntegrator, GeneralizedAlpha

    own = SolverOptions("", options.petsc)
    if options.alpha_backend == "ts":
        return AlphaTSIntegrator(system, options.alpha_radius, options=own)
    return GeneralizedAlpha(system, options.alpha_radius, options=own)


def _explicit(system, options: IntegratorOptions):
    from petsoft.dynamics.explicit import ExplicitIntegrator

    return ExplicitIntegrator(system, options.explicit_scheme,
                              options=SolverOptions("stability_", options.petsc))


def _ere(system, options: IntegratorOptions):
    from petsoft.dynamics.ere import EREIntegrator

    return EREIntegrator(system, options=SolverOptions("ere_", options.petsc))


def _imex(system, options: IntegratorOptions):
    from petsoft.dynamics.imex import ModalImexIntegrator

    return ModalImexIntegrator(system, slow_modes=options.imex_slow_modes, fast="be",
                               options=SolverOptions("", options.petsc))


#: Every scheme, by its name in the experiment file.
SCHEMES: dict[str, Scheme] = {s.name: s for s in (
    Scheme("be", "backward Euler, full Newton", 1, True, _implicit_derivatives(False),
           MaxwellRule.BACKWARD_EULER, _implicit("be"),
           branch_sensitivities=True, minimization=True),
    Scheme("si", "semi-implicit: one Newton step", 1, True, _implicit_derivatives(True),
           MaxwellRule.BACKWARD_EULER, _implicit("si"), one_newton_step=True),
    Scheme("alpha", "generalized-alpha", 2, True, _alpha_derivatives,
           MaxwellRule.GENERALIZED_ALPHA, _alpha, force_at="alpha", carries_acceleration=True,
           branch_sensitivities=True, ts_backend=True),
    Scheme("midpoint", "implicit midpoint with a discrete gradient", 2, True, None,
           MaxwellRule.TRAPEZOIDAL, _implicit("midpoint"), force_at="midpoint"),
    Scheme("trapezoidal", "trapezoidal rule", 2, True, None,
           MaxwellRule.TRAPEZOIDAL, _implicit("trapezoidal"), force_at="trapezoidal"),
    Scheme("ere", "exponential Rosenbrock-Euler", 2, False, None, None, _ere),
    Scheme("explicit", "velocity Verlet (or symplectic Euler), lumped mass", 2, False, None,
           None, _explicit),
    Scheme("imex", "fast/slow modal splitting", 1, True, None, None, _imex,
           continuum_only=True),
)}


def scheme(name: str, where: str = "time.integrator") -> Scheme:
    """The registry entry of ``name``; a clear error naming the valid ones otherwise."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise ExperimentError(f"{where} = {name!r} is unknown; valid: "
                              f"{', '.join(SCHEMES)}") from None


def with_gradients() -> tuple[str, ...]:
    """The schemes calibration differentiates through."""
    return tuple(n for n, s in SCHEMES.items() if s.gradients)


def check_viscoelastic(branch, name: str, where: str = "time.integrator") -> None:
    """Raise (on every rank: the decision is deterministic) when the branch is on and scheme
    ``name`` does not include it."""
    if branch is not None and branch.active and scheme(name, where).maxwell is None:
        supported = [n for n, s in SCHEMES.items() if s.maxwell is not None]
        raise ExperimentError(
            f"{where} = {name!r}: [viscoelastic] ratio = {branch.ratio:g} (a standard linear "
            f"solid) is integrated by {', '.join(supported)} only; choose one of them, or set "
            "[viscoelastic] ratio = 0")
