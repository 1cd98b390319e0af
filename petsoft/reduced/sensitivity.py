"""Forward sensitivities of a reduced run: the derivative of its discrete steps.

The reduced residual (:mod:`petsoft.reduced.galerkin`) at coordinates (q, v, a) is

    R = M_r a + f_r(q) + D_r v - V^T (f_g + f_t(t)),

with M_r, D_r, V^T f_g and the elastic force f_r depending on the parameters p. Its parameter
derivative splits into

    R_p = M_p a + D_p v + f_p(q) + l_p,

where M_p = V^T dM/dp V and D_p = V^T dD/dp V (r x r, per parameter) and l_p = -V^T df_g/dp
(r) are computed once per run from the system's residual derivatives
(:class:`petsoft.dynamics.parameters.ParameterDerivatives`, which are affine in v and a at a
fixed q): D_p's column j is d r/dp at (q = 0, v = v_j, a = 0) minus that at (0, 0, 0), M_p's
the same with a = v_j; f_p(q) comes from the force provider (``parameter_force``: the full
assembly's, or with ECSW the sampled derivative -- the same elements and weights).

Each step's tangent equations are the derivative of the step itself (generalized-alpha: the
state updates of a_1, v_1 and the alpha_m/alpha_f averages differentiated; backward Euler:
v_1 = (q_1 - q_0)/h), so the sensitivities equal finite differences of the reduced run to
round-off order (the Newton tolerance). Their matrix is the step's reduced Jacobian at the
converged state, e.g. am/(b h^2) M_r + af K_r(q_f) + af g/(b h) D_r: per step one reduced
tangent K_r (the full assembly projected, or the sampled elements' r x r sum), one r x r LU
and one solve with P right-hand sides, plus f_p (one force evaluation per parameter on the
sampled elements). The start: dq_0 = 0 (q_ref holds the initial displacement), dv_0 from the
M-projection of the initial velocity v = M_r^-1 V^T M v0 (nonzero for a density only), and
the consistent acceleration's derivative M_r da_0 = -(R_p + D_r dv_0) at t = 0.

Markers: d markers/dp = H V dq/dp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc
from scipy.linalg import lu_factor, lu_solve

from petsoft.dynamics.alpha import alpha_parameters
from petsoft.dynamics.rayleigh import NAMES as RAYLEIGH
from petsoft.dynamics.velocity import LAWS as VELOCITY_LAWS
from petsoft.errors import ExperimentError
from petsoft.physics.body_force import COMPONENTS, TILTS
from petsoft.reduced.galerkin import ReducedModel, ReducedRun, at_frames, projected_derivatives

#: The parameter names (prefixes) the reduced sensitivities cover: the terms the reduced model
#: projects whose residual is affine in the velocity (quadratic drag and dry friction are not
#: reduced; elastic supports and colliders are not differentiated here).
#: the velocity laws that are linear (``linear``: linear drag) are the ones with a D_p
LINEAR_VELOCITY = tuple(n for n, law in VELOCITY_LAWS.items() if law.linear)
DIFFERENTIATED = ("material.", *RAYLEIGH, *LINEAR_VELOCITY, *COMPONENTS)


@dataclass
class ReducedSensitivities:
    """A reduced run with the derivatives of its coordinates and markers.

    Attributes
    ----------
    run : ReducedRun
    names : list of str
    coordinates : ndarray (N + 1, r, P)
        d a_n / d p_j.
    markers : ndarray (N + 1, M, 3, P)
        d markers_n / d p_j.
    """

    run: ReducedRun
    names: list
    coordinates: np.ndarray
    markers: np.ndarray

    def frames(self, frame_times, h: float) -> tuple[np.ndarray, np.ndarray]:
        """(markers (K, M, 3), d markers/dp (K, M, 3, P)) at ``frame_times``, as
        :meth:`petsoft.calibration.forward.ForwardModel.jacobian` returns them."""
        return self.run.frames(frame_times, h), at_frames(self.markers, frame_times, h)


def _is_density(name: str) -> bool:
    return name.startswith("material.") and name.endswith(".density")


def _is_lame(name: str) -> bool:
    """A material name whose derivative is the elastic law's (E, nu, a stiffness field)."""
    return name.startswith("material.") and not _is_density(name)


def operator_derivatives(model: ReducedModel, names, v0: PETSc.Vec | None = None):
    """(M_p (P, r, r), D_p (P, r, r), l_p (r, P), V^T dM/dp v0 (r, P)) at the system's current
    parameters (module docstring). Collective; once per run.

    Known forms first (D = alpha M + beta K0 + linear drag; the mass linear in the density):
    D_p = M_r for damping.mass, V^T K0 V for damping.stiffness, alpha M_p for a density, 0 for
    gravity and for a Lame-type name when beta = 0; M_p = 0 but for a density. The rest -- M_p
    of a density, D_p of a Lame-type name when beta != 0, linear drag and anything else --
    from the residual derivatives column by column: r evaluations on the full mesh for each
    of the two kinds needed (none for E and the Rayleigh coefficients at beta = 0).
    """
    s, V = model.system, model.basis
    names = list(names)
    r, P = V.size, len(names)
    zero, col = s.create_vec(), s.create_vec()
    zero.zeroEntries()
    base = projected_derivatives(s, V, names, zero, zero, zero)
    Dp = np.zeros((P, r, r))
    Mp = np.zeros((P, r, r))
    dens = [j for j, n in enumerate(names) if _is_density(n)]
    generic = [j for j, n in enumerate(names)
               if not (_is_density(n) or n in COMPONENTS + TILTS
                       or n in RAYLEIGH
                       or (_is_lame(n) and s.beta == 0.0))]
    if dens or generic:
        for j in range(r):
            V.expand_column(j, col)
            if generic:
                d = projected_derivatives(s, V, names, zero, col, zero) - base
                for k in generic:
                    Dp[k, :, j] = d[:, k]
            if dens:
                d = projected_derivatives(s, V, names, zero, zero, col) - base
                for k in dens:
                    Mp[k, :, j] = d[:, k]
    for k, name in enumerate(names):
        if name in RAYLEIGH:
            # D_p = V^T B V, B the matrix the Rayleigh term scales (M_r is V^T M V)
            Dp[k] = (model.Mr if s.rayleigh.matrix_of(name) == "mass"
                     else V.project_matrix(s.K0_matrix()))
        elif k in dens:
            Dp[k] = s.alpha * Mp[k]
    dmv0 = np.zeros((r, P))
    if dens and v0 is not None:
        dmv0 = projected_derivatives(s, V, names, zero, zero, v0) - base
    zero.destroy()
    col.destroy()
    return Mp, Dp, base, dmv0


def sensitivities(model: ReducedModel, v0: PETSc.Vec, h: float, nsteps: int, names
                  ) -> ReducedSensitivities:
    """Run the reduced model (:meth:`ReducedModel.run`) with the forward sensitivities of its
    coordinates and markers to the parameters ``names`` (at the system's current values).

    Parameters
    ----------
    model : ReducedModel
    v0 : PETSc.Vec
        The initial velocity (full vector), as for :meth:`ReducedModel.run`.
    h : float
    nsteps : int
    names : sequence of str
        Differentiable parameter names of the system (:meth:`DynamicSystem.parameter_names`;
        those of the terms the reduced model projects: materials, damping, linear drag,
        gravity, stiffness fields).

    Returns
    -------
    ReducedSensitivities
        Collective; the same on every rank.
    """
    names = list(names)
    s = model.system
    if not names:
        raise ExperimentError("reduced sensitivities: no parameter names given")
    if len(set(names)) != len(names):
        raise ExperimentError(f"reduced sensitivities: repeated parameter names in {names}")
    s.parameters.check(names)
    other = [n for n in names if not n.startswith(DIFFERENTIATED)]
    if other:
        raise ExperimentError(f'reduced sensitivities: "{other[0]}" is not differentiated in '
                              "the reduced model (materials, "
                              f"{', '.join(RAYLEIGH + LINEAR_VELOCITY)} and gravity are); use "
                              "ForwardModel.jacobian")
    forces, Mr, Dr = model.forces, model.Mr, model.Dr
    Mp, Dp, lp, dmv0 = operator_derivatives(model, names, v0)
    r, P = model.basis.size, len(names)

    def Rp(q, v, acc):
        """(r, P) d R/d p at the coordinates (q, v, acc)."""
        return (np.einsum("pij,j->ip", Mp, acc) + np.einsum("pij,j->ip", Dp, v)
                + forces.parameter_force(q, names) + lp)

    dq = np.zeros((r, P))
    # v = M_r^-1 V^T M v0: with a changed density neither factor stays put
    v_start = model.coordinates(v0)
    dv = np.linalg.solve(Mr, dmv0 - np.einsum("pij,j->ip", Mp, v_start))
    da = None
    coords = [dq]

    if model.method == "alpha":
        am, af, g, b = alpha_parameters(model.radius)
        ca = 1.0 / (b * h * h)

        def step(n, st0, st1):
            nonlocal dq, dv, da
            (q0, v0c, a0), (q1, v1, a1) = st0, st1
            if da is None:
                # the consistent acceleration's derivative: M_r da0 = -(R_p + D_r dv0), at
                # q = 0 (dq0 = 0)
                da = np.linalg.solve(Mr, -(Rp(q0, v0c, a0) + Dr @ dv))
            qf = q0 + af * (q1 - q0)
            vf = v0c + af * (v1 - v0c)
            amv = a0 + am * (a1 - a0)
            K = forces.tangent(qf)
            J = am * ca * Mr + af * K + af * g / (b * h) * Dr
            # the step's tangents with dq1 = 0, then dq1 from the linear equation
            da1 = -ca * (dq + h * dv + h * h * (0.5 - b) * da)
            dv1 = dv + h * ((1.0 - g) * da + g * da1)
            L0 = (Mr @ ((1.0 - am) * da + am * da1) + K @ ((1.0 - af) * dq)
                  + Dr @ ((1.0 - af) * dv + af * dv1) + Rp(qf, vf, amv))
            dq1 = lu_solve(lu_factor(J), -L0)
            dq, dv, da = dq1, dv1 + h * g * ca * dq1, da1 + ca * dq1
            coords.append(dq)
    else:
        def step(n, st0, st1):
            nonlocal dq, dv
            (_, v0c, _), (q1, v1, _) = st0, st1
            K = forces.tangent(q1)
            J = Mr / h**2 + K + Dr / h
            dv1 = -dq / h
            L0 = Mr @ ((dv1 - dv) / h) + Dr @ dv1 + Rp(q1, v1, (v1 - v0c) / h)
            dq1 = lu_solve(lu_factor(J), -L0)
            dq, dv = dq1, (dq1 - dq) / h
            coords.append(dq)

    run = model.run(v0, h, nsteps, on_step=step)
    dcoords = np.stack(coords)
    dmarkers = np.einsum("ir,nrp->nip", model.H, dcoords).reshape(nsteps + 1, -1, 3, P)
    return ReducedSensitivities(run, names, dcoords, dmarkers)
