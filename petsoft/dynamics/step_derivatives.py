"""What a time step's derivatives are: the protocol each differentiable scheme implements.

Calibration differentiates the *discrete* time stepping (:mod:`petsoft.calibration.forward`).
Every scheme with gradients (:attr:`petsoft.dynamics.integrators.Scheme.derivatives`) carries,
beside its step, the step's linearisation and its two uses:

* :meth:`StepDerivatives.linearize`: the step's Jacobian J (into a matrix the caller owns),
  assembled at the state the step's equation is linearised at, and the parameter derivatives
  R_p = d r/d p of the step equation there (:class:`Linearization`);
* :meth:`StepDerivatives.tangent_step`: one forward-sensitivity step of one parameter, in place
  (the tangent of the step's start -> of its end);
* :meth:`StepDerivatives.adjoint_step`: its transpose (the adjoint of the step's end -> of its
  start), contracting R_p with the step's multiplier.

The caller owns the linear solver of J (a callable ``solve(rhs, out)``), the trajectory (stored
or recomputed) and the observation; the schemes own the formulas. The implementations are
:mod:`petsoft.dynamics.implicit_derivatives` (backward Euler, semi-implicit) and
:mod:`petsoft.dynamics.alpha_derivatives` (generalized-alpha).

Also here, shared by the schemes: the damping's tangent (velocity terms linearised at the step's
velocity), the parameter derivatives of a system (:func:`parameter_derivatives`, with a generic
fallback for systems offering only ``residual_parameter_derivatives``) and the solver of the
consistent mass (:func:`mass_solver`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from petsc4py import PETSc

#: Relative size of the central differences along a step's w (the SI third derivative, the
#: generic parameter derivatives): eps |w|_inf = this x the system's length scale.
SI_EPS = 1e-4

#: ``solve(rhs, out)``: out = J^-1 rhs with the caller's solver of the step's Jacobian
Solve = Callable[[PETSc.Vec, PETSc.Vec], None]
#: ``contract(deriv, mu)``: the caller's use of R_p . mu (gradient, cell maps)
Contract = Callable[[Any, PETSc.Vec], None]


class Linearization:
    """One step's linearisation: J (the caller's matrix, assembled), the parameter derivatives
    and what the scheme's tangent and adjoint reuse.

    Attributes
    ----------
    J : PETSc.Mat
        The step's Jacobian (eliminated supports), the caller's matrix.
    deriv : object
        The parameter derivatives R_p (``.vectors(names)``, ``.contract(names, mu)``,
        ``.cell_sensitivity(mu)`` for a continuum).
    v : PETSc.Vec
        The velocity the step's velocity terms are linearised at.
    w : PETSc.Vec or None
        SI: q1 - qp (the step's Newton update).
    T : PETSc.Mat or None
        SI: the third-derivative term T_w (None when zero).
    coefficients : dict
        Scheme-specific scalars (alpha: the mass and damping coefficients of J).
    """

    def __init__(self, J, deriv, v, w=None, T=None, **coefficients):
        self.J, self.deriv, self.v, self.w, self.T = J, deriv, v, w, T
        self.coefficients = coefficients

    def free(self) -> None:
        """Destroy the vectors and matrices the linearisation made (not J: the caller's)."""
        for x in (self.v, self.w, self.T):
            if x is not None:
                x.destroy()
        self.v = self.w = self.T = None


class StepDerivatives(Protocol):
    """The derivatives of one scheme's step (see the module docstring).

    ``states`` are (q, v, a or None) of steps n and n + 1; the tangent and adjoint vectors
    are (q, v, a, z) of one parameter, a None where the scheme does not carry it.
    """

    #: the scheme carries the acceleration (its tangent and adjoint have an ``a`` part)
    carries_acceleration: bool

    def linearize(self, n: int, st0, st1, J: PETSc.Mat) -> Linearization:
        """Assemble step n -> n+1's Jacobian into J; its parameter derivatives."""
        ...

    def tangent_step(self, lin: Linearization, Rp: PETSc.Vec, dq: PETSc.Vec, dv: PETSc.Vec,
                     da: PETSc.Vec | None, dz: PETSc.Vec | None, solve: Solve,
                     rhs: PETSc.Vec, tmp: PETSc.Vec, q1: PETSc.Vec, name: str) -> None:
        """(dq, dv, da, dz) of step n -> of step n + 1, in place, for parameter ``name``
        whose R_p is ``Rp`` (``q1`` the step's end; ``rhs``, ``tmp`` work vectors)."""
        ...

    def adjoint_step(self, lin: Linearization, gq: PETSc.Vec, gv: PETSc.Vec,
                     ga: PETSc.Vec | None, solve: Solve, contract: Contract, mu: PETSc.Vec,
                     rhs: PETSc.Vec, tmp: PETSc.Vec) -> tuple:
        """The adjoint (gq, gv, ga) of step n + 1 -> of step n (the returned vectors may be
        new ones: the given ones are then destroyed); calls ``contract(lin.deriv, mu)`` with
        the step's multiplier mu."""
        ...


def velocity_state(system, v) -> None:
    """Linearise the system's velocity terms at v in the next Jacobian assembly."""
    setter = system.set_velocity_state
    if setter is not None:
        setter(v)


def damping_tangent(system, v, x, out):
    """out = the damping term linearised at velocity v, applied to x: D x + dG/dv x (drag and
    friction); D x for systems without velocity terms."""
    tangent = system.damping_tangent_apply
    if tangent is None:
        return system.damping_apply(x, out)
    return tangent(v, x, out)


def damping_second(system, lin: Linearization, x, out):
    """out = d/dv [dG/dv x] along the SI step's w at its u (None when zero or not SI)."""
    second = system.damping_second_apply
    terms = system.velocity_terms
    if second is None or terms is None or not terms.nonlinear or lin.w is None:
        return None
    return second(lin.v, lin.w, x, out)


def parameter_derivatives(system, q, v, a, w=None, v_lin=None, k0x=None, size: float = 1.0):
    """d r/d p of ``system`` at (q, v, a) (+ d/dp [K(q) w]; velocity terms linearised at
    v_lin, the SI step's u; + d/dp [K0 k0x], the viscoelastic branch): ``.vectors``,
    ``.contract``. ``size``: the length scale of the generic path's difference along w."""
    if k0x is not None:
        return system.parameter_derivatives(q, v, a, w, k0x, v_lin)
    if system.parameter_derivatives is not None:
        if v_lin is not None:
            return system.parameter_derivatives(q, v, a, w, v_lin=v_lin)
        return system.parameter_derivatives(q, v, a, w)
    return GenericDerivatives(system, q, v, a, w, size, v_lin)


class GenericDerivatives:
    """d r/d p of a system offering only ``residual_parameter_derivatives`` (e.g. mass-spring):
    the w term d/dp [K(q) w] by a central difference of the derivatives in q along w."""

    def __init__(self, system, q, v, a, w, size, v_lin=None):
        self.system = system
        self.q, self.v, self.a = q.copy(), v.copy(), a.copy()
        self.w = w.copy() if w is not None else None
        self.v_lin = v_lin.copy() if v_lin is not None else None
        self.size = size

    def _at(self, names, q):
        s = self.system
        if self.v_lin is not None:
            return s.residual_parameter_derivatives(names, q, self.v, self.a, v_lin=self.v_lin)
        return s.residual_parameter_derivatives(names, q, self.v, self.a)

    def vectors(self, names) -> list:
        out = self._at(names, self.q)
        wmax = self.w.norm(PETSc.NormType.INFINITY) if self.w is not None else 0.0
        if wmax > 0.0:
            eps = SI_EPS * self.size / wmax
            x = self.q.copy()
            x.axpy(eps, self.w)
            plus = self._at(names, x)
            x.axpy(-2.0 * eps, self.w)
            minus = self._at(names, x)
            for o, hi, lo in zip(out, plus, minus, strict=True):
                hi.axpy(-1.0, lo)
                o.axpy(0.5 / eps, hi)
                hi.destroy()
                lo.destroy()
            x.destroy()
        return out

    def contract(self, names, mu) -> np.ndarray:
        vecs = self.vectors(names)
        result = np.array([vec.dot(mu) for vec in vecs])
        for vec in vecs:
            vec.destroy()
        return result


def mass_solver(system) -> PETSc.KSP:
    """CG + Jacobi at rtol 1e-14 on the eliminated mass matrix (the consistent acceleration
    and its derivative); the caller destroys it."""
    M = system.M.copy()
    if system.dirichlet is not None:
        system.dirichlet.eliminate(M)
    ksp = PETSc.KSP().create(comm=system.comm)
    ksp.setOperators(M)
    ksp.setType(PETSc.KSP.Type.CG)
    ksp.getPC().setType(PETSc.PC.Type.JACOBI)
    ksp.setTolerances(rtol=1e-14, atol=1e-50, max_it=10000)
    M.destroy()
    return ksp
