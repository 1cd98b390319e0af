"""The derivatives of the generalized-alpha step (:class:`petsoft.dynamics.alpha.GeneralizedAlpha`).

The step solves M a_m + grad W(q_f) + D v_f - f(t0 + alpha_f h) = 0 for q1, with
a1 = ca (q1 - q0 - h v0 - h^2 (1/2 - beta) a0), ca = 1/(beta h^2),
v1 = v0 + h ((1 - gamma) a0 + gamma a1), q_f, v_f, a_m the alpha_f / alpha_m blends of the
step's two ends. Its Jacobian J = alpha_m ca M + alpha_f K(q_f) + alpha_f gamma/(beta h) D
(+ the viscoelastic branch's c K0) is assembled at q_f.

Tangent step (one parameter, R_p at the step's linearisation): the tangents of a1, v1, q_f,
v_f, a_m with dq1 = 0 (primed) from (dq0, dv0, da0), then
J dq1 = -R_p - (M da_m' + K(q_f) dq_f' + D dv_f') (with the branch: + K0 (a_q dq0 + a_z dz0),
:meth:`~petsoft.physics.viscoelastic.MaxwellBranch.state_coefficients`), and
da1 = da1' + ca dq1, dv1 = dv1' + h gamma ca dq1. K(q_f) x is read off the assembled J
(J x minus its mass, damping and branch parts, over alpha_f).

The adjoint step is its transpose: adjoints of (q1, v1, a1) -> of (q0, v0, a0), one solve with
J (symmetric) for the multiplier mu, and R_p . mu contracted into the gradient. The adjoint does
not include the branch (the forward model refuses it).
"""

from __future__ import annotations

from petsc4py import PETSc

from petsoft.dynamics.alpha import alpha_parameters
from petsoft.dynamics.interfaces import length_scale
from petsoft.dynamics.step_derivatives import (
    Contract,
    Linearization,
    Solve,
    damping_tangent,
    parameter_derivatives,
    velocity_state,
)


class AlphaStepDerivatives:
    """The tangent and adjoint steps of generalized-alpha (:class:`StepDerivatives`).

    Parameters
    ----------
    system : System
    h : float
        The step.
    radius : float
        The spectral radius at infinity of the integrator differentiated.
    branch_sensitivities : bool
        The tangent includes the viscoelastic branch's internal variable.
    """

    carries_acceleration = True

    def __init__(self, system, h: float, radius: float, branch_sensitivities: bool = True):
        self.system, self.h = system, float(h)
        self.am, self.af, self.gamma, self.nbeta = alpha_parameters(radius)
        self.branch_sensitivities = branch_sensitivities
        self.cell_size = length_scale(system)

    def _branch(self):
        """The system's viscoelastic branch when it is on or tracked, else None."""
        branch = self.system.viscoelastic
        if not self.branch_sensitivities or branch is None or not branch.stepping:
            return None
        return branch

    def linearize(self, n: int, st0, st1, J: PETSc.Mat) -> Linearization:
        s, h = self.system, self.h
        (q0, v0, a0), (q1, v1, a1) = st0, st1
        am, af, g, b = self.am, self.af, self.gamma, self.nbeta
        qf, vf, amv = q0.copy(), v0.copy(), a0.copy()
        qf.scale(1.0 - af)
        qf.axpy(af, q1)
        vf.scale(1.0 - af)
        vf.axpy(af, v1)
        amv.scale(1.0 - am)
        amv.axpy(am, a1)
        c = af * g / (b * h)
        aJ = am / (b * h * h)
        velocity_state(s, vf)
        # the viscoelastic branch at alpha_f: g K0 W(q1; q0, z0) (K0 k0x with k0x = g W)
        branch = self._branch()
        cb, k0x = 0.0, None
        if branch is not None:
            cb = branch.jacobian_coefficient()
            k0x = branch.strain(q1).copy()
            k0x.scale(branch.ratio)
        s.assemble_combination(qf, aJ + s.alpha * c, af, s.beta * c + cb, J, velocity=c,
                               reuse=True)
        deriv = parameter_derivatives(s, qf, vf, amv, k0x=k0x, size=self.cell_size)
        for x in (qf, amv) + ((k0x,) if k0x is not None else ()):
            x.destroy()
        return Linearization(J, deriv, vf, aJ=aJ, cD=c, cB=cb)

    def _K_apply(self, lin: Linearization, x, out) -> None:
        """out = K(q_f) x (free rows; x zero on supports) from the eliminated alpha Jacobian."""
        s = self.system
        k = lin.coefficients
        lin.J.mult(x, out)
        tmp = x.duplicate()
        s.M.mult(x, tmp)
        out.axpy(-k["aJ"], tmp)
        damping_tangent(s, lin.v, x, tmp)
        out.axpy(-k["cD"], tmp)
        if k["cB"]:
            # the viscoelastic branch's c K0 in the step's Jacobian is not K(q_f)'s
            s.K0_matrix().mult(x, tmp)
            out.axpy(-k["cB"], tmp)
        out.scale(1.0 / self.af)
        tmp.destroy()

    def tangent_step(self, lin: Linearization, Rp, dq0, dv0, da0, dz0, solve: Solve, rhs, tmp,
                     q1, name: str) -> None:
        """In place: (dq0, dv0, da0) -> (dq1, dv1, da1); with the viscoelastic branch also
        dz0 -> dz1 (its term K0 (a_q dq0 + a_z dz0) in the residual's tangent)."""
        s, h = self.system, self.h
        am, af, g, b = self.am, self.af, self.gamma, self.nbeta
        branch = self._branch() if dz0 is not None else None
        ca = 1.0 / (b * h * h)
        # primed: the tangents with dq1 = 0
        da1 = dq0.copy()
        da1.axpy(h, dv0)
        da1.axpy(h * h * (0.5 - b), da0)
        da1.scale(-ca)
        dv1 = dv0.copy()
        dv1.axpy(h * (1.0 - g), da0)
        dv1.axpy(h * g, da1)
        dvf = dv0.copy()
        dvf.scale(1.0 - af)
        dvf.axpy(af, dv1)
        dam = da0.copy()
        dam.scale(1.0 - am)
        dam.axpy(am, da1)
        dqf = dq0.copy()
        dqf.scale(1.0 - af)
        s.M.mult(dam, rhs)
        self._K_apply(lin, dqf, tmp)
        rhs.axpy(1.0, tmp)
        rhs.axpy(1.0, damping_tangent(s, lin.v, dvf, tmp))
        rhs.axpy(1.0, Rp)
        if branch is not None:
            a_q, a_z = branch.state_coefficients()
            dq0.copy(dqf)                   # dqf <- a_q dq0 + a_z dz0 (dqf is spent)
            dqf.scale(a_q)
            dqf.axpy(a_z, dz0)
            s.K0_matrix().mult(dqf, tmp)
            rhs.axpy(1.0, tmp)
        rhs.scale(-1.0)
        s.zero_prescribed(rhs)
        solve(rhs, tmp)                     # tmp = dq1
        if branch is not None:
            branch.tangent_update(dz0, tmp, q1, name, dq0=dq0)
        tmp.copy(dq0)
        da1.axpy(ca, tmp)
        dv1.axpy(h * g * ca, tmp)
        da1.copy(da0)
        dv1.copy(dv0)
        for x in (da1, dv1, dvf, dam, dqf):
            x.destroy()

    def adjoint_step(self, lin: Linearization, gq1, gv1, ga1, solve: Solve, contract: Contract,
                     mu, rhs, tmp) -> tuple:
        """Transpose of :meth:`tangent_step`: adjoints of (q1, v1, a1) -> of (q0, v0, a0)
        (new vectors; the given ones are destroyed)."""
        s, h = self.system, self.h
        am, af, g, b = self.am, self.af, self.gamma, self.nbeta
        ca = 1.0 / (b * h * h)
        # dv1 = dv0 + h(1-g) da0 + h g da1 ; da1 = ca (dq1 - dq0 - h dv0 - h^2 (1/2-b) da0)
        gda1 = ga1.copy()
        gda1.axpy(h * g, gv1)
        gv0 = gv1.copy()
        ga0 = gv1.copy()
        ga0.scale(h * (1.0 - g))
        rhs.waxpy(ca, gda1, gq1)                      # adjoint of dq1
        gq0 = gda1.copy()
        gq0.scale(-ca)
        gv0.axpy(-ca * h, gda1)
        ga0.axpy(-ca * h * h * (0.5 - b), gda1)
        s.zero_prescribed(rhs)
        solve(rhs, mu)
        contract(lin.deriv, mu)
        # minus the transpose of L(dq0, dv0, da0) = M dam' + K dqf' + D dvf' applied to mu
        ym, yk, yd = s.create_vec(), s.create_vec(), s.create_vec()
        s.M.mult(mu, ym)
        self._K_apply(lin, mu, yk)
        damping_tangent(s, lin.v, mu, yd)
        b_dv1 = yd.copy()
        b_dv1.scale(af)
        b_da1 = ym.copy()
        b_da1.scale(am)
        b_da1.axpy(h * g, b_dv1)
        gq0.axpy(-(1.0 - af), yk)
        gq0.axpy(ca, b_da1)
        gv0.axpy(-(1.0 - af), yd)
        gv0.axpy(-1.0, b_dv1)
        gv0.axpy(ca * h, b_da1)
        ga0.axpy(-(1.0 - am), ym)
        ga0.axpy(-h * (1.0 - g), b_dv1)
        ga0.axpy(ca * h * h * (0.5 - b), b_da1)
        for x in (ym, yk, yd, b_dv1, b_da1, gda1, gq1, gv1, ga1):
            x.destroy()
        return gq0, gv0, ga0
