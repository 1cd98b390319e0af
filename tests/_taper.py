"""A tapered cantilever as a mesh *file* (not a box) for the file-mesh refinement tests.

0.3 m long, its 0.04 x 0.04 m section tapering to half at the tip, 8 x 2 x 2 hexahedra split
into 6 tetrahedra each (192 tets), written as gmsh 2.2 with the 3D group ``body`` and the 2D
group ``clamp`` (the face x = 0), without gmsh; clamped at x = 0 and released under gravity.
"""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from petsoft.mesh.serial import box_mesh
from petsoft.mesh.topology import exterior_faces

#: Calibrate Young's modulus only (the user's model as given).
CALIBRATE = '[calibrate]\n"material.youngs_modulus" = [1e6, 1e8]\n'


def write_taper_mesh(path: Path, cells=(8, 2, 2)) -> int:
    """Write the tapered bar's mesh file; returns its number of tetrahedra."""
    m = box_mesh([0.3, 0.04, 0.04], list(cells))
    p = m.points.copy()
    shrink = 1.0 - 0.5 * p[:, 0] / 0.3
    p[:, 1:] = (p[:, 1:] - 0.02) * shrink[:, None] + 0.02
    faces, _ = exterior_faces(m.tets)
    clamp = faces[np.isclose(p[faces][:, :, 0], 0.0).all(axis=1)]
    tags = [np.ones(len(m.tets), int), np.full(len(clamp), 2)]
    meshio.write(path, meshio.Mesh(p, [("tetra", m.tets), ("triangle", clamp)],
                                   cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
                                   field_data={"body": np.array([1, 3]),
                                               "clamp": np.array([2, 2])}),
                 file_format="gmsh22", binary=False)
    return len(m.tets)


def taper(E: float, *, mesh: str = "taper.msh", extra: str = "", end: float = 0.2,
          step: float = 0.004, gravity=(0.0, 0.0, -9.81), calibrate: str = "",
          order: int = 1) -> str:
    """The experiment text (generalized-alpha, radius 0.9); ``order`` 2 for 10-node tets (the
    truths: P1 refined twice is still 12 % too stiff in bending, P2 refined twice is within
    0.1 % of converged)."""
    gx, gy, gz = gravity
    return f"""
[mesh]
file = "{mesh}"
order = {order}

[material]
model = "linear"
youngs_modulus = {E}
poisson_ratio = 0.3
density = 1000.0
{extra}
[gravity]
acceleration = [{gx}, {gy}, {gz}]

[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[time]
end = {end}
step = {step}
integrator = "alpha"
alpha_radius = 0.9

[output]
directory = "out"
{calibrate}
"""


def taper_diagnosis(directory: Path, truth: str, user: str, seed: int, noise: float = 2e-5,
                    say=None):
    """The taper's truth recorded by ``petsoft synth`` (8 markers, ``noise``, 10 % dropped) and
    a Diagnosis of the ``user`` experiment against it (identification 70 %, gauss-newton on
    sensitivities), on every rank of COMM_WORLD; returns (diagnosis, user experiment).
    ``directory`` must be the same path on every rank."""
    from mpi4py import MPI
    from petsc4py import PETSc

    from petsoft.calibration.synth import SynthOptions, synth
    from petsoft.diagnosis.context import Diagnosis
    from petsoft.experiment import load_experiment
    from petsoft.io.recording import read_recording

    d = Path(directory)
    if MPI.COMM_WORLD.rank == 0:
        write_taper_mesh(d / "taper.msh")
        (d / "truth.toml").write_text(truth)
        (d / "user.toml").write_text(user)
    MPI.COMM_WORLD.Barrier()
    synth(load_experiment(d / "truth.toml"),
          SynthOptions(out=d / "rec.h5", noise=noise, markers=8, dropout=0.1, seed=seed))
    exp = load_experiment(d / "user.toml")
    diag = Diagnosis(exp, read_recording(d / "rec.h5"), fraction=0.7, alpha=0.01,
                     method="gauss-newton", gradient="sensitivity", integrator=None, noise=None,
                     comm=PETSc.COMM_WORLD, say=say or (lambda line: None))
    return diag, exp
