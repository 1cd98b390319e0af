"""Failed Newton steps: retried with half the step (logged); repeated failure stops the run with
an error naming step, time and reason, and the last checkpoint stays valid for --restart."""

from pathlib import Path

import numpy as np
import pytest
import tomllib
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.checkpoint import checkpoint_files
from petsoft.dynamics.simulate import Simulation
from petsoft.errors import SolverError
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model

# A soft neo-Hookean bar released from a strong bend: at h = 0.02 s the first backward-Euler
# Jacobian is indefinite, and CG breaks down on it (this 42-dof bar would get a direct solve by
# default, which does not: the retry test chooses CG + GAMG); at h = 0.01 s it is not.
EXPERIMENT = """
[mesh]
box = { size = [0.3, 0.04, 0.04], cells = [6, 1, 1] }
[material]
model = "neohookean"
youngs_modulus = 1.0e5
poisson_ratio = 0.3
density = 1000.0
[[boundary]]
kind = "fixed"
where = "x < 1e-9"
[initial]
displacement = ["0", "0", "0.5*x**2"]
[time]
end = 0.04
step = 0.02
integrator = "be"
[output]
directory = "out"
checkpoint_every = 1
"""


def _directory(tmp_path_factory, name):
    comm = MPI.COMM_WORLD
    return Path(comm.bcast(str(tmp_path_factory.mktemp(name)) if comm.rank == 0 else None))


def test_failed_step_is_retried_with_half_the_step(tmp_path_factory):
    out = _directory(tmp_path_factory, "retry")
    exp = experiment_from_dict(tomllib.loads(EXPERIMENT))
    lines = []
    opts = PETSc.Options()
    opts.setValue("ksp_type", "cg")
    opts.setValue("pc_type", "gamg")
    try:
        sim = Simulation(build_model(exp), exp, out=out, monitor=lines.append)
        result = sim.run()
        sim.destroy()
    finally:
        opts.delValue("ksp_type")
        opts.delValue("pc_type")
    assert result.retries >= 1
    assert np.isfinite(result.energies).all()
    if MPI.COMM_WORLD.rank == 0:
        retry = [line for line in lines if "retrying with h = 0.01 s" in line]
        assert retry and "step 1, t = 0 s: Newton failed" in retry[0]


def test_repeated_failure_names_step_time_reason_and_keeps_checkpoint(tmp_path_factory):
    out = _directory(tmp_path_factory, "fail")
    exp = experiment_from_dict(tomllib.loads(EXPERIMENT))
    sim = Simulation(build_model(exp), exp, out=out)
    reference = sim.run()
    final = reference.energies[-1].copy()
    sim.destroy()
    if MPI.COMM_WORLD.rank == 0:
        for step, path in checkpoint_files(out / "checkpoints"):
            if step > 1:
                path.unlink()
    MPI.COMM_WORLD.Barrier()
    impossible = {"snes_max_it": "1", "snes_rtol": "1e-30", "snes_atol": "1e-30",
                  "snes_stol": "0"}
    opts = PETSc.Options()
    for k, v in impossible.items():
        opts.setValue(k, v)
    try:
        sim = Simulation(build_model(exp), exp, out=out)
        with pytest.raises(SolverError, match=r"step 2 at t = 0.02 s .* failed 7 times .*"
                                              r"DIVERGED_MAX_IT.*checkpoint is still valid"):
            sim.run(restart=True)
        sim.destroy()
    finally:
        for k in impossible:
            opts.delValue(k)
    assert [s for s, _ in checkpoint_files(out / "checkpoints")] == [1]
    sim = Simulation(build_model(exp), exp, out=out)
    again = sim.run(restart=True)
    sim.destroy()
    assert np.array_equal(again.energies[-1], final)
