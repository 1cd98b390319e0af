"""Checkpoints and restarts: bitwise on the same ranks, 1e-10 across rank counts, and a run
killed (SIGKILL) while writing a checkpoint restarts from the previous valid one."""

import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import tomllib
from child_process import child_env  # tests/child_process.py
from mpi4py import MPI

from petsoft.atomic import temporaries
from petsoft.dynamics.checkpoint import checkpoint_files
from petsoft.dynamics.simulate import Simulation
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model

serial_only = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns processes")

EXPERIMENT = """
[mesh]
box = {{ size = [0.3, 0.04, 0.04], cells = [6, 1, 1] }}
[material]
model = "neohookean"
youngs_modulus = 1.0e5
poisson_ratio = 0.3
density = 1000.0
[damping]
mass = 1.0
[gravity]
acceleration = [0.0, 0.0, -9.81]
[[boundary]]
kind = "fixed"
where = "x < 1e-9"
[initial]
displacement = ["0", "0", "0.3*x**2"]
[time]
end = 0.12
step = 0.002
integrator = "{integrator}"
[output]
directory = "out"
every = 5
checkpoint_every = 20
probes = [[0.3, 0.02, 0.02]]
"""


def _shared_dir(tmp_path_factory, name):
    comm = MPI.COMM_WORLD
    return Path(comm.bcast(str(tmp_path_factory.mktemp(name)) if comm.rank == 0 else None))


def _run(exp, out, restart=False):
    model = build_model(exp)
    sim = Simulation(model, exp, out=out)
    result = sim.run(restart=restart)      # its solvers push the experiment's [petsc]
    q = MPI.COMM_WORLD.bcast(model.dmesh.gather_global(result.q))
    sim.destroy()
    return q


#: CG + algebraic multigrid on a bar large enough for a hierarchy of several levels (the run
#: keeps the hierarchy's interpolation across steps and renews it after each checkpoint)
MULTIGRID = """
[petsc]
ksp_type = "cg"
pc_type = "gamg"
"""


@pytest.mark.parametrize("integrator, solver", [("be", "default"), ("midpoint", "default"),
                                                ("alpha", "default"), ("be", "gamg"),
                                                ("alpha", "gamg")])
def test_restart_is_bitwise_on_the_same_ranks(tmp_path_factory, integrator, solver):
    """Stop after the step-20 checkpoint (the later ones are deleted, as if the run died), restart:
    final state, energies and probe trajectories equal the uninterrupted run bit for bit."""
    if solver == "gamg" and MPI.COMM_WORLD.size > 2:
        # measured: on 3 ranks two uninterrupted runs in one process already differ (by ~3e-17
        # m), also with a new hierarchy at every step as before hierarchies were kept, and so
        # does a bare loop of backward-Euler steps from a bent state; the direct solve and CG +
        # Jacobi repeat on 3 ranks, and GAMG repeats when its coarse solve is replaced
        # (-mg_coarse_ksp_type cg -mg_coarse_pc_type jacobi): PETSc 3.18's default GAMG coarse
        # solve is where the bits change. On 1 and 2 ranks the runs repeat bit for bit
        pytest.skip("GAMG runs do not repeat bit for bit on more than 2 ranks")
    base = _shared_dir(tmp_path_factory, f"restart-{integrator}-{solver}")
    text = EXPERIMENT.format(integrator=integrator)
    if solver == "gamg":
        text = text.replace("cells = [6, 1, 1]", "cells = [24, 3, 3]") + MULTIGRID
    exp = experiment_from_dict(tomllib.loads(text))
    q_full = _run(exp, base / "full")
    q_first = _run(exp, base / "cut")
    assert np.array_equal(q_first, q_full)
    if MPI.COMM_WORLD.rank == 0:
        for step, path in checkpoint_files(base / "cut" / "checkpoints"):
            if step > 20:
                path.unlink()
    MPI.COMM_WORLD.Barrier()
    q_restart = _run(exp, base / "cut", restart=True)
    assert np.array_equal(q_restart, q_full)
    if MPI.COMM_WORLD.rank == 0:
        a = np.loadtxt(base / "full" / "energies.csv", delimiter=",", skiprows=1)
        b = np.loadtxt(base / "cut" / "energies.csv", delimiter=",", skiprows=1)
        assert np.array_equal(a, b)
        with h5py.File(base / "full" / "probes.h5") as f, h5py.File(base / "cut" /
                                                                    "probes.h5") as g:
            assert np.array_equal(f["frames/time"][()], g["frames/time"][()])
            assert np.array_equal(f["frames/position"][()], g["frames/position"][()])
        assert (base / "cut" / "segments" / "1" / "trajectory.xdmf").exists()


def test_a_run_that_fails_keeps_every_frame_before_the_failure(tmp_path_factory, monkeypatch):
    """Trajectory frames are written in batches (a second apart): a run whose step 37 fails
    still leaves every frame before it in trajectory.xdmf (steps 0, 5, ..., 35), equal to the
    uninterrupted run's, and the step-20 checkpoint."""
    import meshio

    from petsoft.errors import SolverError

    base = _shared_dir(tmp_path_factory, "failing")
    exp = experiment_from_dict(tomllib.loads(EXPERIMENT.format(integrator="alpha")))
    _run(exp, base / "full")
    real = Simulation._advance

    def failing(self, n, *args, **kwargs):
        if n == 37:
            raise SolverError("step 37 diverged (made to fail by the test)")
        return real(self, n, *args, **kwargs)

    monkeypatch.setattr(Simulation, "_advance", failing)
    model = build_model(exp)
    sim = Simulation(model, exp, out=base / "failed")
    try:
        with pytest.raises(SolverError, match="step 37"):
            sim.run()
    finally:
        sim.destroy()
    if MPI.COMM_WORLD.rank == 0:
        def frames(out):
            with meshio.xdmf.TimeSeriesReader(str(out / "trajectory.xdmf")) as reader:
                reader.read_points_cells()
                return [reader.read_data(k)[:2] for k in range(reader.num_steps)]

        failed, full = frames(base / "failed"), frames(base / "full")
        assert [t for t, _ in failed] == pytest.approx([0.002 * n for n in range(0, 36, 5)],
                                                       abs=1e-12)
        for (t, data), (t_full, data_full) in zip(failed, full, strict=False):
            assert t == t_full
            np.testing.assert_array_equal(data["displacement"], data_full["displacement"])
        assert [step for step, _ in checkpoint_files(base / "failed" / "checkpoints")] == [20]


def _cli(args, cwd, ranks=1, env=None, wait=True):
    cmd = [sys.executable, "-m", "petsoft.cli.main", *args]
    if ranks > 1:
        cmd = [shutil.which("mpiexec") or "mpiexec", "-n", str(ranks)] + cmd
    if not wait:
        return subprocess.Popen(cmd, cwd=cwd, env=env or child_env(), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    r = subprocess.run(cmd, cwd=cwd, env=env or child_env(), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    return r


def _final_position(out: Path) -> np.ndarray:
    with h5py.File(out / "probes.h5") as f:
        return f["frames/position"][-1]


def _final_state(out: Path) -> np.ndarray:
    import meshio

    with meshio.xdmf.TimeSeriesReader(str(out / "trajectory.xdmf")) as reader:
        reader.read_points_cells()
        _, data, _ = reader.read_data(reader.num_steps - 1)
    return data["displacement"]


@serial_only
@pytest.mark.parametrize("first, second", [(2, 1), (1, 2)])
def test_restart_on_another_number_of_ranks(tmp_path, first, second):
    """Checkpoints are in mesh numbering: a run checkpointed on `first` ranks continues on
    `second` ranks to the uninterrupted answer within 1e-10 (direct solver, so the linear
    solves do not depend on the partition)."""
    (tmp_path / "exp.toml").write_text(EXPERIMENT.format(integrator="alpha"))
    direct = ["-ksp_type", "preonly", "-pc_type", "lu", "-pc_factor_mat_solver_type", "mumps"]
    _cli(["simulate", "exp.toml", "--out", "full", *direct], tmp_path, ranks=first)
    _cli(["simulate", "exp.toml", "--out", "cut", *direct], tmp_path, ranks=first)
    for step, path in checkpoint_files(tmp_path / "cut" / "checkpoints"):
        if step > 40:
            path.unlink()
    r = _cli(["simulate", "exp.toml", "--out", "cut", "--restart", *direct], tmp_path,
             ranks=second)
    assert f"written on {first} rank(s)" in r.stdout
    a, b = _final_state(tmp_path / "full"), _final_state(tmp_path / "cut")
    assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()


@serial_only
def test_sigkill_during_checkpoint_write_restarts_from_previous(tmp_path):
    """SIGKILL while the step-40 checkpoint is half written: the temporary file is left behind,
    checkpoint 20 stays the latest valid one, and the restart reaches the uninterrupted answer
    bit for bit."""
    (tmp_path / "exp.toml").write_text(EXPERIMENT.format(integrator="be"))
    _cli(["simulate", "exp.toml", "--out", "full"], tmp_path)
    env = child_env()
    env["PETSOFT_CHECKPOINT_PAUSE"] = "40:60"
    proc = _cli(["simulate", "exp.toml", "--out", "cut"], tmp_path, env=env, wait=False)
    checkpoints = tmp_path / "cut" / "checkpoints"
    temporary = temporaries(re.escape("checkpoint-00000040.h5"))

    def partial():
        return checkpoints.is_dir() and any(temporary.fullmatch(p.name)
                                            for p in checkpoints.iterdir())

    deadline = time.time() + 120
    while not partial() and time.time() < deadline:
        time.sleep(0.05)
    assert partial(), "the run never started writing checkpoint 40"
    time.sleep(0.3)  # inside the pause: the file is half written
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert partial()  # left behind, under a name no reader takes for a checkpoint
    assert [s for s, _ in checkpoint_files(tmp_path / "cut" / "checkpoints")] == [20]
    r = _cli(["simulate", "exp.toml", "--out", "cut", "--restart"], tmp_path)
    assert "restarting from checkpoint-00000020.h5" in r.stdout
    assert np.array_equal(_final_position(tmp_path / "full"), _final_position(tmp_path / "cut"))
    assert np.array_equal(_final_state(tmp_path / "full"), _final_state(tmp_path / "cut"))


def test_restart_without_checkpoint_is_a_clear_error(tmp_path_factory):
    from petsoft.errors import PetsoftError

    base = _shared_dir(tmp_path_factory, "nocheckpoint")
    exp = experiment_from_dict(
        tomllib.loads(EXPERIMENT.format(integrator="be")))
    with pytest.raises(PetsoftError, match="no complete checkpoint"):
        _run(exp, base / "empty", restart=True)
