"""The random cases' truth-error estimate (scripts/benchmarks/independent/random_cases.py,
``truth_error``) on synthetic runs whose discretisation error is known: u_h = u + c h^p e.
Pure numpy (random_cases imports gmsh and DOLFINx only inside the functions that run them)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parents[1] / "scripts/benchmarks/independent"


@pytest.fixture(scope="module")
def rc():
    sys.path.insert(0, str(HERE))
    try:
        spec = importlib.util.spec_from_file_location("random_cases", HERE / "random_cases.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.path.remove(str(HERE))


def runs(p_space: float, c_space: float, c_time: float, h: float = 1.0, dt: float = 1.0):
    """Synthetic runs: the exact field plus c h^p e (space) and c dt^2 f (time)."""
    rng = np.random.default_rng(3)
    u, e, f = (rng.normal(size=(40, 6, 3)) for _ in range(3))

    def run(hh, tt):
        return u + c_space * hh ** p_space * e + c_time * tt ** 2 * f

    d = {"truth": run(h, dt), "space": run(1.4 * h, dt), "space2": run(1.96 * h, dt),
         "time": run(1.96 * h, 2 * dt)}      # the step's check on the coarsest mesh
    err = {"space": c_space * h ** p_space * e, "time": c_time * dt ** 2 * f}
    return d, err


@pytest.mark.parametrize("p", [0.7, 1.0, 2.0, 3.0])
def test_a_power_law_error_is_recovered(rc, p):
    d, err = runs(p, 0.2, 0.05)
    out = rc.truth_error(d)
    assert out["space_observed_order"] == pytest.approx(p, rel=1e-9)
    assert out["space_error_estimate"] == pytest.approx(rc.rms(err["space"]), rel=1e-9)
    assert out["time_error_estimate"] == pytest.approx(rc.rms(err["time"]), rel=1e-9)
    assert out["bound_rms_over_noise"] == pytest.approx(
        rc.rms(err["space"]) + rc.rms(err["time"]), rel=1e-9)


def test_an_order_above_p2s_is_not_trusted(rc):
    # observed 4.5 (a lucky cancellation): the estimate uses 3, so it over-, never under-states
    d, err = runs(4.5, 0.2, 0.0)
    out = rc.truth_error(d)
    assert out["space_observed_order"] == pytest.approx(4.5)
    assert out["space_order_used"] == 3.0
    assert out["space_error_estimate"] > 1.5 * rc.rms(err["space"])


def test_a_p3_truth_trusts_order_four_not_more(rc):
    # P3 at observed order 4 is taken as it is (P2's cap, 3, would overstate it); at 4.5 the
    # estimate uses 4
    d, err = runs(4.0, 0.2, 0.0)
    out = rc.truth_error(d, degree=3)
    assert out["space_order_used"] == pytest.approx(4.0)
    assert out["space_error_estimate"] == pytest.approx(rc.rms(err["space"]), rel=1e-9)
    assert rc.truth_error(d)["space_error_estimate"] > 1.3 * rc.rms(err["space"])
    d, err = runs(4.5, 0.2, 0.0)
    out = rc.truth_error(d, degree=3)
    assert out["space_order_used"] == 4.0
    assert out["space_error_estimate"] > rc.rms(err["space"])


def test_no_convergence_seen_is_no_estimate(rc):
    d, _ = runs(2.0, 0.2, 0.0)
    d["space2"] = d["truth"] + 0.5 * (d["space"] - d["truth"])    # D2 < D1
    d["time"] = d["space2"]                 # (no time error: the step's check on that mesh)
    out = rc.truth_error(d)
    assert out["space_error_estimate"] is None and out["bound_rms_over_noise"] is None


def test_a_failed_level_refines_what_its_error_says(rc):
    # r000 of seed 2's shape: space 0.14, time 0.18 x the noise (bound 0.32 > 0.2). Halving
    # the step alone (time error / 4) is predicted to pass, and does; the mesh is kept
    d, _ = runs(3.0, 0.12, 0.18)
    out = rc.truth_error(d)
    assert out["bound_rms_over_noise"] > rc.TOLERANCE
    assert rc.refine_what(out) == (False, True)
    again = rc.truth_error(runs(3.0, 0.12, 0.18, dt=0.5)[0])
    assert again["bound_rms_over_noise"] < rc.TOLERANCE
    # space-dominated: a finer mesh (its error / 1.4^2 at order 2), the step kept; it passes
    out = rc.truth_error(runs(2.0, 0.3, 0.02)[0])
    assert rc.refine_what(out) == (True, False)
    again = rc.truth_error(runs(2.0, 0.3, 0.02, h=1 / 1.4)[0])
    assert again["bound_rms_over_noise"] < rc.TOLERANCE
    # neither alone is enough: both, predicted as the errors / 1.4^2 and / 4
    out = rc.truth_error(runs(2.0, 0.2, 0.2)[0])
    assert rc.refine_what(out) == (True, True)
    again = rc.truth_error(runs(2.0, 0.2, 0.2, h=1 / 1.4, dt=0.5)[0])
    assert rc.predicted_bound(out, True, True) == pytest.approx(
        again["bound_rms_over_noise"], rel=1e-9)
    # r003 of seed 2: 0.57 at order 1.5 and 0.12 in time, both refined predicted ~0.37
    out = rc.truth_error(runs(1.5, 0.55, 0.12)[0])
    assert rc.refine_what(out) == (True, True)
    assert rc.predicted_bound(out, True, True) > rc.TOLERANCE
    # no convergence seen in space: a finer mesh
    d, _ = runs(2.0, 0.2, 0.0)
    d["space2"] = d["truth"] + 0.5 * (d["space"] - d["truth"])
    d["time"] = d["space2"]
    assert rc.refine_what(rc.truth_error(d)) == (True, False)
    assert rc.predicted_bound(rc.truth_error(d), True, False) is None
    # a level that passed has nothing to refine
    with pytest.raises(ValueError, match="passed"):
        rc.refine_what(rc.truth_error(runs(3.0, 0.01, 0.01)[0]))


@pytest.mark.parametrize("rho", [0.02, 0.1, 0.3])
def test_newtons_estimated_stop_leaves_less_than_the_tolerance(rho):
    """generate.newton_done on a linearly contracting iteration (the modified Newton of the
    truths: x_k - x* = rho^k e0): with the estimate it stops no later than the increment rule,
    one iteration sooner when the contraction allows, and the error left is below the
    tolerance; the first increment never stops it (no contraction seen yet)."""
    from _independent import load

    gen = load("generate")
    tol, e0 = 1e-9, 3e-5

    def stop_after(estimate: bool) -> tuple[int, float]:
        last = np.inf
        for k in range(1, 60):
            size = e0 * rho ** (k - 1) * (1 - rho)         # |x_k - x_{k-1}|
            if gen.newton_done(size, last, tol, estimate):
                return k, e0 * rho ** k                     # the error left at x_k
            last = size
        raise AssertionError("never stopped")

    k_inc, left_inc = stop_after(False)
    k_est, left_est = stop_after(True)
    assert left_inc < tol and left_est < tol
    assert k_est == k_inc - 1 and k_est >= 2
    assert gen.newton_done(1e-12, np.inf, tol, True)
    assert not gen.newton_done(5e-9, np.inf, tol, True)      # one increment: no estimate yet
