"""The foundation term end to end, as petsoft's registry finds it (run with the package installed:
petsoft's tests/test_package_terms.py installs it into a scratch prefix and runs this file).

The body is the small cantilever of petsoft's diagnose tests (0.3 x 0.04 x 0.04 m, 6 x 1 x 1 box
cells, fixed at x = 0) resting on the foundation under its bottom face z = 0, released under
gravity with its tip swung upward, so that it both lifts off the bed (tension) and presses into
it (compression).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.calibrate import run_calibration
from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.calibration.synth import SynthOptions, synth
from petsoft.diagnosis.diagnose import run_diagnose
from petsoft.diagnosis.report import PHYSICS
from petsoft.errors import ExperimentError
from petsoft.experiment import (
    dumps_toml,
    experiment_from_dict,
    get_parameter,
    load_experiment,
    parameter_names,
    with_parameters,
)
from petsoft.terms import PLUGINS, TERMS

E, KC, KT = 2.0e7, 2.0e5, 2.0e4
BASE = {
    "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 1, 1]}, "order": 2},
    "material": {"model": "linear", "youngs_modulus": E, "poisson_ratio": 0.3,
                 "density": 1000.0},
    "gravity": {"acceleration": [0.0, 0.0, -9.81]},
    "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
    "initial": {"velocity": ["0", "0", "10*x*x"]},
    "time": {"end": 0.2, "step": 0.004, "integrator": "alpha", "alpha_radius": 0.9},
    "output": {"directory": "out"},
}
FOUNDATION = {"compression": KC, "tension": KT}   # under the faces facing -z
MARKERS = np.array([[0.3, 0.02, 0.02], [0.2, 0.0, 0.04], [0.1, 0.04, 0.0]])


def _experiment(order=2, **edits) -> dict:
    data = copy.deepcopy(BASE)
    data["mesh"]["order"] = order
    data.update(copy.deepcopy(edits))
    return data


def test_the_registry_holds_the_term():
    assert "foundation.bilinear" in TERMS and "foundation.bilinear" in PHYSICS
    assert PLUGINS["foundation.bilinear"].package == "petsoft-foundation"


def test_read_and_refused_with_clear_errors():
    exp = experiment_from_dict(_experiment(foundation={"compression": 1e5, "where": "z < 1e-9"}))
    values = exp.terms["foundation"]
    assert values["compression"] == 1e5 and values["tension"] == 0.0
    assert values["direction"] == (0.0, 0.0, -1.0)
    assert "foundation.compression" in parameter_names(exp)
    moved = with_parameters(exp, {"foundation.tension": 3e4})
    assert get_parameter(moved, "foundation.tension") == 3e4
    assert experiment_from_dict(moved.to_dict()) == moved
    assert "foundation.compression" not in parameter_names(experiment_from_dict(_experiment()))
    for table, words in [({"compresion": 1.0}, "did you mean foundation.compression"),
                         ({"tension": -1.0},
                          "foundation.tension = -1.0 is out of range: valid is tension >= 0"),
                         ({"direction": [0.0, 1.0]}, "expected an array of 3 numbers")]:
        with pytest.raises(ExperimentError, match=words):
            experiment_from_dict(_experiment(foundation=table))


#: The schemes whose sensitivities are checked: be (P1 and P2), and on P1 the semi-implicit
#: step (its derivative carries the Hessian's action on w) and generalized-alpha.
SCHEMES = [(1, "be"), (2, "be"), (1, "si"), (1, "alpha")]


@pytest.mark.parametrize("order, integrator", SCHEMES)
def test_simulated_and_differentiated(order, integrator):
    """The foundation moves the tip (the bar swings up off the bed, whose tension pulls it
    back); the forward model's exact sensitivities in k_c, k_t agree with central differences
    and the adjoint gradient with the sensitivities."""
    exp = experiment_from_dict(_experiment(order, foundation=FOUNDATION,
                                           time={"end": 0.04, "step": 0.004,
                                                 "integrator": integrator}))
    names = ["foundation.compression", "foundation.tension"]
    fm = ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), [0.02, 0.04],
                      comm=PETSc.COMM_WORLD)
    weights = np.random.default_rng(2).standard_normal((2, len(MARKERS), 3))
    try:
        p = fm.p0.copy()
        sim, jac = fm.jacobian(p)
        fd = fm.fd_jacobian(p, rel_step=1e-6)
        off = fm.simulate(np.zeros(2))
        _, grad = fm.gradient(p, lambda x: (float(np.sum(weights * x)), weights))
    finally:
        fm.destroy()
    # the tip (marker 0) at 40 ms: moved by the bed by more than a noise level (0.1 mm)
    assert abs(off[-1, 0, 2] - sim[-1, 0, 2]) > 1e-4, (off[-1, 0], sim[-1, 0])
    np.testing.assert_allclose(grad, np.einsum("kmc,kmcp->p", weights, jac), rtol=1e-8)
    for j, name in enumerate(names):
        scale = np.abs(jac[..., j]).max()
        err = np.abs(jac[..., j] - fd[..., j]).max() / scale
        print(f"P{order} {integrator} {name}: |d sim/dp| {scale:.3e}, relative difference to "
              f"central differences {err:.2e}")
        assert scale > 0.0 and err < 1e-4, (name, err)


def _write(path, data: dict) -> None:
    """Write an experiment file on rank 0; every rank then reads it."""
    comm = MPI.COMM_WORLD
    if comm.rank == 0:
        path.write_text(dumps_toml(data))
    comm.Barrier()


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A recording of the bar on its foundation (the truth) as petsoft's diagnose tests make
    theirs: ``petsoft synth --refine 2`` (cells and step halved: the truth is not the user's
    discretisation), 8 random surface markers, 0.1 mm noise, 10 % of the samples dropped, seed
    3; with its folder (rank 0's, shared by every rank)."""
    comm = MPI.COMM_WORLD
    d = Path(comm.bcast(str(tmp_path_factory.mktemp("foundation")) if comm.rank == 0 else None))
    _write(d / "truth.toml", _experiment(foundation=FOUNDATION))
    synth(load_experiment(d / "truth.toml"),
          SynthOptions(out=d / "rec.h5", noise=1e-4, markers=8, dropout=0.1, refine=2, seed=3))
    comm.Barrier()
    return d


def test_calibrated_back(recording):
    """k_c and k_t start 2x off and are fitted back from the recording made with them."""
    user = _experiment(foundation={**FOUNDATION, "compression": 2 * KC, "tension": 0.5 * KT},
                       calibrate={"foundation.compression": [0.0, 1e7],
                                  "foundation.tension": [0.0, 1e7]})
    _write(recording / "cal.toml", user)
    res = run_calibration(load_experiment(recording / "cal.toml"), recording / "rec.h5",
                          out=recording / "cal", comm=PETSc.COMM_WORLD)
    values = dict(zip(res.names, res.values, strict=True))
    print(f"calibrated {values} (truth k_c {KC:g}, k_t {KT:g})")
    assert values["foundation.compression"] == pytest.approx(KC, rel=0.1)
    assert values["foundation.tension"] == pytest.approx(KT, rel=0.3)
    # the user's file with the calibrated values in its [foundation] table (rank 0 wrote it)
    MPI.COMM_WORLD.Barrier()
    written = load_experiment(recording / "cal" / "calibrated.toml").terms["foundation"]
    assert written["compression"] == pytest.approx(values["foundation.compression"])


def test_diagnose_names_it(recording):
    """The user's model without the foundation (E 10 % low, calibrated), diagnosed as a user
    runs it (every default, the numerics check on): the foundation is named alone and the
    final model is consistent with the data."""
    user = _experiment(calibrate={"material.youngs_modulus": [1e6, 1e8]})
    user["material"]["youngs_modulus"] = 0.9 * E
    _write(recording / "user.toml", user)
    res = run_diagnose(load_experiment(recording / "user.toml"), recording / "rec.h5",
                       out=None, comm=PETSc.COMM_WORLD)
    named = [a["physics"] for a in res.added]
    print(f"named {named}, verdict {res.verdict} -> {res.final_verdict}, "
          f"{dict(zip(res.names, res.values, strict=True))}")
    assert res.verdict == "missing-physics"
    assert named == ["foundation.bilinear"], (res.added, res.scores)
    assert res.final_verdict == "consistent", res.report["fit"]
