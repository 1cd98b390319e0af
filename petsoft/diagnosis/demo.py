"""The embedded diagnosis example of ``petsoft demo``: hide an effect, find it again.

1. **Truth.** A soft cantilever bar (0.3 x 0.04 x 0.04 m, E = 2e7 Pa) swinging under gravity from
   an initial velocity, with an effect the user's model lacks (:data:`HIDDEN`: viscous damping
   proportional to mass, alpha = 4 1/s, by default).
2. **Recording.** ``petsoft synth`` simulates the truth with another integrator (the midpoint
   rule) at half the user's step, observes 8 random surface markers, adds 0.05 mm noise and
   drops 10 % of the samples (``recording.h5``; the truth in ``truth.json`` beside it, which the
   diagnosis never reads). The truth keeps the user's mesh so that the demo runs in minutes,
   not hours: a 36-tet bar is far from mesh convergence, and with a refined truth the numerics
   check (rightly) refines the model first, which costs more than a demo should.
   ``scripts/benchmarks/bench_diagnose.py`` makes its recordings on refined meshes.
3. **Diagnosis.** ``petsoft diagnose`` starts from the user's model: the truth without the effect,
   Young's modulus 10 % off and calibrated. It calibrates, tests the residual against the noise,
   locates the mismatch, ranks every vocabulary term, adds the best one, re-calibrates, and keeps
   it only if the fit and the held-out prediction improve.

Everything lands in ``OUT/diagnosis/``: ``report.html`` and ``report.md`` (the evidence in
words), ``report.json``
(formats.md section 3), the figures, ``residual_field.xdmf`` (ParaView) and ``diagnosed.toml``.
"""

from __future__ import annotations

from pathlib import Path

from mpi4py import MPI

from petsoft.atomic import write_text
from petsoft.calibration.synth import SynthOptions, synth
from petsoft.experiment import dumps_toml, load_experiment

#: The truth's extra tables (the effect the user's model lacks) and what diagnose should name.
HIDDEN = {"tables": {"damping": {"mass": 4.0}}, "physics": "damping.mass",
          "parameter": ("damping.mass", 4.0)}

E_TRUE = 2.0e7


def _experiment(extra: dict, youngs_modulus: float, integrator: dict, calibrate: bool,
                end: float = 0.3) -> dict:
    data = {
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 1, 1]}},
        "material": {"model": "linear", "youngs_modulus": youngs_modulus,
                     "poisson_ratio": 0.3, "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "initial": {"velocity": ["0", "0", "2*x"]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "time": {"end": end, **integrator},
        "output": {"directory": "out"},
    }
    data.update(extra)
    if calibrate:
        data["calibrate"] = {"material.youngs_modulus": [1e6, 1e8]}
    return data


def run_diagnosis_demo(out: Path, say=print, *, end: float = 0.3, numerics: bool = True,
                       max_additions: int = 3) -> dict:
    """Synthesise a recording with a hidden effect and diagnose it (all ranks call).

    ``end`` (s, the record's length), ``numerics`` (diagnose's refinement checks) and
    ``max_additions`` exist for a quick run (the test suite's); ``petsoft demo`` uses the
    defaults.

    Returns
    -------
    dict
        ``hidden``, ``named`` (added physics), ``verdict``, ``parameter`` (name, true, found),
        ``validation`` (held-out rms before/after) and ``noise``.
    """
    from petsoft.diagnosis.diagnose import run_diagnose
    from petsoft.diagnosis.story import Story

    comm = MPI.COMM_WORLD
    out = Path(out)
    noise = 5e-5
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        # the recording's frames are the truth's steps (1 ms). The user's step resolves the
        # swing well (50 steps per period): with a coarser one, generalized-alpha's own period
        # error and damping are a large part of the mismatch, the numerics check rightly flags
        # them, and the demo gets slow
        truth = _experiment(HIDDEN["tables"], E_TRUE,
                            {"step": 0.001, "integrator": "midpoint"}, calibrate=False, end=end)
        user = _experiment({}, 0.9 * E_TRUE, {"step": 0.002, "integrator": "alpha",
                                              "alpha_radius": 0.9}, calibrate=True, end=end)
        write_text(out / "truth.toml", dumps_toml(truth))
        write_text(out / "user.toml", dumps_toml(user))
        say(f"demo: the truth has {HIDDEN['physics']} {HIDDEN['tables']}; the user's model "
            f"(user.toml) lacks it and starts with E 10 % low")
    comm.Barrier()
    synth(load_experiment(out / "truth.toml"), SynthOptions(out=out / "recording.h5", noise=noise,
                                                            markers=8, dropout=0.1, refine=1,
                                                            seed=3))
    comm.Barrier()
    res = run_diagnose(load_experiment(out / "user.toml"), out / "recording.h5",
                       out=out / "diagnosis", say=say, numerics=numerics,
                       max_additions=max_additions)
    named = [a["physics"] for a in res.added]
    name, true = HIDDEN["parameter"]
    found = (float(res.final.values[res.final.names.index(name)])
             if name in res.final.names else None)
    val = res.report["fit"].get("validation") or {}
    # what only the demo knows, the truth; then the diagnosis' conclusion, last
    if comm.rank == 0:
        say("")
        say(f"demo: the truth hid {HIDDEN['physics']} ({name} {true:g}); diagnose named "
            f"{', '.join(named) or 'nothing'}"
            + (f", {name} found {found:.4g} ({abs(found - true) / true:.1%} off)"
               if found is not None else ""))
        for line in Story(res.report).conclusion(out / "diagnosis"):
            say(line)
    return {"hidden": HIDDEN["physics"], "named": named, "verdict": res.verdict,
            "parameter": {"name": name, "true": true, "found": found},
            "validation": val, "noise": noise}
