"""Every material law's stress (and energy, and tangent) at finite strain against its textbook
formula, computed by a route independent of petsoft's code (issue 36, item 1).

petsoft's laws (``petsoft/fem/kernels/materials.py``, the specification, and the C kernels in
``csrc/elastic.c``) are compared with:

* linear, StVK, neo-Hookean: psi(F) written below in sympy from its textbook definition, and
  P = d psi / d F, dP/dF = d^2 psi / d F^2 by sympy's symbolic differentiation;
* co-rotated (psi = mu ||F - R||^2 + lam/2 tr(R^T F - I)^2, R the rotation of the polar
  decomposition): the principal-stress formula of an isotropic law of the singular values,
  P = U diag(d psi / d sigma_i) V^T with psi = mu sum (sigma_i - 1)^2 + lam/2 (sum sigma_i - 3)^2,
  U, V from scipy's SVD; and, separately, a central difference of psi(F) evaluated with
  scipy.linalg.polar (a different factorisation from petsoft's signed SVD);

at deformation gradients far from the identity: a rotation by 50 degrees of a stretch
(1.3, 0.8, 1.1); a simple shear of 0.6; a compression to (0.6, 0.9, 0.85) under a rotation; a
general non-symmetric F with det F = 1.4; a large compression (J ~ 0.35) with shear. Both the
numpy reference and the production C kernel are compared, to 1e-12 of max |P|.

Mutants (issue 36), made by hand one at a time, the tests run, reverted (scratch script, not
kept). "new" = this file (F) and tests/test_hyperelastic_reference.py (R); "old" = the failures
in tests/test_materials.py and tests/test_kernels.py under the same mutant:

* neo-Hookean lam/2 (ln J)^2 -> lam/2 (J - 1)^2, consistently in psi, P and dP/dF of the numpy
  reference: F test_stress_energy[neohookean-numpy-*] for 4 of 5 F (not simple shear: J = 1,
  where both terms and their derivatives vanish) and test_rigid_rotation[neohookean-numpy];
  old: only C-vs-numpy comparisons and the projection check (no property test).
* the same in the C kernel (psi and P of ``evaluate``): F test_stress_energy[neohookean-c-*]
  (4 of 5), test_rigid_rotation[neohookean-c]; R test_p1_matches_dolfinx[neohookean] and
  test_p2_..._quadrature_error[neohookean].
* StVK S = 2 mu E + ... -> mu E + ... (stress only; numpy, and separately C): F
  test_stress_energy[stvk-<backend>-*] (5 of 5), test_rigid_rotation[stvk-<backend>]; C also R
  (P1 and P2). Consistently in psi = mu/2 E:E, S and dP/dF (numpy): the same F tests; old: only
  linearisation-at-identity and C-vs-numpy.
* co-rotated P = 2 mu (F - R) + ... -> mu (F - R) + ... (numpy; C): F
  test_stress_energy[corotated-<backend>-*] (5 of 5), test_corotated_stress_is_derivative_of_
  polar_energy, test_corotated_uniaxial_stretch_of_rotated_bar, test_rigid_rotation
  [corotated-<backend>]; C also R test_corotated_rotated_bar_in_uniaxial_tension[1, 2];
  consistently in psi, P, dP/dF (numpy): the same F tests.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import sympy as sp

from petsoft.fem.kernels import compiled
from petsoft.fem.kernels import materials as reference

MU, LAM = 3.7, 5.3  # distinct, not round: a swapped or mis-scaled coefficient shows
BACKENDS = {"numpy": reference.material_response, "c": compiled.material_response}


def _rotation(axis, angle_deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.radians(angle_deg)
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


def _gradients() -> dict[str, np.ndarray]:
    shear = np.eye(3)
    shear[0, 1] = 0.6
    general = np.array([[1.2, 0.3, -0.2], [0.1, 0.9, 0.25], [-0.15, 0.2, 1.1]])
    general *= (1.4 / np.linalg.det(general)) ** (1 / 3)
    squash = _rotation((0.3, -1.0, 0.5), 25) @ np.array([[0.5, 0.2, 0.0], [0.0, 0.8, -0.1],
                                                         [0.0, 0.0, 0.9]])
    F = {
        "rotated-stretch": _rotation((1.0, 2.0, 3.0), 50) @ np.diag([1.3, 0.8, 1.1]),
        "simple-shear": shear,
        "rotated-compression": _rotation((0.0, 1.0, 1.0), 70) @ np.diag([0.6, 0.9, 0.85]),
        "general": general,
        "large-compression": squash,
    }
    for name, f in F.items():
        assert np.linalg.det(f) > 0.3, name
        assert np.abs(f - np.eye(3)).max() > 0.19, name  # finite strain, not near I
    return F


GRADIENTS = _gradients()


# ------------------------------------------------------------------------------------------------
# The textbook laws, in sympy


def _sympy_law(law: str):
    """(psi, P, dPdF) as numpy functions of F (3, 3), from psi written here and sympy's
    derivatives."""
    Fs = sp.Matrix(3, 3, sp.symbols("F0:9", real=True))
    mu, lam = sp.Rational(37, 10), sp.Rational(53, 10)
    Id = sp.eye(3)
    if law == "linear":
        eps = (Fs + Fs.T) / 2 - Id
        psi = mu * sum(e**2 for e in eps) + lam / 2 * eps.trace() ** 2
    elif law == "stvk":
        Eg = (Fs.T * Fs - Id) / 2
        psi = mu * sum(e**2 for e in Eg) + lam / 2 * Eg.trace() ** 2
    elif law == "neohookean":
        J = Fs.det()
        psi = mu / 2 * ((Fs.T * Fs).trace() - 3) - mu * sp.log(J) + lam / 2 * sp.log(J) ** 2
    else:
        raise AssertionError(law)
    flat = list(Fs)
    P = [sp.diff(psi, f) for f in flat]
    H = [[sp.diff(p, f) for f in flat] for p in P]
    f_psi, f_P, f_H = (sp.lambdify(flat, e, "numpy") for e in (psi, P, H))

    def call(F):
        args = np.asarray(F, float).ravel()
        return (float(f_psi(*args)), np.array(f_P(*args), float).reshape(3, 3),
                np.array(f_H(*args), float).reshape(3, 3, 3, 3))
    return call


@pytest.fixture(scope="module")
def sympy_laws():
    return {law: _sympy_law(law) for law in ("linear", "stvk", "neohookean")}


def _corotated_principal(F):
    """psi and P of the co-rotated law by the principal-stress formula (scipy's SVD, det F > 0:
    the sign of U V^T is fixed by making both proper rotations)."""
    U, s, Vt = np.linalg.svd(F)
    if np.linalg.det(U) < 0:
        U[:, 2] *= -1
        s[2] *= -1
    if np.linalg.det(Vt) < 0:
        Vt[2] *= -1
        s[2] *= -1
    psi = MU * np.sum((s - 1) ** 2) + LAM / 2 * (s.sum() - 3) ** 2
    dpsi_ds = 2 * MU * (s - 1) + LAM * (s.sum() - 3)
    return psi, U @ np.diag(dpsi_ds) @ Vt


def _corotated_polar_psi(F):
    R, _ = scipy.linalg.polar(F)
    return MU * np.sum((F - R) ** 2) + LAM / 2 * (np.trace(R.T @ F) - 3) ** 2


def _compare(name, got, want, tol=1e-12):
    err = np.abs(np.asarray(got) - np.asarray(want)).max() / max(np.abs(want).max(), 1e-300)
    assert err < tol, f"{name}: relative difference {err:.3e}"
    return err


def _cases():
    for law in reference.MODELS:
        for backend in BACKENDS:
            for fname in GRADIENTS:
                yield pytest.param(law, backend, fname, id=f"{law}-{backend}-{fname}")


@pytest.mark.parametrize(("law", "backend", "fname"), list(_cases()))
def test_stress_energy(law, backend, fname, sympy_laws):
    """psi and P (and dP/dF where sympy gives it) of petsoft's law at a finite-strain F equal
    the independent formula's to 1e-12 (relative to the largest entry)."""
    F = GRADIENTS[fname]
    psi, P, dPdF = BACKENDS[backend](law, F[None], MU, LAM)
    if law == "corotated":
        psi_ref, P_ref = _corotated_principal(F)
        H_ref = None
    else:
        psi_ref, P_ref, H_ref = sympy_laws[law](F)
    _compare("psi", psi[0], psi_ref)
    _compare("P", P[0], P_ref)
    if H_ref is not None:
        _compare("dP/dF", dPdF[0], H_ref, tol=1e-11)


def test_gradients_are_where_the_laws_differ(sympy_laws):
    """The test F are where the nonlinear laws matter: at 4 of the 5 (neo-Hookean in simple
    shear is the exception: J = 1 and mu (F - F^-T) = 2 mu eps exactly), each law's P differs
    from the linear law's by more than 10 % of max |P|, and the laws differ from each other."""
    for law in ("stvk", "corotated", "neohookean"):
        far = 0
        for F in GRADIENTS.values():
            eps = 0.5 * (F + F.T) - np.eye(3)
            P_lin = 2 * MU * eps + LAM * np.trace(eps) * np.eye(3)
            P = _corotated_principal(F)[1] if law == "corotated" else sympy_laws[law](F)[1]
            far += np.abs(P - P_lin).max() > 0.1 * np.abs(P).max()
        assert far >= 4, law


@pytest.mark.parametrize("backend", list(BACKENDS))
def test_corotated_stress_is_derivative_of_polar_energy(backend):
    """Co-rotated: petsoft's P equals the central difference (h = 1e-5, error ~h^2) of psi(F)
    computed with scipy.linalg.polar, at every test F, to 1e-8 of max |P|."""
    h = 1e-5
    for fname, F in GRADIENTS.items():
        _, P, _ = BACKENDS[backend]("corotated", F[None], MU, LAM)
        fd = np.zeros((3, 3))
        for i in range(3):
            for j in range(3):
                d = np.zeros((3, 3))
                d[i, j] = h
                fd[i, j] = (_corotated_polar_psi(F + d) - _corotated_polar_psi(F - d)) / (2 * h)
        _compare(f"corotated P vs FD of polar psi at {fname}", P[0], fd, tol=1e-8)


@pytest.mark.parametrize("backend", list(BACKENDS))
def test_corotated_uniaxial_stretch_of_rotated_bar(backend):
    """Closed form, by hand: F = Q diag(a, b, b) (a bar stretched along its axis by a, laterally
    by b, then rotated by Q) has R = Q and P = Q diag(2 mu (a - 1) + lam t,
    2 mu (b - 1) + lam t, same), t = a + 2 b - 3. The lateral stress vanishes (uniaxial stress)
    exactly when b = 1 - lam (a - 1) / (2 (mu + lam)), and the axial force per reference area is
    then P_axial = (a - 1) mu (2 mu + 3 lam) / (mu + lam) (= E (a - 1) for these Lame
    parameters: Young's modulus). Checked for a = 1.3 and a = 0.7, Q a 65-degree rotation."""
    Q = _rotation((2.0, -1.0, 0.5), 65)
    young = MU * (2 * MU + 3 * LAM) / (MU + LAM)
    for a in (1.3, 0.7):
        b = 1 - LAM * (a - 1) / (2 * (MU + LAM))
        F = Q @ np.diag([a, b, b])
        _, P, _ = BACKENDS[backend]("corotated", F[None], MU, LAM)
        local = Q.T @ P[0]  # the stress in the bar's axes
        want = np.diag([young * (a - 1), 0.0, 0.0])
        _compare(f"uniaxial a={a}", local, want)


@pytest.mark.parametrize("backend", list(BACKENDS))
@pytest.mark.parametrize("law", ["corotated", "neohookean", "stvk"])
def test_rigid_rotation_of_loaded_body(law, backend, sympy_laws):
    """Objectivity with a hand-checkable number: P(Q F) = Q P(F) for a 120-degree rotation Q of
    a stretched, sheared F, and P(F) itself equals the formula's (so this cannot pass by
    rotating a wrong stress)."""
    Q = _rotation((1.0, 1.0, -2.0), 120)
    F = GRADIENTS["general"]
    _, P, _ = BACKENDS[backend](law, np.stack([F, Q @ F]), MU, LAM)
    if law == "corotated":
        want = _corotated_principal(F)[1]
    else:
        want = sympy_laws[law](F)[1]
    _compare("P(F)", P[0], want)
    _compare("P(QF) = Q P(F)", P[1], Q @ want)
