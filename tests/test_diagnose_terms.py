"""`petsoft diagnose` end to end for every term of the physics vocabulary (issue 36, item 3).

One small case per term of :data:`petsoft.diagnosis.report.PHYSICS` and a control: a *truth*
experiment with the term, recorded by ``petsoft synth --refine 2`` (the mesh's cells doubled
along every axis, the step halved: the truth is not the user's discretisation), 8 random
surface markers, 0.1 mm position noise, 10 % of the samples dropped; the *user's* model is the
truth without the term, Young's modulus 10 % low, calibrating E only. ``run_diagnose`` runs as a
user runs it (numerics check on, every default): the test asserts that the concealed term is the
one term added and that the final verdict is ``consistent``; the control must add nothing.

The body is the small cantilever of the other diagnose tests (0.3 x 0.04 x 0.04 m, 6 x 1 x 1 box
cells, generalized-alpha r = 0.9 at 4 ms over 0.2 s, released under gravity), with 10-node
tetrahedra in both models: on 4-node ones one cell across, the user's mesh is far from the truth
and every case would first be a mesh diagnosis (tests/test_diagnose_file_mesh.py covers that).
The 10-node user mesh differs from the refined truth by a fraction of the noise once E is
refitted (the control: chi2/dof 1.04); at 0.05 mm noise it did not (chi2/dof 1.3, and with the
weak stiff-inclusion signal a spurious added mass was named), hence 0.1 mm. Where a term needs
a motion to show, the case says which (a flat bar swung both ways for the terms that a single
bending mode confuses with mass damping, a larger swing for the nonlinear law). Every case uses
the same seed (3), not chosen by outcome. The effect sizes were set while writing the cases, and
what the first tries gave is said here: a stiffness damping of 2e-4 s on the square bar was not
named at this noise and 5e-4 s was named damping.mass (hence the flat bar); a stiff inclusion
of 2x E was named with a spurious added mass at 0.05 mm noise (hence 4x); the nonlinear swing
60 x^2 (the benchmark's) was found but took minutes (hence 20 x^2); the floor over 0.2 s was
named with a spurious gravity (hence 0.12 s, which is also faster). The others are the
benchmark's values (scripts/benchmarks/bench_diagnose.py) and passed at the first try, as did
``gravity.direction`` (the truth's gravity turned sideways at its size, tilt_b = 0.3: 17 degrees;
chi2/dof 27 -> 0.98).

Two terms fail the test on a case this small; they are ``xfail(strict=True)`` with what was
observed (:data:`NOT_FOUND`): a compliant clamp is named together with a soft region at the clamp
(the benchmark's compliance case, scripts/benchmarks/bench_diagnose.py, also names a stiffness
region for it), and a floor is named alone but the penalty impact leaves the final fit far from
the noise (the benchmark's contact case ends at 2.2x the noise on the held-out window).
With seed 4 instead of 3 (checked once, not kept), the ten other terms and the control passed
as here, compliance named the same pair and the floor was not named.

Runtime: serially 237 s for the fourteen items under a load average of ~8 on the 2-core machine
(the slowest: material.nonlinear 48 s, damping.stiffness 41 s, friction.dry and contact.plane
28 s each), 177 s at a load of ~6; a quiet machine should take a fraction of that. On 2 ranks
(the control, gravity, material.heterogeneous) 89 s under a load of ~8.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.synth import SynthOptions, synth
from petsoft.diagnosis.diagnose import run_diagnose
from petsoft.diagnosis.report import PHYSICS
from petsoft.experiment import dumps_toml, load_experiment

E_TRUE, NOISE, SEED = 2.0e7, 1e-4, 3

BASE = {
    "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 1, 1]}, "order": 2},
    "material": {"model": "linear", "youngs_modulus": E_TRUE, "poisson_ratio": 0.3,
                 "density": 1000.0},
    "gravity": {"acceleration": [0.0, 0.0, -9.81]},
    "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
    "time": {"end": 0.2, "step": 0.004, "integrator": "alpha", "alpha_radius": 0.9},
    "output": {"directory": "out"},
}

#: A flat bar (0.04 wide, 0.02 thick) swung both ways: its two bending frequencies differ by 2x.
#: A mass damping damps a mode at a rate independent of its frequency, a stiffness damping at a
#: rate growing with it, and surface drag per unit mass is larger across the thin way; on the
#: square bar's one swinging mode these laws give the same decay and are confused (seen: a
#: stiffness damping of 5e-4 s named as damping.mass).
FLAT = {"mesh": {"box": {"size": [0.3, 0.04, 0.02]}},
        "initial": {"velocity": ["0", "3*x*x", "6*x*x"]}}


def _sphere(center, radius) -> str:
    x, y, z = center
    return f"(x - {x})**2 + (y - {y})**2 + (z - {z})**2 < {radius}**2"


#: term -> edits of both models, of the truth only, of the user's model only
CASES: dict[str, dict] = {
    "control": {},
    "damping.mass": {"truth": {"damping": {"mass": 4.0}}},
    "damping.stiffness": {"both": FLAT, "truth": {"damping": {"stiffness": 5e-4}}},
    "gravity": {"user": {"gravity": {"acceleration": [0.0, 0.0, 0.0]}}},
    # gravity stated straight down, the truth's turned sideways by 17 degrees at the same size
    "gravity.direction": {"truth": {"gravity": {"tilt_b": 0.3}}},
    "drag.linear": {"both": FLAT, "truth": {"drag": {"linear": 80.0}}},
    "drag.quadratic": {"both": FLAT, "truth": {"drag": {"quadratic": 300.0}}},
    "friction.dry": {"truth": {"friction": {"dry": 1.0, "speed": 0.003}}},
    # a sphere four times stiffer at the clamp
    "material.heterogeneous": {"truth": {
        "region": {"stiff": {"where": _sphere([0.05, 0.02, 0.02], 0.05)}},
        "material": {"stiff": {"youngs_modulus": 4 * E_TRUE}}}},
    # a sphere four times denser at the tip
    "mass.added": {"truth": {
        "region": {"heavy": {"where": _sphere([0.275, 0.02, 0.02], 0.03)}},
        "material": {"heavy": {"density": 4000.0}}}},
    "material.viscoelastic": {"truth": {"viscoelastic": {"ratio": 0.3,
                                                         "relaxation_time": 0.015}}},
    # a corotated truth swung up to a tip deflection of ~30 mm (a tenth of the length)
    "material.nonlinear": {"both": {"initial": {"velocity": ["0", "0", "20*x*x"]}},
                           "truth": {"material": {"model": "corotated"}}},
    "boundary.compliance": {"truth": {"boundary": [
        {"kind": "fixed", "where": "x < 1e-9", "compliance": 2e-9}]}},
    # swung down into a floor 12 mm below, with the stiffness damping a soft solid has (known
    # to the user) so that the impact's high modes do not ring on; 0.12 s (two impacts)
    "contact.plane": {"both": {"damping": {"stiffness": 2e-4},
                               "initial": {"velocity": ["0", "0", "-18*x*x"]},
                               "time": {"end": 0.12}},
                      "truth": {"collider": [{"kind": "plane", "point": [0.0, 0.0, -0.012],
                                              "normal": [0.0, 0.0, 1.0]}]}},
}


def _merge(data: dict, edits: dict) -> dict:
    out = copy.deepcopy(data)
    for k, v in edits.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _models(name: str) -> tuple[dict, dict]:
    """(truth, user) experiment dicts of one case."""
    case = CASES[name]
    both = _merge(BASE, case.get("both", {}))
    truth = _merge(both, case.get("truth", {}))
    user = _merge(both, case.get("user", {}))
    user["material"]["youngs_modulus"] = 0.9 * E_TRUE
    user["calibrate"] = {"material.youngs_modulus": [1e6, 1e8]}
    return truth, user


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    comm = MPI.COMM_WORLD
    return Path(comm.bcast(str(tmp_path_factory.mktemp("terms")) if comm.rank == 0 else None))


def _diagnose(folder: Path, name: str):
    """Record the case's truth with ``petsoft synth --refine 2`` and diagnose the user's model
    against it (all ranks); prints the outcome (``-s`` shows it)."""
    comm = MPI.COMM_WORLD
    d = folder / name
    truth, user = _models(name)
    if comm.rank == 0:
        d.mkdir(parents=True, exist_ok=True)
        (d / "truth.toml").write_text(dumps_toml(truth))
        (d / "user.toml").write_text(dumps_toml(user))
    comm.Barrier()
    t0 = time.perf_counter()
    synth(load_experiment(d / "truth.toml"),
          SynthOptions(out=d / "rec.h5", noise=NOISE, markers=8, dropout=0.1, refine=2,
                       seed=SEED))
    comm.Barrier()
    res = run_diagnose(load_experiment(d / "user.toml"), d / "rec.h5", out=None,
                       comm=PETSc.COMM_WORLD)
    fit = res.report["fit"]
    if comm.rank == 0:
        print(f"\n{name}: named {[a['physics'] for a in res.added]}, verdict {res.verdict} -> "
              f"{res.final_verdict}, chi2/dof {fit['base']['chi2_per_dof']:.3g} -> "
              f"{fit['final']['chi2_per_dof']:.3g}, {time.perf_counter() - t0:.1f} s")
    return res


def _named(res) -> list[str]:
    return [a["physics"] for a in res.added]


def test_every_vocabulary_term_has_a_case():
    assert set(CASES) - {"control"} == set(PHYSICS)


def test_control_names_nothing(folder):
    res = _diagnose(folder, "control")
    assert res.verdict == "consistent", res.report["fit"]
    assert _named(res) == [] and res.final_verdict == "consistent"
    E = res.final.values[res.final.names.index("material.youngs_modulus")]
    assert E == pytest.approx(E_TRUE, rel=0.05)


#: Terms diagnosed on 2 ranks too (with the control): a term of values and a spatial term,
#: whose sphere is placed from the adjoint per-cell map gathered over the ranks (damping.mass
#: runs on 2 ranks in tests/test_diagnose.py). The others are serial_only: on 2 ranks of the
#: loaded 2-core machine a case took 3-7x its serial time (damping.mass 37 s vs 12 s,
#: material.viscoelastic 43 s vs 12 s, material.heterogeneous 58 s vs 8 s, under load).
PARALLEL = {"gravity", "material.heterogeneous"}

#: Terms not found on a case this small: what was observed instead (seed 3, as here).
NOT_FOUND: dict[str, str] = {
    "boundary.compliance": (
        "named material.heterogeneous (a soft sphere at the clamp, E 8.3 MPa) first and "
        "boundary.compliance second: round 1 scores 960 vs 813, fitted chi2 915 vs 1268 (785 "
        "dof); final consistent. A soft root and a compliant clamp bend the bar alike, and the "
        "compliant truth is mesh-sensitive (refine 1 vs 2 at the truth's values: 3.2e-4 m rms, "
        "rigid 0.94e-4 m). At compliance 5e-10 nothing was named (E absorbed it), at 1e-8 the "
        "same pair; with seed 4 the same pair"),
    "contact.plane": (
        "named contact.plane alone (its offset fitted 2.9 mm above the true floor), but the "
        "final verdict stays missing-physics at chi2/dof 315 -> 27.3: with the plane, halving "
        "the step or refining the mesh changes the refitted simulation by 8x / 7x the noise "
        "and neither comes closer to the data (chi2/dof 37 / 100), so none is adopted; the "
        "penalty impact (4 m/h^2 per node) is not the refined truth's on this mesh and step; "
        "with seed 4's markers the plane was not named (material.nonlinear and damping.mass, "
        "chi2/dof 94.5 -> 88.5)"),
}


def _param(term: str):
    marks = [] if term in PARALLEL else [pytest.mark.serial_only]
    if term in NOT_FOUND:
        marks.append(pytest.mark.xfail(strict=True, reason=NOT_FOUND[term]))
    return pytest.param(term, marks=marks, id=term)


@pytest.mark.parametrize("term", [_param(t) for t in PHYSICS])
def test_the_concealed_term_is_named_alone(folder, term):
    res = _diagnose(folder, term)
    assert res.verdict == "missing-physics"
    assert _named(res) == [term], (term, res.added, res.report["fit"])
    assert res.final_verdict == "consistent", res.report["fit"]
