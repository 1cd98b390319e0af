"""build_reduced (petsoft.reduced.build): the reduced model a screening asks for.

On the tiny bar of tests/test_reduced.py: from the full training run and a finite-difference
sensitivity trajectory of Young's modulus, with full-model checks at the training point and
E +-10 %, build_reduced returns the first model (over its energy fractions) whose error is
below the target; its reported error is the direct comparison of its runs with the full ones;
the levels before it were not below; with a target no level meets it returns the richest model
with an error that says so; the system is left at the training parameters. A sensitivity check
(ForwardModel.jacobian's columns times a parameter change) enters the error as its own check,
equal to the direct comparison of the returned model's sensitivities.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_reduced import FRAMES, _forward, _trajectory

from petsoft.reduced.build import build_reduced, training_snapshots
from petsoft.reduced.error import marker_error
from petsoft.reduced.galerkin import steps_for
from petsoft.reduced.sensitivity import sensitivities

E = "material.youngs_modulus"
ENERGIES = (0.99, 0.9999, 1 - 1e-8)


def _setup():
    exp, fm = _forward("alpha")
    s = fm.system
    p0 = fm.p0.copy()
    states = _trajectory(fm)
    dp = 1e-3 * p0[0]
    fm._set(p0 + dp)
    moved = _trajectory(fm)
    fm._set(p0)
    sens = []
    for a, b in zip(moved[1:], states[1:], strict=True):
        a.axpy(-1.0, b)
        a.scale(1.0 / dp)
        sens.append(a)
    checks = {label: ({E: float(p0[0] * f)}, fm.simulate(p0 * f))
              for label, f in (("train", 1.0), ("E-10%", 0.9), ("E+10%", 1.1))}
    fm._set(p0)
    _, v0 = s.initial_state()
    return fm, states, sens, checks, v0, {E: float(p0[0])}


def _errors(fm, model, checks, v0, noise):
    out = {}
    for label, (values, full) in checks.items():
        model.set_parameters(values)
        red = model.run(v0, fm.h, steps_for(FRAMES, fm.h)).frames(FRAMES, fm.h)
        out[label] = marker_error(full, red, noise)[0]
    return out


def test_build_reduced_returns_the_first_model_below_the_target():
    fm, states, sens, checks, v0, train = _setup()
    s = fm.system
    kw = dict(frame_times=FRAMES, parameters=train, checks=checks, extra=[sens],
              method="alpha", radius=0.9, ecsw_every=2)
    # the levels' errors, each level on its own (one energy), in noise units of 1 um
    noise = 1e-6
    errs = []
    for e in ENERGIES:
        model, err = build_reduced(s, fm.observer, states, v0, fm.h, noise=noise,
                                   energies=[e], **kw)
        errs.append(err.rms)
        model.destroy()
    assert errs[0] > errs[1] > errs[2] > 0.0
    # a target between the first two levels: the second is returned, with its error
    target = np.sqrt(errs[0] * errs[1])
    model, err = build_reduced(s, fm.observer, states, v0, fm.h, noise=noise,
                               energies=ENERGIES, target=target, **kw)
    assert err.below(target) and err.rms == pytest.approx(errs[1], rel=1e-12)
    assert s.parameters.values[E] == train[E]
    direct = _errors(fm, model, checks, v0, noise)
    assert set(err.checks) == set(direct)
    for label, value in direct.items():
        assert err.checks[label]["rms"] == pytest.approx(value, rel=1e-9)
    model.destroy()
    # a target below every level: the richest model, not below
    model, err = build_reduced(s, fm.observer, states, v0, fm.h, noise=noise,
                               energies=ENERGIES, target=0.5 * errs[2], **kw)
    assert not err.below(0.5 * errs[2]) and err.rms == pytest.approx(errs[2], rel=1e-12)
    model.destroy()
    fm.destroy()


def test_build_reduced_refuses_bad_input():
    fm, states, sens, checks, v0, train = _setup()
    s = fm.system
    with pytest.raises(ValueError, match="at least one check"):
        build_reduced(s, fm.observer, states, v0, fm.h, FRAMES, train, {}, 1e-6)
    bad = {"x": ({"damping.mass": 1.0}, checks["train"][1])}
    with pytest.raises(ValueError, match="damping.mass"):
        build_reduced(s, fm.observer, states, v0, fm.h, FRAMES, train, bad, 1e-6)
    with pytest.raises(ValueError, match="at least one step"):
        training_snapshots(s, states[:1])
    fm.destroy()


def test_build_reduced_checks_sensitivities():
    fm, states, sens, checks, v0, train = _setup()
    s = fm.system
    _, jac = fm.jacobian(fm.p0)
    step = [0.1 * train[E]]
    noise = 1e-6
    model, err = build_reduced(s, fm.observer, states, v0, fm.h, FRAMES, train, checks, noise,
                               extra=[sens], method="alpha", radius=0.9, energies=ENERGIES,
                               sensitivity_checks={"train": (train, [E], jac, step)})
    label = f"train d/d{E}"
    assert set(err.checks) == set(checks) | {label}
    _, red = sensitivities(model, v0, fm.h, steps_for(FRAMES, fm.h), [E]).frames(FRAMES, fm.h)
    direct = marker_error(jac[..., 0] * step[0], red[..., 0] * step[0], noise)[0]
    assert direct > 0.0
    assert err.checks[label]["rms"] == pytest.approx(direct, rel=1e-9)
    assert err.rms >= direct
    model.destroy()
    fm.destroy()
