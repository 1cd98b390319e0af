"""The derivatives of the backward Euler and semi-implicit steps (:mod:`petsoft.dynamics.implicit`).

Per step with h, Jacobian J and parameter derivative R_p = d r/d p of the step equation:

* BE (full Newton: J at the step's end q1): J dq1 = -R_p + M (dq0/h^2 + dv0/h) + D dq0/h,
  dv1 = (dq1 - dq0)/h. With the viscoelastic branch (c = g/(1 + h/tau), its force c K0 (q1 - z0)
  in the residual and c K0 in J) the right-hand side gains c K0 dz0 and z's tangent steps by
  :meth:`~petsoft.physics.viscoelastic.MaxwellBranch.tangent_update`.
* SI, q1 = qp - J(qp)^-1 R(qp), qp = q0 + h v0: J(qp) dq1 = -S_p - T_w (dq0 + h dv0)
  + M (dq0/h^2 + dv0/h) + D dq0/h, with w = q1 - qp, S_p = R_p + d/dp [K(qp) w] and
  T_w = d/deps K(qp + eps w), a third derivative of W: zero for the linear material, else the
  central difference (K(qp + eps w) - K(qp - eps w)) / (2 eps) with eps |w|_inf = SI_EPS x the
  length scale (exact to round-off for StVK, O(1e-8) relative for corotated and neo-Hookean).
  Measured (tests/test_sensitivity.py, corotated bar): the SI gradient's Taylor remainder falls
  as eps^2 from eps = 2e-2 to ~5e-6 (relative) and flattens at the misfit's round-off (~1e-19
  absolute, eps ~ 1e-7) before the difference's error shows; without T_w it falls only as eps.
  Nonlinear velocity terms, linearised at u = (qp - q0)/h, add their second derivative along w.

Where the marker accelerations are observed, a1 = (v1 - v0)/h is one more output of the step:
da1 = (dv1 - dv0)/h, and its adjoint joins v1's and v0's.

The adjoint step is the transpose: with g = gq1 + gv1/h, mu = J^-1 g (J symmetric),
gq0 = -gv1/h + M mu/h^2 + D mu/h (- T_w mu), gv0 = M mu/h (- h T_w mu), and R_p . mu
contracted into the gradient.
"""

from __future__ import annotations

from petsc4py import PETSc

from petsoft.dynamics.interfaces import length_scale
from petsoft.dynamics.step_derivatives import (
    SI_EPS,
    Contract,
    Linearization,
    Solve,
    damping_second,
    damping_tangent,
    parameter_derivatives,
    velocity_state,
)


class ImplicitStepDerivatives:
    """The tangent and adjoint steps of ``be`` or ``si`` (:class:`StepDerivatives`).

    Parameters
    ----------
    system : System
    h : float
        The step.
    one_newton_step : bool
        Semi-implicit (one Newton step from the predictor) instead of backward Euler.
    observe_acceleration : bool
        The tangent and adjoint carry a1 = (v1 - v0)/h.
    """

    carries_acceleration = False

    def __init__(self, system, h: float, one_newton_step: bool,
                 observe_acceleration: bool = False):
        self.system, self.h = system, float(h)
        self.si = one_newton_step
        self.accel = observe_acceleration
        # a length scale for the SI third-derivative difference: mean cell size or spring length
        self.cell_size = length_scale(system)
        # the SI third-derivative term vanishes for the linear law (K constant)
        elastic = system.elastic
        self.linear_material = elastic is not None and all(g.model == "linear"
                                                           for g in elastic.groups)

    def _branch(self):
        """The system's viscoelastic branch when it is on or tracked (BE only), else None."""
        branch = self.system.viscoelastic
        if self.si or branch is None or not branch.stepping:
            return None
        return branch

    # -- the step's linearisation -----------------------------------------------------------------
    def linearize(self, n: int, st0, st1, J: PETSc.Mat) -> Linearization:
        s, h = self.system, self.h
        (q0, v0, _), (q1, v1, _) = st0, st1
        if not self.si:
            # full Newton: the Jacobian at the step's end
            acc = v1.copy()
            acc.axpy(-1.0, v0)
            acc.scale(1.0 / h)
            # the viscoelastic branch (forward sensitivities only; the adjoint refuses it):
            # c K0 (q1 - z0) with c = g/(1 + h/tau), z0 the step's start
            branch, c, k0x = self._branch(), 0.0, None
            if branch is not None:
                c = branch.jacobian_coefficient()
                k0x = q1.copy()
                k0x.axpy(-1.0, branch.step_start)
                k0x.scale(c)
            v = v1.copy()
            velocity_state(s, v)
            s.assemble_combination(q1, 1.0 / h**2 + s.alpha / h, 1.0, s.beta / h + c, J,
                                   velocity=1.0 / h, reuse=True)
            deriv = parameter_derivatives(s, q1, v1, acc, k0x=k0x, size=self.cell_size)
            acc.destroy()
            if k0x is not None:
                k0x.destroy()
            return Linearization(J, deriv, v)
        # one Newton step from the predictor: the very matrix of the SI step
        qp = q0.copy()
        qp.axpy(h, v0)
        s.apply_prescribed(qp, (n + 1) * h)
        w = q1.copy()
        w.axpy(-1.0, qp)
        acc = v1.copy()
        acc.axpy(-1.0, v0)
        acc.scale(1.0 / h)
        # the SI residual evaluates the damping at u = (qp - q0)/h (v0, with the supports'
        # velocity) and its Jacobian linearises the velocity terms there
        u = qp.copy()
        u.axpy(-1.0, q0)
        u.scale(1.0 / h)
        velocity_state(s, u)
        s.assemble_combination(qp, 1.0 / h**2 + s.alpha / h, 1.0, s.beta / h, J,
                               velocity=1.0 / h, reuse=True)
        deriv = parameter_derivatives(s, qp, v1, acc, w, v_lin=u, size=self.cell_size)
        T = self._third(qp, w)
        for x in (acc, qp):
            x.destroy()
        return Linearization(J, deriv, u, w=w, T=T)

    def _third(self, qp, w):
        """T_w = d/deps K(qp + eps w) as a matrix (None when zero: linear material, w = 0)."""
        s = self.system
        wmax = w.norm(PETSc.NormType.INFINITY)
        if self.linear_material or wmax == 0.0:
            return None
        eps = SI_EPS * self.cell_size / wmax
        T, Km = s.create_matrix(), s.create_matrix()
        x = qp.copy()
        x.axpy(eps, w)
        s.assemble_combination(x, 0.0, 1.0, 0.0, T, eliminate=False)
        x.axpy(-2.0 * eps, w)
        s.assemble_combination(x, 0.0, 1.0, 0.0, Km, eliminate=False)
        T.axpy(-1.0, Km)
        T.scale(0.5 / eps)
        x.destroy()
        Km.destroy()
        return T

    # -- forward sensitivities --------------------------------------------------------------------
    def tangent_step(self, lin: Linearization, Rp, dq0, dv0, da0, dz0, solve: Solve, rhs, tmp,
                     q1, name: str) -> None:
        s, h = self.system, self.h
        branch = self._branch() if dz0 is not None else None
        # rhs = -R_p + M (dq0/h^2 + dv0/h) + D dq0/h (- T_w (dq0 + h dv0) for SI)
        tmp.waxpy(h, dv0, dq0)
        s.M.mult(tmp, rhs)
        rhs.scale(1.0 / h**2)
        rhs.axpy(-1.0, Rp)
        rhs.axpy(1.0 / h, damping_tangent(s, lin.v, dq0, tmp))
        if damping_second(s, lin, dv0, tmp) is not None:
            # SI: the Jacobian's velocity terms at u = v0 move with dv0
            rhs.axpy(-1.0 / h, tmp)
        if lin.T is not None:
            tmp.waxpy(h, dv0, dq0)
            dqp = tmp.copy()
            lin.T.mult(dqp, tmp)
            rhs.axpy(-1.0, tmp)
            dqp.destroy()
        if branch is not None:
            # R has -c K0 z0: its tangent moves to the right-hand side as + c K0 dz0
            s.K0_matrix().mult(dz0, tmp)
            rhs.axpy(branch.jacobian_coefficient(), tmp)
        s.zero_prescribed(rhs)
        dq1 = tmp
        solve(rhs, dq1)
        if branch is not None:
            branch.tangent_update(dz0, dq1, q1, name)
        if self.accel:
            dv0.copy(da0)
        # dv1 = (dq1 - dq0)/h
        dv0.waxpy(-1.0, dq0, dq1)
        dv0.scale(1.0 / h)
        dq1.copy(dq0)
        if self.accel:
            # da1 = (dv1 - dv0)/h
            da0.aypx(-1.0, dv0)
            da0.scale(1.0 / h)

    # -- the discrete adjoint ---------------------------------------------------------------------
    def adjoint_step(self, lin: Linearization, gq, gv, ga, solve: Solve, contract: Contract,
                     mu, rhs, tmp) -> tuple:
        s, h = self.system, self.h
        if self.accel:
            # a1 = (v1 - v0)/h: its adjoint joins v1's (and v0's below)
            gv.axpy(1.0 / h, ga)
        # g = gq1 + gv1/h; mu = J^-1 P g
        rhs.waxpy(1.0 / h, gv, gq)
        s.zero_prescribed(rhs)
        solve(rhs, mu)
        contract(lin.deriv, mu)
        # gq0 = -gv1/h + M mu/h^2 + D mu/h (- T_w mu), gv0 = M mu/h (- h T_w mu)
        s.M.mult(mu, tmp)
        gq0 = tmp.copy()
        gq0.scale(1.0 / h**2)
        gq0.axpy(-1.0 / h, gv)
        tmp.copy(gv)
        gv.scale(1.0 / h)
        gq0.axpy(1.0 / h, damping_tangent(s, lin.v, mu, tmp))
        if damping_second(s, lin, mu, tmp) is not None:
            gv.axpy(-1.0 / h, tmp)      # the transpose of the tangent's term (symmetric)
        if lin.T is not None:
            lin.T.mult(mu, tmp)
            gq0.axpy(-1.0, tmp)
            gv.axpy(-h, tmp)
        gq0.copy(gq)
        gq0.destroy()
        if self.accel:
            gv.axpy(-1.0 / h, ga)
            ga.zeroEntries()
        return gq, gv, ga
