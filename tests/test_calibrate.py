"""`petsoft calibrate` end to end on a tiny bar: recovery, uncertainty, outputs, errors, ranks.

The recordings here are made on the calibration mesh itself (an inverse crime, on purpose: these
tests check the pipeline, where the answer must then be the truth to the noise level). Recovery
from refined-mesh data is measured by scripts/examples/demo_calibrate_bar.py.
"""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from child_process import child_env  # tests/child_process.py
from mpi4py import MPI

from petsoft.calibration.calibrate import run_calibration
from petsoft.calibration.synth import SynthOptions, synth
from petsoft.calibration.uncertainty import uncertainty
from petsoft.errors import ExperimentError
from petsoft.experiment import get_parameter, load_experiment

TRUTH = {"material.youngs_modulus": 1.0e6, "damping.mass": 3.0}

EXPERIMENT = """
[mesh]
box = {{ size = [0.2, 0.04, 0.04], cells = [5, 1, 1] }}

[material]
model = "linear"
youngs_modulus = {E}
poisson_ratio = 0.3
density = 1000.0

[damping]
mass = {alpha}

[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[initial]
displacement = ["0.002*sin(pi*x/0.4)", "0", "0"]

[time]
end = 0.03
step = 0.001
integrator = "alpha"
alpha_radius = 0.9

[petsc]
ksp_type = "preonly"
pc_type = "lu"
{calibrate}
"""

CALIBRATE = """
[calibrate]
"material.youngs_modulus" = [1.0e5, 1.0e7]
"damping.mass" = [0.0, 20.0]
"""

NOISE = 1e-6


def _shared_dir(tmp_path_factory, name):
    comm = MPI.COMM_WORLD
    return Path(comm.bcast(str(tmp_path_factory.mktemp(name)) if comm.rank == 0 else None))


def _write(path, text):
    if MPI.COMM_WORLD.rank == 0:
        path.write_text(text)
    MPI.COMM_WORLD.Barrier()
    return path


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = _shared_dir(tmp_path_factory, "calibrate")
    truth = _write(d / "truth.toml", EXPERIMENT.format(E=TRUTH["material.youngs_modulus"],
                                                      alpha=TRUTH["damping.mass"], calibrate=""))
    rec = d / "rec.h5"
    synth(load_experiment(truth), SynthOptions(out=rec, noise=NOISE, markers=6, dropout=0.1,
                                               refine=1, seed=5))
    start = _write(d / "start.toml", EXPERIMENT.format(E=1.15e6, alpha=1.0, calibrate=CALIBRATE))
    return d, rec, start


def test_recovers_truth_with_consistent_uncertainty(case):
    d, rec, start = case
    exp = load_experiment(start)
    lines = []
    res = run_calibration(exp, rec, method="gauss-newton", out=d / "gn", say=lines.append)
    values = dict(zip(res.names, res.values, strict=True))
    std = dict(zip(res.names, res.std, strict=True))
    for name, true in TRUTH.items():
        # on the calibration mesh the only error is the noise: within 5 standard deviations
        assert abs(values[name] - true) < 5 * std[name], (name, values[name], std[name])
        assert 0 < std[name] < 0.01 * true
    assert res.rms_before > 20 * NOISE
    assert res.rms_after < 1.5 * NOISE
    assert abs(res.noise_estimate / NOISE - 1) < 0.2   # the fit's residual is the noise
    assert res.reason.startswith("CONVERGED")
    if MPI.COMM_WORLD.rank == 0:
        assert any(line.lstrip().startswith("it ") for line in lines)   # progress per iteration
        assert any("material.youngs_modulus" in line and "[1e+05, 1e+07]" in line
                   for line in lines)                                    # the result table
        summary = json.loads((d / "gn" / "summary.json").read_text())
        assert summary["command"] == "calibrate"
        assert summary["parameters"]["damping.mass"] == pytest.approx(values["damping.mass"])
        assert summary["rms_after"] < summary["rms_before"]
        for f in ("trajectories.png", "residuals.png", "calibrated.toml"):
            assert (d / "gn" / f).stat().st_size > 0
    MPI.COMM_WORLD.Barrier()
    calibrated = load_experiment(d / "gn" / "calibrated.toml")
    assert get_parameter(calibrated, "material.youngs_modulus") == pytest.approx(
        values["material.youngs_modulus"], rel=1e-12)


@pytest.mark.parametrize("method, gradient", [("lbfgs", "adjoint"), ("gauss-newton", "fd")])
def test_other_methods_and_gradients_agree(case, method, gradient):
    d, rec, start = case
    exp = load_experiment(start)
    ref = run_calibration(exp, rec, method="gauss-newton")
    res = run_calibration(exp, rec, method=method, gradient=gradient)
    np.testing.assert_allclose(res.values, ref.values, rtol=2e-4)


def test_random_starts_are_fitted_and_the_best_is_the_result(case):
    """``starts=2``: the user's start and two random ones in the bounds (on groups of ranks),
    each fitted; the result is the best of them, every start's outcome is in
    ``result.starts``, and the user's start reaches the one-start fit (the random ones here
    stop in worse minima at the bounds: damping trades against stiffness on a 30 ms record)."""
    d, rec, start = case
    exp = load_experiment(start)
    one = run_calibration(exp, rec, method="gauss-newton")
    many = run_calibration(exp, rec, method="gauss-newton", starts=2, seed=3)
    assert [s["index"] for s in many.starts] == [0, 1, 2]
    assert many.starts[0]["start"] == pytest.approx([1.15e6, 1.0])    # the user's own start
    assert all(s["error"] == "" for s in many.starts)
    assert len({tuple(s["start"]) for s in many.starts}) == 3
    best = min(many.starts, key=lambda s: s["objective"])
    assert many.objective_after == pytest.approx(best["objective"], rel=1e-12)
    np.testing.assert_allclose(many.values, best["parameters"], rtol=1e-12)
    assert many.starts[0]["objective"] == pytest.approx(one.objective_after, rel=1e-6)
    np.testing.assert_allclose(many.starts[0]["parameters"], one.values, rtol=2e-4)


def test_nothing_to_calibrate_and_frames_before_zero(case, tmp_path_factory):
    d, rec, start = case
    exp = load_experiment(d / "truth.toml")
    with pytest.raises(ExperimentError, match=r"nothing to calibrate.*\[calibrate\]"):
        run_calibration(exp, rec)
    from petsoft.io.recording import read_recording
    r = read_recording(rec)
    shifted = _shared_dir(tmp_path_factory, "shifted") / "rec.h5"
    if MPI.COMM_WORLD.rank == 0:
        r.times = r.times - 0.005
        r.write(shifted)
    MPI.COMM_WORLD.Barrier()
    with pytest.raises(ExperimentError, match=r"first frame is at t = -0.005 s"):
        run_calibration(load_experiment(start), shifted)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns processes")
def test_command_line_one_and_two_ranks_agree(case):
    d, rec, start = case
    out = {}
    for n in (1, 2):
        cmd = [sys.executable, "-m", "petsoft.cli.main", "calibrate", str(start), str(rec),
               "--out", str(d / f"cli{n}")]
        if n == 2:
            cmd = [shutil.which("mpiexec") or "mpiexec", "-n", "2"] + cmd
        run = subprocess.run(cmd, capture_output=True, text=True, env=child_env(), timeout=600)
        assert run.returncode == 0, run.stderr
        assert "rms position error" in run.stdout
        out[n] = json.loads((d / f"cli{n}" / "summary.json").read_text())
    assert out[2]["ranks"] == 2
    for name in TRUTH:
        assert out[2]["parameters"][name] == pytest.approx(out[1]["parameters"][name], rel=1e-6)
    bad = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "calibrate", str(start),
                          str(d / "missing.h5")], capture_output=True, text=True, env=child_env())
    assert bad.returncode == 2 and "missing.h5" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns processes")
def test_recovery_demo_quick(tmp_path):
    """scripts/examples/demo_calibrate_bar.py --quick: both cases run, the table and
    recovery.json are written, and even on its 6x1x1 mesh E lands within 5 % (region E within
    15 %)."""
    script = Path(__file__).resolve().parents[1] / "scripts" / "examples" / "demo_calibrate_bar.py"
    run = subprocess.run([sys.executable, str(script), "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, env=child_env(), timeout=600)
    assert run.returncode == 0, run.stderr
    assert "all within target" in run.stdout
    rows = json.loads((tmp_path / "recovery.json").read_text())
    assert {r["case"] for r in rows} == {"bar", "regions"}
    errors = {(r["case"], r["parameter"]): r["error"] for r in rows}
    assert abs(errors[("bar", "material.youngs_modulus")]) < 0.05
    for (case, name), err in errors.items():
        if case == "regions":
            assert abs(err) < 0.15, (name, err)
    assert (tmp_path / "bar" / "calibrated" / "calibrated.toml").is_file()


def test_residual_plot_axis_survives_an_exactly_zero_frame(tmp_path, monkeypatch):
    """A noise-free recording matches the simulation exactly at t = 0; the log axis of the
    residual-over-time panel must still show the residual's decades, not 1e-300..1e-4."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from petsoft.calibration import plots

    t = np.linspace(0.0, 0.1, 51)
    data = np.zeros((51, 3, 3))
    after = 1e-5 * np.sin(40 * t)[:, None, None] * np.ones((1, 3, 3))
    after[0] = 0.0
    limits = []
    monkeypatch.setattr(plt.Figure, "savefig",
                        lambda fig, *a, **k: limits.append(fig.axes[0].get_ylim()))
    plots.plot_residuals(tmp_path / "r.png", t, data, 10 * after, after, ["a", "b", "c"], 2e-6)
    low, high = limits[0]
    assert high / low < 1e6, (low, high)


def test_calibration_figures_draw_millimetres(tmp_path):
    """Positions and residuals in mm, as the diagnosis' figures: the drawn arrays are 1e3 x the
    metres, the most-moving marker first."""
    import matplotlib

    matplotlib.use("Agg")
    from petsoft.calibration import plots

    t = np.linspace(0.0, 0.1, 51)
    data = np.zeros((51, 2, 3))
    data[:, 1, 2] = 2e-3 * np.sin(40 * t)                 # marker 1 moves 2 mm along z
    after = data + 1e-5
    drawn = plots.plot_trajectories(tmp_path / "t.png", t, data, None, after, ["a", "b"], 1)
    assert drawn["picks"] == [(1, 2)]
    np.testing.assert_allclose(drawn["recorded_mm"][:, 0], 1e3 * data[:, 1, 2])
    res = plots.plot_residuals(tmp_path / "r.png", t, data, data + 1e-3, after, ["a", "b"],
                               1e-5)
    np.testing.assert_allclose(res["per_marker_mm"]["before"], [1.0, 1.0])
    np.testing.assert_allclose(res["per_marker_mm"]["calibrated"], [0.01, 0.01])
    assert res["noise_mm"] == pytest.approx(0.01)


def test_observations_hold_the_window_checks_and_the_noise_policy():
    """The recording's /noise wins over the given noise (which must be a positive number),
    which wins over estimating it; the window keeps frames up to [time] end and rejects frames
    before t = 0 and position-less data."""
    from petsoft.calibration.calibrate import (
        BY_CALLER,
        BY_RECORDING,
        ESTIMATED,
        Observations,
        frames_up_to,
    )
    from petsoft.io.recording import Recording

    times = np.array([0.0, 0.1, 0.2, 0.3])
    rec = Recording(reference=np.zeros((1, 3)), names=["m0"], times=times,
                    positions=np.zeros((4, 1, 3)))
    assert Observations(rec).sigma() == (1.0, ESTIMATED)
    assert Observations(rec, noise=2e-3).sigma() == (2e-3, "--noise")
    rec_noise = Recording(reference=rec.reference, names=rec.names, times=times,
                          positions=rec.positions, noise={"position_std": 1e-3})
    assert Observations(rec_noise, noise=2e-3).sigma() == (1e-3, "the recording's /noise")
    # the policy diagnose words its own way (petsoft.diagnosis.context.position_noise)
    assert Observations(rec).stated_noise() is None
    assert Observations(rec, noise=2e-3).stated_noise() == (2e-3, BY_CALLER)
    assert Observations(rec_noise, noise=-1.0).stated_noise() == (1e-3, BY_RECORDING)
    for bad in (0.0, -1e-3, np.nan):
        with pytest.raises(ExperimentError, match="must be > 0"):
            Observations(rec, noise=bad).sigma()
    # recorded times carry round-off: a frame stamped at the end is in the window
    end = 0.2
    assert frames_up_to(np.array([0.1, end * (1 + 1e-13), end * (1 + 1e-11)]),
                        end).tolist() == [True, True, False]

    class _Time:
        end = 0.2

    class _Exp:
        time = _Time()
        source = "<test>"

    assert Observations(rec).window(_Exp()).tolist() == [True, True, True, False]
    early = Recording(reference=rec.reference, names=rec.names, times=times - 0.1,
                      positions=rec.positions)
    with pytest.raises(ExperimentError, match="before the experiment's initial state"):
        Observations(early).window(_Exp())
    with pytest.raises(ExperimentError, match="no /frames/position"):
        Observations(Recording(reference=rec.reference, names=rec.names, times=times)).window(
            _Exp())



def test_a_fit_runs_the_forward_model_once_per_optimizer_evaluation(case, monkeypatch):
    """The report's "before" (the start) and the uncertainty's Jacobian (the optimum) are what
    Gauss-Newton already computed there: no forward or sensitivity run beyond the optimizer's
    own evaluations (two more a fit before), and the same numbers as runs made afresh."""
    from petsoft.calibration.forward import ForwardModel

    d, rec, start = case
    runs = []
    for name in ("simulate", "jacobian"):
        real = getattr(ForwardModel, name)

        def counted(self, p, *args, _real=real, _name=name, **kwargs):
            runs.append(_name)
            return _real(self, p, *args, **kwargs)

        monkeypatch.setattr(ForwardModel, name, counted)
    exp = load_experiment(start)
    res = run_calibration(exp, rec, method="gauss-newton", gradient="sensitivity")
    assert res.reason.startswith("CONVERGED")
    assert len(runs) == res.evaluations, runs
    monkeypatch.undo()

    # afresh: the start's simulation, and the optimum's Jacobian from a new sensitivity run
    problem, fm, scaling = _misfit_problem(exp, rec, res.sigma)
    try:
        z_start = scaling.to_scaled(scaling.start)
        assert problem.rms(problem.simulate(z_start)) == pytest.approx(res.rms_before,
                                                                       rel=1e-12)
        z = scaling.to_scaled(res.values)
        r, J = problem.residual_jacobian(z)
        std = uncertainty(J, r, scaling=scaling, z=z, noise_std=1.0).std
        np.testing.assert_allclose(std, res.std, rtol=1e-9)
    finally:
        fm.destroy()


def test_a_misfit_remembers_its_first_and_last_evaluations(case):
    """Runs at the same z are made once (copies handed out); the first point stays remembered,
    the others while among the last REMEMBERED."""
    from petsoft.calibration.objective import REMEMBERED

    d, rec, start = case
    exp = load_experiment(start)
    problem, fm, scaling = _misfit_problem(exp, rec, NOISE)
    try:
        z0 = scaling.to_scaled(scaling.start)
        r, J = problem.residual_jacobian(z0)
        again_r, again_J = problem.residual_jacobian(z0)
        assert problem.evaluations == 1
        np.testing.assert_array_equal(again_J, J)
        again_J[:] = 0.0                                   # a copy: the memory is intact
        assert np.any(problem.residual_jacobian(z0)[1] != 0.0)
        sim0 = problem.simulate(z0)                        # the Jacobian run's simulation
        assert problem.evaluations == 1
        others = [z0 + 0.01 * (k + 1) for k in range(REMEMBERED + 1)]
        for z in others:
            problem.simulate(z)
        assert problem.evaluations == 2 + REMEMBERED
        np.testing.assert_array_equal(problem.simulate(z0), sim0)   # the first: kept
        problem.simulate(others[-1])                                 # a recent one: kept
        assert problem.evaluations == 2 + REMEMBERED
        problem.simulate(others[0])                                  # the oldest: forgotten
        assert problem.evaluations == 3 + REMEMBERED
    finally:
        fm.destroy()


def _misfit_problem(exp, rec, sigma):
    """A calibration's least-squares problem for ``exp`` against ``rec``, as run_calibration
    makes it (sensitivity gradients)."""
    from petsoft.calibration.calibrate import Observations, build_forward, calibration_parameters
    from petsoft.calibration.objective import MarkerMisfit
    from petsoft.calibration.scaling import ParameterScaling
    from petsoft.io.recording import read_recording_on_all_ranks

    recording = read_recording_on_all_ranks(rec, MPI.COMM_WORLD)
    keep = Observations(recording).window(exp)
    names, p0, bounds = calibration_parameters(exp)
    scaling = ParameterScaling(names, p0, np.array([b[0] for b in bounds]),
                               np.array([b[1] for b in bounds]))
    fm = build_forward(exp, names, recording, recording.times[keep], MPI.COMM_WORLD, None)
    problem = MarkerMisfit(fm, recording.positions[keep], scaling, sigma=sigma,
                           gradient="sensitivity")
    return problem, fm, scaling
