"""`petsoft synth`: refinement, markers, sampling, noise, dropout, truth.json (tiny runs)."""

import json
import subprocess
import sys
from argparse import Namespace
from pathlib import Path

import meshio
import numpy as np
import pytest
from mpi4py import MPI

from petsoft.calibration.observation import MarkerObserver
from petsoft.calibration.synth import SynthError, refine_mesh, run_synth, surface_nodes
from petsoft.dynamics.simulate import Simulation
from petsoft.experiment import load_experiment
from petsoft.io.recording import read_recording
from petsoft.mesh.serial import box_mesh, read_mesh, signed_volumes
from petsoft.mesh.topology import exterior_faces
from petsoft.physics.model import build_model

EXPERIMENT = """
[mesh]
{mesh}

[material]
model = "linear"
youngs_modulus = 2.0e5
poisson_ratio = 0.3
density = 1000.0

[gravity]
acceleration = [0.0, 0.0, -9.81]

[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[time]
end = 0.02
step = 0.002
integrator = "be"

[output]
directory = "out"
"""


def _shared_dir(tmp_path_factory, name):
    comm = MPI.COMM_WORLD
    return Path(comm.bcast(str(tmp_path_factory.mktemp(name)) if comm.rank == 0 else None))


def _experiment(folder, mesh='box = { size = [0.3, 0.04, 0.04], cells = [6, 1, 1] }'):
    path = folder / "bar.toml"
    if MPI.COMM_WORLD.rank == 0:
        path.write_text(EXPERIMENT.format(mesh=mesh))
    MPI.COMM_WORLD.Barrier()
    return path


def _args(exp, out, **kw):
    base = dict(experiment=str(exp), out=str(out), noise=0.0, markers=5, markers_file=None,
                dropout=0.0, refine=1, integrator=None, seed=3)
    base.update(kw)
    return Namespace(**base)


def _read(path):
    MPI.COMM_WORLD.Barrier()
    return read_recording(path)


def test_refine_mesh_keeps_volume_tags_and_groups():
    m = box_mesh([0.3, 0.1, 0.2], [3, 1, 2])
    m.cell_tags[:] = np.arange(len(m.tets)) % 3
    faces, _ = exterior_faces(m.tets)                    # outward, as validate() keeps them
    m.facet_groups["end"] = faces[:2]
    r = refine_mesh(m)
    assert len(r.tets) == 8 * len(m.tets)
    assert signed_volumes(r.points, r.tets).min() > 0
    assert np.isclose(signed_volumes(r.points, r.tets).sum(), 0.3 * 0.1 * 0.2, rtol=1e-12)
    np.testing.assert_array_equal(np.bincount(r.cell_tags), 8 * np.bincount(m.cell_tags))
    np.testing.assert_array_equal(r.points[:len(m.points)], m.points)   # old nodes first

    def area(p, t):
        return 0.5 * np.linalg.norm(np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]),
                                    axis=1)
    assert len(r.facet_groups["end"]) == 8
    assert np.isclose(area(r.points, r.facet_groups["end"]).sum(),
                      area(m.points, m.facet_groups["end"]).sum(), rtol=1e-12)
    # normals keep their direction
    n_old = np.cross(*(m.points[m.facet_groups["end"][:, i]] - m.points[m.facet_groups["end"][:, 0]]
                       for i in (1, 2)))
    n_new = np.cross(*(r.points[r.facet_groups["end"][:, i]] - r.points[r.facet_groups["end"][:, 0]]
                       for i in (1, 2)))
    assert (n_new.reshape(2, 4, 3) @ n_old[:, :, None] > 0).all()


def test_synth_box_clean_noisy_and_refined(tmp_path_factory):
    d = _shared_dir(tmp_path_factory, "synth")
    exp = _experiment(d)
    run_synth(_args(exp, d / "clean" / "rec.h5"))
    clean = _read(d / "clean" / "rec.h5")
    np.testing.assert_allclose(clean.times, np.arange(11) * 0.002, atol=1e-15)
    nodes = surface_nodes(box_mesh([0.3, 0.04, 0.04], [6, 1, 1]))
    pts = box_mesh([0.3, 0.04, 0.04], [6, 1, 1]).points
    assert all(np.isclose(np.linalg.norm(pts[nodes] - r, axis=1), 0).any()
               for r in clean.reference)
    sag = clean.positions[-1, :, 2] - clean.reference[:, 2]
    assert sag.min() < -1e-5                      # the bar falls under gravity
    np.testing.assert_array_equal(clean.positions[0], clean.reference)
    assert clean.noise == {"position_std": 0.0}
    truth = json.loads((d / "clean" / "truth.json").read_text())
    assert truth["parameters"]["material.youngs_modulus"] == 2.0e5
    assert truth["refine"] == 1 and truth["integrator"] == "be" and truth["step"] == 0.002
    assert json.loads((d / "clean" / "summary.json").read_text())["command"] == "synth"
    # the observation operator on an ordinary simulation of the same experiment sees the same
    # final marker positions (B q against synth's gathered barycentric interpolation)
    experiment = load_experiment(exp)
    model = build_model(experiment)
    sim = Simulation(model, experiment)
    result = sim.run()
    obs = MarkerObserver.from_recording(sim.system, clean)
    np.testing.assert_allclose(obs.observe(result.q), clean.positions[-1], rtol=0, atol=1e-13)
    obs.destroy()
    sim.destroy()

    std = 2e-4
    run_synth(_args(exp, d / "noisy" / "rec.h5", noise=std, dropout=0.25, markers=5))
    noisy = _read(d / "noisy" / "rec.h5")
    np.testing.assert_array_equal(noisy.reference, clean.reference)   # same seed, same markers
    seen = noisy.seen()
    assert 0.1 < 1 - seen.mean() < 0.4                   # 25 % dropped (55 samples)
    resid = (noisy.positions - clean.positions)[seen]
    assert 0.8 * std < resid.std() < 1.2 * std and abs(resid.mean()) < 0.3 * std
    assert noisy.noise["position_std"] == std

    run_synth(_args(exp, d / "fine" / "rec.h5", refine=2, integrator="midpoint"))
    fine = _read(d / "fine" / "rec.h5")
    truth = json.loads((d / "fine" / "truth.json").read_text())
    assert truth["step"] == 0.001 and truth["integrator"] == "midpoint"
    assert truth["tets"] == {"simulated": 288, "original": 36}
    diff = np.abs(fine.positions - clean.positions).max()
    # another discretisation: not the same numbers, but the same motion
    assert 1e-3 * np.abs(sag).max() < diff < 0.5 * np.abs(sag).max()


def test_synth_file_mesh_refinement_and_errors(tmp_path_factory):
    d = _shared_dir(tmp_path_factory, "synthfile")
    box = box_mesh([0.3, 0.04, 0.04], [6, 1, 1])
    if MPI.COMM_WORLD.rank == 0:
        meshio.write(d / "bar.msh", meshio.Mesh(box.points, [("tetra", box.tets)]),
                     file_format="gmsh22", binary=False)
        (d / "markers.txt").write_text("# x y z\n0.3, 0.04, 0.04\n0.15 0.0 0.02\n")
    MPI.COMM_WORLD.Barrier()
    assert len(read_mesh(d / "bar.msh").tets) == 36
    exp = _experiment(d, mesh='file = "bar.msh"')
    run_synth(_args(exp, d / "r" / "rec.h5", refine=2, markers_file=str(d / "markers.txt")))
    rec = _read(d / "r" / "rec.h5")
    truth = json.loads((d / "r" / "truth.json").read_text())
    assert truth["tets"] == {"simulated": 288, "original": 36}
    np.testing.assert_allclose(rec.reference, [[0.3, 0.04, 0.04], [0.15, 0.0, 0.02]])
    with pytest.raises(SynthError, match="--refine 3: a file mesh is refined by 1->8"):
        run_synth(_args(exp, d / "x" / "rec.h5", refine=3))
    with pytest.raises(SynthError, match=r"--dropout = 1.5.*\[0, 1\)"):
        run_synth(_args(exp, d / "x" / "rec.h5", dropout=1.5))
    with pytest.raises(SynthError, match="--noise = -1.*>= 0"):
        run_synth(_args(exp, d / "x" / "rec.h5", noise=-1.0))
    with pytest.raises(SynthError, match="--markers 500: the mesh has only 28 surface nodes"):
        run_synth(_args(exp, d / "x" / "rec.h5", markers=500))


@pytest.mark.serial_only
def test_synth_command_line(tmp_path):
    exp = _experiment(tmp_path)
    run = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "synth", str(exp), "--out",
                          str(tmp_path / "o" / "r.h5"), "--markers", "3", "--noise", "1e-4"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "wrote" in run.stdout and "truth.json" in run.stdout
    assert read_recording(tmp_path / "o" / "r.h5").num_markers == 3
    run = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "synth", str(exp), "--out",
                          str(tmp_path / "o" / "r.h5"), "--dropout", "2"],
                         capture_output=True, text=True)
    assert run.returncode == 2 and run.stderr.startswith("petsoft: error: --dropout = 2")
