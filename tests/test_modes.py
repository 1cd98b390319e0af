"""Natural frequencies and mode shapes (petsoft.solvers.modes, `petsoft modes`).

1. Cantilever bending modes against Euler-Bernoulli, with a Timoshenko beam (1D FE) reference to
   show convergence under refinement.
2. M-orthonormality and K-orthogonality of the modes.
3. Axial modes of a clamped-free bar (nu = 0), identified by shape, against the exact 1D values.
4. Free and partly supported bodies: exact rigid-body modes, then elastic ones.
5. Serial == 2 ranks; the CLI end to end.

Every test runs collectively (serially and under ``mpiexec -n 2``); quantities checked are global
reductions, so the assertions agree on every rank. ``pytest -s`` prints the measured tables.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from _static_cases import experiment
from child_process import child_env  # tests/child_process.py
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.cli.main import split_arguments
from petsoft.errors import PetsoftError
from petsoft.physics.model import build_model
from petsoft.solvers.modes import assemble_operators, compute_modes
from petsoft.solvers.options import clear_options

serial_only = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns processes")

E, RHO = 1.0e6, 1000.0
C = np.sqrt(E / RHO)                      # bar wave speed with nu = 0
CLAMP = {"kind": "fixed", "where": "x < 1e-9"}
BETA_L = np.array([1.8751, 4.6941, 7.8548])


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _bar(size, cells, boundary=(CLAMP,), nu=0.0, comm=None):
    exp = experiment("linear", box=(size, cells), E=E, nu=nu, density=RHO, boundary=boundary)
    return build_model(exp, comm)


def _euler_bernoulli(L, a):
    """Clamped-free square a x a beam: f_n = (beta_n L)^2 / (2 pi L^2) sqrt(E I / (rho A))."""
    return BETA_L**2 / (2 * np.pi * L**2) * np.sqrt(E * (a**4 / 12) / (RHO * a * a))


def _timoshenko(L, a, nmodes=3, nel=400):
    """Lowest bending frequencies (Hz) of a clamped-free Timoshenko beam (square a x a, nu = 0,
    shear coefficient 10(1+nu)/(12+11nu) = 5/6, rotary inertia), by linear 1D elements with
    one-point shear integration (no locking); nel = 400 makes its own error ~1e-4."""
    h, A, I, kGA = L / nel, a * a, a**4 / 12, 5.0 / 6.0 * (E / 2.0) * a * a
    B = np.array([-1.0 / h, -0.5, 1.0 / h, -0.5])          # shear strain w' - theta at midpoint
    ke = kGA * h * np.outer(B, B)
    ke[np.ix_([1, 3], [1, 3])] += E * I / h * np.array([[1.0, -1.0], [-1.0, 1.0]])
    lin = h / 6.0 * np.array([[2.0, 1.0], [1.0, 2.0]])
    me = np.zeros((4, 4))
    me[np.ix_([0, 2], [0, 2])] = RHO * A * lin
    me[np.ix_([1, 3], [1, 3])] = RHO * I * lin
    n = 2 * (nel + 1)
    K, M = np.zeros((n, n)), np.zeros((n, n))
    dofs = 2 * np.arange(nel)[:, None] + np.arange(4)[None, :]
    rows, cols = dofs[:, :, None], dofs[:, None, :]
    np.add.at(K, (rows, cols), ke)
    np.add.at(M, (rows, cols), me)
    K, M = K[2:, 2:], M[2:, 2:]                            # clamp w and theta at x = 0
    Linv = np.linalg.inv(np.linalg.cholesky(M))
    lam = np.linalg.eigvalsh(Linv @ K @ Linv.T)[:nmodes]
    return np.sqrt(lam) / (2 * np.pi)


def _component_fractions(result, M) -> np.ndarray:
    """(n, 3): the share of each mode's kinetic norm x^T M x in its x, y, z components.

    The consistent mass couples no two components (it is kron(scalar, I3)), so the three shares
    add up to 1.
    """
    out = np.zeros((len(result.modes), 3))
    y, w = M.createVecLeft(), M.createVecLeft()
    for i, x in enumerate(result.modes):
        for c in range(3):
            x.copy(y)
            arr = y.getArray().reshape(-1, 3)
            arr[:, [d for d in range(3) if d != c]] = 0.0
            M.mult(y, w)
            out[i, c] = y.dot(w)
    y.destroy()
    w.destroy()
    return out / out.sum(axis=1, keepdims=True)


def _modes_with_operators(model, nmodes, **kw):
    result = compute_modes(model, nmodes, **kw)
    K, M, _ = assemble_operators(model)
    return result, K, M


def _bending_families(model, result, a) -> np.ndarray:
    """(n,) family of each mode of a beam along x with its centreline at y = z = a/2: +1 / -1
    for bending along the diagonal y = z / y = -z, 0 for anything else.

    Bending moves the centreline sideways as much as the rest of the section; torsion and axial
    modes leave it (almost) still sideways. The box mesh's Kuhn split is symmetric under the
    swap y <-> z but not under y -> -y, so the two bending families lie along the diagonals.
    """
    mesh = model.dmesh.mesh
    centre = np.all(np.abs(mesh.points[:, 1:] - a / 2) < 1e-9 * a, axis=1)
    family = np.zeros(len(result.modes), dtype=int)
    for i, x in enumerate(result.modes):
        u = model.dmesh.gather_global(x)          # collective
        if PETSc.COMM_WORLD.rank == 0:
            uc = u[centre, 1:]
            sideways = np.sqrt((uc**2).sum(1).mean() / (u[:, 1:] ** 2).sum(1).mean())
            corr = (uc[:, 0] * uc[:, 1]).sum() / (uc**2).sum()
            if sideways > 0.5 and abs(corr) > 0.4:
                family[i] = int(np.sign(corr))
    return PETSc.COMM_WORLD.tompi4py().bcast(family, root=0)


# ================================================================================================
# 1. Cantilever bending


def test_cantilever_bending_against_beam_theory():
    """A 1 m x 0.05 m x 0.05 m cantilever (nu = 0: no Poisson stiffening; slenderness 20) on three
    meshes refined by 2 in every direction (40x2x2, 80x4x4, 160x8x8 hexes, 6 tets each).

    The Kuhn split of the hexes is symmetric under y <-> z but not under y -> -y, so the two
    bending directions are the diagonals y = +-z and are not exactly degenerate: each mode is
    identified by the sideways motion of its centreline (see _bending_families), giving three
    bending modes per diagonal. Checked:

    * the error against a Timoshenko beam (shear + rotary inertia; the 3D limit of these modes to
      ~0.1%) decreases at every refinement, for all 6 modes (P1 tets converge from above);
    * on the finest mesh every frequency is within 4% of Euler-Bernoulli. Measured: +3.3/+1.8%
      (n = 1, y = z / y = -z), +2.3/+0.8% (n = 2), +0.7/-0.7% (n = 3). Timoshenko lies 0.2%,
      1.1% and 2.6% below Euler-Bernoulli for n = 1, 2, 3 here, which is why the stiff-in-bending
      P1 error (+3.4/+1.9% against Timoshenko for every n at 8 elements through the thickness,
      falling ~4x per refinement) and the EB error partly cancel for n = 3.
    """
    L, a = 1.0, 0.05
    eb, timo = _euler_bernoulli(L, a), _timoshenko(L, a)
    meshes = [(40, 2, 2), (80, 4, 4), (160, 8, 8)]
    found = []                          # per mesh: (2, 3) bending frequencies, y = z / y = -z
    for cells in meshes:
        model = _bar((L, a, a), cells)
        result, K, M = _modes_with_operators(model, 10)
        family = _bending_families(model, result, a)
        f = result.frequencies_hz
        per_dir = [f[family == d][:3] for d in (1, -1)]
        assert all(len(p) == 3 for p in per_dir), (cells, f, family)
        found.append(np.array(per_dir))
        result.destroy()
        K.destroy()
        M.destroy()

    _print(f"\ncantilever L = {L} m, {a} m square, nu = 0: bending frequencies (Hz)")
    _print(f"{'mesh':>12} {'n':>2} {'f_y=z':>9} {'f_y=-z':>9} {'EB':>9} {'err':>7} {'err':>7}"
           f" {'Timosh.':>9} {'err':>7} {'err':>7}")
    for cells, fm in zip(meshes, found, strict=True):
        for n in range(3):
            ey, ez = fm[:, n] / eb[n] - 1
            ty, tz = fm[:, n] / timo[n] - 1
            _print(f"{'x'.join(map(str, cells)):>12} {n + 1:>2} {fm[0, n]:9.5f} {fm[1, n]:9.5f}"
                   f" {eb[n]:9.5f} {ey:+7.2%} {ez:+7.2%} {timo[n]:9.5f} {ty:+7.2%} {tz:+7.2%}")
    errors = np.array([np.abs(fm / timo[None, :] - 1) for fm in found])   # (mesh, dir, n)
    assert np.all(np.diff(errors, axis=0) < 0), errors
    assert np.all(found[-1] > timo[None, :])          # P1 tets are too stiff, never too soft
    assert np.all(np.abs(found[-1] / eb[None, :] - 1) < 0.04), found[-1] / eb - 1


# ================================================================================================
# 2. Orthogonality


@pytest.mark.parametrize("boundary", [(CLAMP,), ()], ids=["clamped", "free"])
def test_modes_are_mass_orthonormal_and_stiffness_orthogonal(boundary):
    """X^T M X = I and X^T K X = diag(omega^2) to 1e-8 (K relative to its largest entry in this
    block), for a clamped and a free body (whose six rigid modes are included: 0 on the
    diagonal). Constrained entries of every mode are exactly 0."""
    model = _bar((0.4, 0.04, 0.04), (16, 2, 2), boundary=boundary, nu=0.3)
    result, K, M = _modes_with_operators(model, 10)
    X = result.modes
    w = M.createVecLeft()
    XMX, XKX = np.zeros((10, 10)), np.zeros((10, 10))
    for j, x in enumerate(X):
        M.mult(x, w)
        XMX[:, j] = [y.dot(w) for y in X]
        K.mult(x, w)
        XKX[:, j] = [y.dot(w) for y in X]
    w.destroy()
    lam = result.eigenvalues
    assert np.abs(XMX - np.eye(10)).max() < 1e-8, XMX
    assert np.abs(XKX - np.diag(lam)).max() < 1e-8 * lam.max(), XKX
    held = max(np.abs(x.getArray(readonly=True)[model.dirichlet.owned_offsets(x)]).max(initial=0)
               for x in X)
    assert MPI.COMM_WORLD.allreduce(held, op=MPI.MAX) == 0.0
    assert np.all(np.diff(lam) >= 0) and result.relative_errors.max() < 1e-8
    _print(f"\n{boundary and 'clamped' or 'free'}: max |X^T M X - I| "
           f"{np.abs(XMX - np.eye(10)).max():.1e}, max |X^T K X - diag| / max omega^2 "
           f"{np.abs(XKX - np.diag(lam)).max() / lam.max():.1e}")
    result.destroy()
    K.destroy()
    M.destroy()


# ================================================================================================
# 3. Axial modes (independent of beam theory)


def test_axial_modes_of_clamped_free_bar():
    """A stubby clamped-free bar (1 m, 0.2 m square, nu = 0; 40x4x4 hexes): with nu = 0 the
    axial motion u_x(x) is an exact 3D solution, f_k = (2k - 1) / (4 L) sqrt(E / rho) = 7.906 and
    23.717 Hz. The axial modes are those with > 99% of their kinetic norm in x (a bending mode
    sits at 23.48 Hz, next to the second axial one). Tolerance 0.1%: the consistent-mass P1
    dispersion error is ~(k h)^2 / 24 = 6e-4 for k = 2 with h = L / 40 (measured +0.006% and
    +0.047%)."""
    L = 1.0
    model = _bar((L, 0.2, 0.2), (40, 4, 4))
    result, K, M = _modes_with_operators(model, 14)
    share = _component_fractions(result, M)
    axial = result.frequencies_hz[share[:, 0] > 0.99]
    exact = (2 * np.arange(1, 3) - 1) / (4 * L) * C
    _print(f"\naxial modes: {axial} Hz, exact {exact}, errors {axial[:2] / exact - 1}")
    assert len(axial) >= 2
    assert np.all(np.abs(axial[:2] / exact - 1) < 1e-3)
    result.destroy()
    K.destroy()
    M.destroy()


# ================================================================================================
# 4. Rigid-body modes


def test_free_body_has_six_rigid_modes_then_elastic_ones():
    """No Dirichlet condition: modes 1-6 are the rigid motions (eigenvalue exactly 0, K x = 0 to
    round-off), mode 7 is elastic. The elastic frequencies do not depend on the negative shift
    that replaces sigma = 0 (automatic, or a user's -eps_target = -1): to 1e-8."""
    model = _bar((0.4, 0.04, 0.04), (16, 2, 2), boundary=(), nu=0.3)
    result, K, M = _modes_with_operators(model, 9)
    assert result.rigid_modes == 6 and result.shift < 0
    assert np.all(result.frequencies_hz[:6] == 0.0) and result.frequencies_hz[6] > 1.0
    w = K.createVecLeft()
    for x in result.modes[:6]:
        K.mult(x, w)
        assert w.norm() < 1e-10 * K.norm(PETSc.NormType.INFINITY) * x.norm()
    w.destroy()
    PETSc.Options().setValue("eps_target", "-1")
    try:
        other = compute_modes(model, 9)
    finally:
        clear_options(["eps_target"])
    assert other.shift == -1.0 and other.rigid_modes == 6
    assert np.allclose(other.frequencies_hz[6:], result.frequencies_hz[6:], rtol=1e-8, atol=0)
    # A positive target: only the elastic modes nearest it (the rigid ones stay deflated).
    near = compute_modes(model, 1, target=1.001 * result.eigenvalues[7])
    assert near.rigid_modes == 0 and len(near.modes) == 1
    assert np.isclose(near.frequencies_hz[0], result.frequencies_hz[7], rtol=1e-8, atol=0)
    _print(f"\nfree body: {result.frequencies_hz} Hz (shift {result.shift:.3g})")
    for r in (result, other, near):
        r.destroy()
    K.destroy()
    M.destroy()


def test_symmetry_rollers_leave_three_rigid_modes():
    """Only u_x = 0 on the plane x = 0: the body can still slide in y and z and spin about x,
    so 3 rigid modes come first, then elastic ones."""
    roller = {"kind": "fixed", "where": "x < 1e-9", "components": ["x"]}
    model = _bar((0.4, 0.04, 0.04), (16, 2, 2), boundary=(roller,), nu=0.3)
    result = compute_modes(model, 5)
    assert result.rigid_modes == 3
    assert np.all(result.frequencies_hz[:3] == 0.0) and result.frequencies_hz[3] > 0.5
    result.destroy()


def test_too_many_modes_is_a_clear_error():
    model = _bar((0.4, 0.04, 0.04), (1, 1, 1))   # 8 nodes, 4 clamped: 12 free dofs
    with pytest.raises(PetsoftError, match="between 1 and the number of unconstrained dofs"):
        compute_modes(model, 13)


# ================================================================================================
# 5. Serial == parallel, CLI


def test_serial_equals_parallel():
    """The frequencies on PETSC_COMM_WORLD equal those computed on each rank alone (COMM_SELF)
    to 1e-8 relative (nu = 0.3 cantilever, 8 modes)."""
    size, cells = (0.4, 0.04, 0.04), (24, 3, 3)
    world = compute_modes(_bar(size, cells, nu=0.3), 8)
    alone = compute_modes(_bar(size, cells, nu=0.3, comm=PETSc.COMM_SELF), 8)
    rel = np.abs(world.frequencies_hz / alone.frequencies_hz - 1).max()
    _print(f"\n{PETSc.COMM_WORLD.size} rank(s) vs 1: max relative difference {rel:.1e}")
    assert rel < 1e-8
    world.destroy()
    alone.destroy()


def test_split_arguments_keeps_num_modes_ours():
    for n in (["-n", "6"], ["-n=6"], ["-n6"], ["--num-modes", "6"]):
        ours, petsc = split_arguments(["modes", "e.toml", "-eps_tol", "1e-9", *n, "-eps_view"])
        assert ours == ["modes", "e.toml", *n] and petsc == ["-eps_tol", "1e-9", "-eps_view"]


EXPERIMENT = """
[mesh]
box = { size = [0.4, 0.04, 0.04], cells = [16, 2, 2] }

[material]
model = "neohookean"
youngs_modulus = 1.0e6
poisson_ratio = 0.45
density = 1100.0

[gravity]
acceleration = [0.0, 0.0, -9.81]

[[boundary]]
kind = "fixed"
where = "x < 1e-6"

[petsc]
ksp_type = "cg"
"""


@serial_only
def test_cli_writes_frequencies_and_mode_shapes(tmp_path):
    import meshio

    (tmp_path / "exp.toml").write_text(EXPERIMENT)
    cmd = [sys.executable, "-m", "petsoft.cli.main", "modes", "exp.toml", "-eps_tol", "1e-9",
           "-n", "4", "--out", "d"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, env=child_env(),
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "frequency (Hz)" in proc.stdout and "wrote" in proc.stdout
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    f = summary["frequencies_hz"]
    assert summary["command"] == "modes" and len(f) == 4
    assert all(v > 0 for v in f) and f == sorted(f)
    assert summary["solver"]["tolerance"] == 1e-9 and summary["solver"]["converged"] >= 4
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "d" / "modes.xdmf")) as reader:
        points, _ = reader.read_points_cells()
        assert reader.num_steps == 4
        for k in range(4):
            t, point_data, _ = reader.read_data(k)
            assert t == k + 1 and point_data["mode"].shape == points.shape
            assert np.abs(point_data["mode"][points[:, 0] < 1e-6]).max() == 0.0

    bad = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "modes", "exp.toml", "-n", "0"],
                         cwd=tmp_path, capture_output=True, text=True, env=child_env(), timeout=60)
    assert bad.returncode == 2 and "must be >= 1" in bad.stderr


def test_progress_lines_say_how_many_pairs_converged(monkeypatch):
    """With a monitor, the eigensolver reports its iterations: converged pairs of those wanted
    and, once some converged, the time left at that pace (every line here: interval 0)."""
    import petsoft.solvers.modes as modes

    monkeypatch.setattr(modes, "PROGRESS_SECONDS", 0.0)
    lines = []
    model = _bar([0.4, 0.04, 0.04], [20, 2, 2])
    result = compute_modes(model, 4, monitor=lines.append)
    result.destroy()
    if MPI.COMM_WORLD.rank != 0:
        assert lines == []           # rank 0 prints
        return
    assert lines and all(line.startswith("modes: Krylov-Schur iteration ") for line in lines)
    assert all(" of 4 eigenpairs converged (" in line for line in lines)
