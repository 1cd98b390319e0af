"""``petsoft calibrate --check-mesh`` (``petsoft.calibrate(..., check_mesh=True)``) and the
refined experiments the numerics checks build (petsoft/calibration/refinement.py).

The tapered cantilever's coarse mesh file (192 tets, tests/_taper.py) is calibrated against
recordings made on its 1 -> 8 refinement (``synth --refine 2``). Bending (released under gravity)
with precise data: the refit on the refined mesh moves E by many standard deviations and the
command must warn, saying by how many. Hanging along its axis (gravity along x, where P1 tets are
nearly exact: E is 2 % low on the coarse mesh) with noise the size of the motion: the same kind
of shift is within the standard deviation and it must not warn.
"""

from pathlib import Path

import numpy as np
import pytest
from _taper import taper, write_taper_mesh
from mpi4py import MPI

import petsoft
from petsoft.calibration.refinement import (
    MESH_HALVED,
    ORDER_RAISED,
    REFINEMENTS,
    STEP_HALVED,
    levels_needed,
    mesh_cells,
    why_not,
)
from petsoft.calibration.synth import SynthOptions, synth
from petsoft.experiment import experiment_from_dict, load_experiment
from petsoft.physics.model import load_mesh

TRUE_E = 2.0e7


def _cal(lo, hi):
    return f'[calibrate]\n"material.youngs_modulus" = [{lo}, {hi}]\n'


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    comm = MPI.COMM_WORLD
    d = Path(comm.bcast(str(tmp_path_factory.mktemp("check_mesh")) if comm.rank == 0 else None))
    axial = dict(step=0.002, gravity=(9.81, 0.0, 0.0))
    if comm.rank == 0:
        write_taper_mesh(d / "taper.msh")
        # the first 0.1 s: the bar's first swing, where the coarse mesh's stiffness shows most
        (d / "bend.toml").write_text(taper(TRUE_E, end=0.1))
        (d / "user_bend.toml").write_text(taper(1.8e7, end=0.1, calibrate=_cal(1e6, 1e8)))
        (d / "axial.toml").write_text(taper(2e5, **axial))
        (d / "user_axial.toml").write_text(taper(1.8e5, **axial, calibrate=_cal(1e4, 1e7)))
    comm.Barrier()
    recs = {}
    for name, noise in (("bend", 5e-5), ("axial", 4e-3)):
        recs[name] = d / name / "rec.h5"
        synth(load_experiment(d / f"{name}.toml"),
              SynthOptions(out=recs[name], noise=noise, markers=8, refine=2, seed=7))
    comm.Barrier()
    return {"dir": d, "rec": recs, "user": load_experiment(d / "user_bend.toml"),
            "user_axial": load_experiment(d / "user_axial.toml")}


def test_the_refined_experiment_is_a_value_that_reads_back(case):
    user = case["user"]
    fine = MESH_HALVED.make(user)
    assert fine.mesh.refine == 1 and fine.mesh.file == user.mesh.file
    assert experiment_from_dict(fine.to_dict(), source="back").mesh == fine.mesh
    assert mesh_cells(user) == 192 and mesh_cells(fine) == 1536 == MESH_HALVED.cells(user)
    assert len(load_mesh(fine).tets) == 1536
    assert STEP_HALVED.make(user).time.step == user.time.step / 2
    assert [r.label for r in REFINEMENTS] == ["step/2", "mesh x2", "P2"]
    assert why_not(MESH_HALVED, fine, 6000, "diagnose's") == (
        "the refined mesh would have 12288 tets, over diagnose's limit of 6000")
    assert why_not(MESH_HALVED, user, 6000) is None
    # Richardson factors: P1 displacements converge as h^2 -> error 4/3 and 1/3 of the change
    assert MESH_HALVED.error_factors(user) == pytest.approx((4 / 3, 1 / 3))
    # 10-node elements on the same mesh: the experiment reads back with order 2; they cost the
    # nodes of the 1->8 refined P1 mesh; the whole change is the P1 model's error
    quadratic = ORDER_RAISED.make(user)
    assert quadratic.mesh.order == 2 and quadratic.mesh.refine == 0
    assert experiment_from_dict(quadratic.to_dict(), source="back").mesh == quadratic.mesh
    assert load_mesh(quadratic).order == 2 and len(load_mesh(quadratic).tets) == 192
    assert ORDER_RAISED.error_factors(user) == (1.0, 0.0)
    assert why_not(ORDER_RAISED, user, 6000) is None
    assert why_not(ORDER_RAISED, quadratic, 6000) == ("the elements are already quadratic "
                                                      "(order 2)")
    assert why_not(ORDER_RAISED, fine, 6000, "diagnose's") == (
        "10-node tetrahedra on 1536 tets have as many nodes as 12288 4-node ones, over "
        "diagnose's limit of 6000")
    # the mesh refinement of a 10-node model converges as h^3 and costs 8x the nodes
    assert MESH_HALVED.error_factors(quadratic) == pytest.approx((8 / 7, 1 / 7))
    assert why_not(MESH_HALVED, quadratic, 6000, "diagnose's") == (
        "the refined mesh of 10-node tetrahedra would have as many nodes as 12288 4-node ones, "
        "over diagnose's limit of 6000")
    assert levels_needed(0.5) == 0 and levels_needed(3.0) == 1 and levels_needed(5.0) == 2


def test_markers_stay_at_the_same_material_points_on_the_refined_mesh(case):
    """Synth's markers are nodes of the user's mesh, named by node id in truth.json: the same
    ids name the same points of the refined mesh (its original nodes keep their numbers)."""
    import json

    rec = petsoft.read_recording(case["rec"]["bend"])
    truth = json.loads((case["rec"]["bend"].parent / "truth.json").read_text())
    user = case["user"]
    nodes = []
    for exp in (user, MESH_HALVED.make(user)):
        mesh = load_mesh(exp)
        dist = np.linalg.norm(mesh.points[None] - rec.reference[:, None], axis=2)
        nodes.append(dist.argmin(axis=1))
        assert dist.min(axis=1).max() < 1e-12         # every marker sits on a node
    np.testing.assert_array_equal(nodes[0], nodes[1])  # the same node numbers
    np.testing.assert_array_equal(nodes[0], truth["markers"]["nodes"])


def test_check_mesh_warns_when_refining_moves_the_parameter_beyond_its_std(case):
    lines = []
    res = petsoft.calibrate(case["user"], case["rec"]["bend"], gradient="sensitivity",
                            check_mesh=True, say=lines.append)
    check = res.mesh_check
    assert check["done"] and "192 -> 1536 tets" in check["how"]
    shift = check["shift_sigmas"]["material.youngs_modulus"]
    E0, E1 = res.values[0], check["values"]["material.youngs_modulus"]
    assert shift == pytest.approx((E1 - E0) / res.std[0])
    assert abs(shift) > 1.0
    assert abs(E1 / TRUE_E - 1) < abs(E0 / TRUE_E - 1)        # the refined mesh is closer
    assert any(f"moves material.youngs_modulus by {abs(shift):.3g} standard deviations" in w
               for w in check["warnings"]), check["warnings"]
    if MPI.COMM_WORLD.rank == 0:
        assert any(line.startswith("warning: refining the mesh (every tet split 1->8")
                   for line in lines)
    # 10-node elements on the same mesh: bending stiffness removed the same way, a larger move
    # (the truth here is P1 refined twice, itself 12 % stiff: E2 overshoots TRUE_E)
    order = check["order"]
    assert order["done"] and "10-node tetrahedra on the same 192 tets" in order["how"]
    E2 = order["values"]["material.youngs_modulus"]
    assert E2 > E1 > E0 and order["shift_sigmas"]["material.youngs_modulus"] > 1.0
    assert any(w.startswith("raising the elements to order 2") and "[mesh] order = 2" in w
               for w in order["warnings"]), order["warnings"]


@pytest.mark.serial_only      # a second calibration + check (~10 s serial): once is enough
def test_check_mesh_is_quiet_when_the_shift_is_within_the_std(case):
    res = petsoft.calibrate(case["user_axial"], case["rec"]["axial"], gradient="sensitivity",
                            check_mesh=True)
    check = res.mesh_check
    assert check["done"]
    E0, E1 = res.values[0], check["values"]["material.youngs_modulus"]
    assert 0.003 < E1 / E0 - 1 < 0.05             # it moved, but by less than its std
    assert abs(check["shift_sigmas"]["material.youngs_modulus"]) < 1.0
    assert check["warnings"] == []


@pytest.mark.serial_only      # the same fit as above through the command line: once is enough
def test_the_command_line_flag_writes_the_check_to_the_summary(case, capsys):
    import json

    from petsoft.cli.main import main

    out = case["dir"] / "cli"
    assert main(["calibrate", str(case["dir"] / "user_bend.toml"), str(case["rec"]["bend"]),
                 "--gradient", "sensitivity", "--check-mesh", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "warning: refining the mesh (every tet split 1->8: 192 -> 1536 tets) moves " \
           "material.youngs_modulus by" in printed
    check = json.loads((out / "summary.json").read_text())["mesh_check"]
    assert check["done"] and check["shift_sigmas"]["material.youngs_modulus"] > 1.0
