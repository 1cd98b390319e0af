"""Random independent diagnose cases (issue 37, item 1): mesh, simulate and write a draw.

Run through generate.py with the system python (DOLFINx 0.5 and gmsh)::

    nice -n 10 /usr/bin/python3 scripts/benchmarks/independent/generate.py \
        --random N --seed S --out DIR [--size small|realistic] [--only 0,3] [--refine 1] \
        [--draw-only]

random_draw.py draws each case's parameters from (S, index); here, for every case, under
``DIR/<name>/``:

* ``mesh.msh``: the user's P1 mesh (gmsh) with the drawn number of tets;
* the truth's level chosen first (frequency_screen.py): the body's first natural frequencies
  on a ladder of graded meshes (seconds) predict each level's error; the cheapest level (mesh
  size, 4-16 steps a frame) predicted within 0.8x the tolerance and an affordable cost is
  taken, and a case no affordable level is predicted to pass is **discarded** before any time
  run (it used to cost ~20-45 core-minutes to find out);
* the truth: DOLFINx P2 on that finer gmsh mesh at that fraction of the user's step
  (generate.py's :func:`simulate_truth`), sampled at markers that are surface nodes of the
  user's mesh;
* the effect-free run (cases with a concealed effect): the same truth without the concealed
  effect(s) -- the user's physics at the true parameters -- whose difference from the truth, rms
  over markers and frames in units of the noise, is the case's **effect size**, measured on the
  accepted level's coarsest mesh (h x 1.96, beside that level's run with the effect: ~1/4 of
  a run at h; on the test draw 1925304550's r001-bracket 0.4104 there against 0.4106 at h);
* the truth's own error, from two coarser runs in space (h x 1.4 and x 1.96: the observed
  order, at most P2's 3) and one in time (the step doubled, order 2), :func:`truth_error`
  (checked from the coarse side: the cheap side). A case whose bound exceeds :data:`TOLERANCE`
  x its noise
  is simulated again one level finer (the step halved, h / 1.4 or both: the cheapest predicted
  to pass, :func:`refine_what`; checked the same way), up to
  ``--refine`` times (default 1); if it still fails it is **discarded** (``discarded.json`` says
  why) and counted in ``draw.json``. The effect-free run is made at the accepted level
  (on its coarsest mesh);
* ``recording.h5`` (noise, dropped samples, occluded stretches), ``user.toml`` and
  ``truth.json`` (everything drawn and measured; run.py's keys ``concealed``, ``shape``,
  ``truth.youngs_modulus``, ``noise.position_std`` as the fixed suite's).

``DIR/draw.json`` is the manifest: seed, N, size, the generator's git commit, and per case its
family, category, concealed set, magnitudes, effect size / noise, the truth's error bound and
its status (written, discarded, pending). Clean runs are cached in ``DIR/.runs/`` (an
interrupted draw resumes; ``--only`` splits a draw over processes).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import frequency_screen as fs  # noqa: E402
import generate as indep  # noqa: E402
import random_draw as rd  # noqa: E402
import random_shapes as rs  # noqa: E402

#: the truth's steps per user frame (0.5 ms), its coarser check's mesh ratio
SUBSTEPS, COARSER = 4, 1.4
#: the largest accepted truth error bound (rms over markers and frames) / the case's noise
TOLERANCE = 0.2
#: Newton's stop (m): the error estimated to remain after the last increment
#: (generate.simulate_truth's newton_estimate; the test draw 1925304550's r000-plate over
#: 0.1 s: 4.6 -> 3.7 iterations a step, 102 -> 88 s, its markers 1.8e-8 m rms, 7e-5x the noise,
#: from those of the increment stop at 1e-9 m)
NEWTON_TOL = 1e-9
ALPHA_RADIUS = 0.9
#: markers sit this far (m) inside the user's mesh from a surface node
NUDGE = 5e-4


def say(line: str) -> None:
    print(line, flush=True)


def git_commit() -> dict:
    """The generator's commit and whether its folder has uncommitted changes."""
    def git(*a):
        return subprocess.run(["git", "-C", str(HERE), *a], capture_output=True,
                              text=True).stdout.strip()
    return {"commit": git("rev-parse", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "--", "."))}


def pick_candidates(case: dict, points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Up to 3 x markers candidate markers: surface nodes of the user's mesh off the clamp, drawn
    from the generator seeded by (seed, index, 1), each moved :data:`NUDGE` into the user's mesh
    (towards its cells' centroids; kept on the node if that leaves them). The caller keeps the
    first ``markers`` that every truth mesh holds: the fine meshes' chords cut inside a curved
    face's nodes (the shell's faces are all curved: unmoved, 6 of 22 markers survived)."""
    cand = indep.surface_nodes(tets)
    cand = cand[~rs.clamp_mask(case["geometry"], points[cand].T)]
    rng = np.random.default_rng([*case["seed"], 1])
    k = min(3 * case["markers"], len(cand))
    chosen = np.sort(rng.choice(cand, size=k, replace=False))
    out = points[chosen].copy()
    for i, node in enumerate(chosen):
        star = tets[np.any(tets == node, axis=1)]
        inward = points[star].mean(axis=1).mean(axis=0) - points[node]
        q = points[node] + NUDGE * inward / np.linalg.norm(inward)
        # barycentric coordinates of q in each cell of the star: inside one of them?
        corners = points[star]
        T = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))
        lam = np.linalg.solve(T, (q - corners[:, 0])[:, :, None])[:, :, 0]
        if np.any((lam >= 0).all(axis=1) & (lam.sum(axis=1) <= 1)):
            out[i] = q
    return out


def _num(v) -> str:
    return "n/a" if v is None else f"{v:.3g}"


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a ** 2)))


def truth_error(d: dict, degree: int = 2) -> dict:
    """The truth's error at the markers, in units of the noise, from the runs ``d`` (already
    divided by the noise): ``truth``, ``space`` (h x 1.4), ``space2`` (h x 1.96), ``time`` (the
    step doubled, on the h x 1.96 mesh: the step's effect is a phase error of the body's
    frequencies, which the meshes share to ~0.1-0.3 %; on the test draw 59653812's r000-bar,
    r004-plate and r001-fillet it was 0.998, 1.002 and 1.059 times the effect at h,
    probes/time_check_mesh.py, for ~1/4 of the cost).

    Space: the differences D1 = |u(1.4 h) - u(h)| and D2 = |u(1.96 h) - u(1.4 h)| (rms) give the
    observed order p = log(D2 / D1) / log 1.4, taken at most 3 (P2's), and the error
    D1 / (1.4^p - 1). P2's 3 is not what the meshes show: a clamped plate's runs over 0.2 s
    converged at p ~ 0.7 (the clamp's edge singularity, phase drift), and 3 would have called
    its truth converged at 0.19 x the noise where p 0.7 says 1.25 x. D2 <= D1 (no convergence
    seen) is no estimate (None): the case fails. Time: generalized-alpha's order 2,
    |u(2 dt) - u(dt)| / 3 on the h x 1.96 mesh (the runs at 4 and 8 steps a frame differed by
    0.008-0.02 x the noise). The bound is their sum.
    """
    d1, d2 = rms(d["space"] - d["truth"]), rms(d["space2"] - d["space"])
    p = math.log(d2 / d1) / math.log(COARSER) if d1 > 0 and d2 > d1 else (
        3.0 if d1 == 0 else 0.0)
    p_used = min(p, degree + 1.0)
    # None: no convergence seen, no estimate (JSON null, not Infinity)
    e_space = d1 / (COARSER ** p_used - 1.0) if p_used > 0 else None
    dt = rms(d["time"] - d["space2"])
    e_time = dt / 3.0
    return {"method": "observed order in space (three meshes), order 2 in time",
            "space_difference": d1, "space2_difference": d2,
            "space_observed_order": p, "space_order_used": p_used,
            "space_error_estimate": e_space,
            "time_difference": dt, "time_error_estimate": e_time,
            "max_space_difference": float(np.abs(d["space"] - d["truth"]).max()),
            "bound_rms_over_noise": None if e_space is None else e_space + e_time}


def refine_what(conv: dict) -> tuple[bool, bool]:
    """Whether the next level makes the mesh finer (h / 1.4) and the step smaller (halved),
    from a failed level's :func:`truth_error`: the cheapest of step only (~2 truths), mesh only
    (~1.4^3 = 2.7) and both (~5.5) whose predicted bound is within the tolerance (the time
    error / 4 for a halved step, the space error / 1.4^p at the order used), else both; no
    estimate in space: the mesh (and the step where its error exceeds half the tolerance).
    Seed 2's first case (r000) failed at 0.32 x the noise, space 0.14 and time 0.18: the step
    halved alone predicts 0.19."""
    space, time_ = conv["space_error_estimate"], conv["time_error_estimate"]
    if space is None:
        return True, time_ > TOLERANCE / 2
    if space + time_ < TOLERANCE:
        raise ValueError("refine_what: the level passed its error check")
    for finer_h, finer_step in ((False, True), (True, False)):
        if predicted_bound(conv, finer_h, finer_step) < TOLERANCE:
            return finer_h, finer_step
    return True, True


def predicted_bound(conv: dict, finer_h: bool, finer_step: bool) -> float | None:
    """The bound (x noise) a level refined so is predicted to have: the space error / 1.4^p
    (p the order used) for h / 1.4, the time error / 4 for the step halved; None without a
    space estimate (no convergence seen: nothing to predict from)."""
    space, time_ = conv["space_error_estimate"], conv["time_error_estimate"]
    if space is None:
        return None
    return ((space / COARSER ** conv["space_order_used"] if finer_h else space)
            + (time_ / 4 if finer_step else time_))


def least_predicted(screen: dict) -> float | None:
    """The smallest bound (x noise) :func:`frequency_screen.choose` predicted at any level."""
    bounds = [lv["predicted"]["bound"] for lv in screen["levels"] if lv["predicted"]]
    return min(bounds) if bounds else None


def body(case: dict, effect_free: bool = False) -> dict:
    """generate.simulate_truth's ``body`` of the case: the truth's or (``effect_free``) the
    user's physics at the true parameters (the user's law and gravity)."""
    g, fam, exc = case["geometry"], case["family"], case["excitation"]
    law = case["user"]["model"] if effect_free else "neohookean"
    # the regions' conforming mesh for the effect-free twin too (its materials left out), so
    # that the effect's size is not mixed with a change of mesh
    regions = case["truth"].get("regions")
    return {"mesh": lambda gmsh, h: rs.mesh(gmsh, fam, g, h, graded=True, regions=regions),
            "h_fine": rs.truth_h(g), "clamp": lambda x: rs.clamp_mask(g, x),
            "velocity": exc["velocity"], "displacement": exc["displacement"],
            "material": {**case["material"], "law": law},
            "gravity": case["user"]["gravity"] if effect_free else case["gravity"],
            "base": exc["base"]}


def run(gmsh, case: dict, markers: np.ndarray, label: str, cache: Path, *,
        effect_free: bool = False, h: float | None = None, substeps: int = SUBSTEPS,
        degree: int = 2) -> dict:
    """One DOLFINx run of ``case`` at ``markers`` (cached under ``cache`` by label; a P3
    run's label says so)."""
    label = label if degree == 2 else f"p{degree}-{label}"
    path = cache / f"{case['name']}-{label}.npz"
    if (cached := indep.cached_run(path, markers, say)) is not None:
        return cached
    truth = {} if effect_free else case["truth"]
    res = indep.simulate_truth(gmsh, case["name"], {"shape": case["family"], "truth": truth},
                               markers, say, h_fine=h, substeps=substeps, end=case["end"],
                               newton_tol=NEWTON_TOL, body=body(case, effect_free),
                               newton_estimate=True, degree=degree)
    meta = {k: v for k, v in res.items() if k not in ("displacements", "found")}
    meta["h"] = h or rs.truth_h(case["geometry"])
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, markers=markers, displacements=res["displacements"], found=res["found"],
             meta=json.dumps(meta))
    say(f"  {label}: {res['fine_tets']} P{degree} tets, {res['dofs']} dofs, step "
        f"{res['step']:g} s, {res['newton']} Newton iterations, {res['seconds']:.0f} s")
    return res | {"h": meta["h"]}


def user_toml(case: dict, user_h: float) -> dict:
    """The user's experiment: the believed model (the truth minus the concealed effects), E
    started off, the mesh file beside it."""
    u, exc = case["user"], case["excitation"]
    E = u["youngs_modulus"]
    return {
        "mesh": {"file": "mesh.msh"},
        "material": {"model": u["model"], "youngs_modulus": E,
                     "poisson_ratio": case["material"]["poisson_ratio"],
                     "density": case["material"]["density"]},
        "gravity": {"acceleration": u["gravity"]},
        "initial": {"displacement": exc["displacement"], "velocity": exc["velocity"]},
        "boundary": [{"kind": "fixed", "where": rs.clamp_expression(case["geometry"])}
                     if exc["base"] is None else
                     {"kind": "prescribed", "where": rs.clamp_expression(case["geometry"]),
                      "displacement": exc["clamp_displacement"]}],
        "time": {"end": case["end"], "step": rd.STEP, "integrator": "alpha",
                 "alpha_radius": ALPHA_RADIUS},
        "output": {"directory": "out"},
        "calibrate": {"material.youngs_modulus": [E / 10, E * 10]},
    }


def make_case(gmsh, case: dict, out: Path, refine: int = 1) -> dict:
    """Mesh, simulate, check (refining the truth up to ``refine`` times) and write one case;
    return its draw.json row."""
    name, d, cache = case["name"], out / case["name"], out / ".runs"
    lo, hi = rd.SIZES[case["size"]]["tets"]
    t0 = time.perf_counter()
    points, tets, user_h = rs.user_mesh(gmsh, case["family"], case["geometry"],
                                        case["user_tets"], d / "mesh.msh", lo, hi)
    say(f"{name}: {case['category']}, concealed {'+'.join(case['concealed']) or 'nothing'}; "
        f"user mesh {len(tets)} tets (h {user_h:.3g} m), {case['end']:g} s, "
        f"noise {case['noise_fraction']:.3g} x the motion")
    cand = pick_candidates(case, points, tets)
    # the truth's level from the body's natural frequencies (seconds), before any time run
    screen = fs.choose(gmsh, case, TOLERANCE, say=say)
    if screen["h"] is None:
        why = ("the first natural frequencies predict no truth level within "
               f"{fs.MARGIN * TOLERANCE:.3g} x noise at most {fs.MAX_TET_STEPS:.3g} P2 "
               f"tet-steps (the least predicted: {_num(least_predicted(screen))} x noise)")
        d.mkdir(parents=True, exist_ok=True)
        (d / "discarded.json").write_text(json.dumps(
            {"case": name, "reason": why, "convergence": None, "screen": screen, "draw": case},
            indent=1) + "\n")
        for stale in ("truth.json", "recording.h5", "user.toml"):
            (d / stale).unlink(missing_ok=True)
        say(f"{name}: DISCARDED ({why})")
        return {"index": case["index"], "name": name, "family": case["family"],
                "category": case["category"], "concealed": case["concealed"],
                "magnitudes": case["magnitudes"], "effect_size_over_noise": None,
                "truth_error_bound_over_noise": None, "refinements": 0, "noise": None,
                "user_tets": int(len(tets)), "simulation_seconds": 0.0,
                "status": "discarded", "reason": why}
    noise = None
    levels, spent = [], {}
    hl, sl, conv = screen["h"], screen["substeps"], {}
    degree = screen.get("degree") or 2
    for level in range(refine + 1):
        # level L: h at sl steps a frame (finer than the last level's where its error was),
        # checked by two runs coarser in space (h x 1.4, h x 1.96: the observed order) and one
        # in time (the step doubled, on the h x 1.96 mesh: truth_error)
        if level > 0:
            finer_h, finer_step = refine_what(conv)
            predicted = predicted_bound(conv, finer_h, finer_step)
            if predicted is not None and predicted >= TOLERANCE:
                # one level is predicted to fail too (seed 2's r003: 0.68 at order 1.5, both
                # refined ~0.37): discarded without the ~5.5 truths it costs
                conv["predicted_next_bound"] = predicted
                say(f"{name}: one refinement predicted to reach {predicted:.3g} x noise, above"
                    f" {TOLERANCE}: not made")
                level -= 1
                break
            hl, sl = (hl / COARSER if finer_h else hl), (2 * sl if finer_step else sl)
        # the coarsest first: a case whose cells are thrown over (a release on a fillet's
        # small graded cells) fails there, before the dear run at h
        at = {"space2": (hl * COARSER ** 2, sl), "time": (hl * COARSER ** 2, sl // 2),
              "space": (hl * COARSER, sl), "truth": (hl, sl)}
        runs = {key: run(gmsh, case, cand, f"truth-h{h_:.5g}-s{s_}", cache, h=h_,
                         substeps=s_, degree=degree) for key, (h_, s_) in at.items()}
        # per (h, steps a frame): a level that halves only the step reuses the last truth as
        # its time check, counted once
        spent.update({(r["h"], r["step"]): r["seconds"] for r in runs.values()})
        found = np.logical_and.reduce([r["found"] for r in runs.values()])
        keep = np.flatnonzero(found)[:case["markers"]]
        disp = {k: r["displacements"][:, keep] for k, r in runs.items()}      # m
        if noise is None:
            # the noise is the drawn fraction of the first truth's largest marker
            # displacement, fixed from then on (a case has one noise)
            motion = float(np.linalg.norm(disp["truth"], axis=-1).max())
            noise = rd.noise_level(case["noise_fraction"], motion)
            case = dict(case, noise=noise)
            say(f"{name}: largest marker displacement {motion * 1e3:.3g} mm, noise "
                f"{noise * 1e3:.3g} mm")
        conv = truth_error({k: v / noise for k, v in disp.items()}, degree=degree)
        for key in ("space", "space2", "time"):
            r = runs[key]
            conv[f"{key}_run"] = {"h": r["h"], "tets": r["fine_tets"], "dofs": r["dofs"],
                                  "step": r["step"], "seconds": r["seconds"]}
        bound = conv["bound_rms_over_noise"]
        conv["converged"] = bound is not None and bound < TOLERANCE
        conv["level"] = level
        levels.append({"level": level, "h": hl, "step": runs["truth"]["step"],
                       "space_error": conv["space_error_estimate"],
                       "time_error": conv["time_error_estimate"],
                       "bound_rms_over_noise": bound})
        say(f"{name}: level {level} truth error bound {_num(bound)} x noise (space "
            f"{_num(conv['space_error_estimate'])} at observed order "
            f"{conv['space_observed_order']:.2f}, differences {conv['space_difference']:.3f}"
            f" and {conv['space2_difference']:.3f}; time {conv['time_error_estimate']:.3f}); "
            f"{len(keep)} markers")
        if conv["converged"] or len(keep) < rd.MARKER_RANGE[0]:
            break
    conv["levels"] = levels
    conv["screen"] = screen
    seconds = sum(spent.values())
    tr = runs["truth"]
    if len(keep) < rd.MARKER_RANGE[0]:
        bound_ok, why = False, f"only {len(keep)} markers inside every truth mesh"
    else:
        bound_ok = conv["converged"]
        why = (f"truth error bound {_num(bound)} x noise above {TOLERANCE} after {level} "
               "refinement(s)" + (" (one more predicted to reach "
                                  f"{_num(conv['predicted_next_bound'])})"
                                  if "predicted_next_bound" in conv else "")
               if bound is not None else
               f"no convergence in space seen (runs at 1.96 h, 1.4 h, h differed by "
               f"{conv['space2_difference']:.3f} and {conv['space_difference']:.3f} x noise) "
               f"after {level} refinement(s)")
    # a control's effect is nothing; a discarded case's is not measured (None)
    size = {"rms": 0.0, "max": 0.0} if not case["concealed"] else {"rms": None, "max": None}
    if bound_ok and case["concealed"]:
        # the effect-free run on the accepted level's coarsest mesh (h x 1.96), against the
        # run with the effect there: their discretisation errors mostly cancel in the
        # difference, and it costs ~1/4 of a run at h (the effect size is the power curves'
        # abscissa, wanted to a few per cent, not to the truth's 0.2x the noise)
        runs["free"] = run(gmsh, case, cand, f"free-h{hl * COARSER ** 2:.5g}-s{sl}", cache,
                           effect_free=True, h=hl * COARSER ** 2, substeps=sl, degree=degree)
        seconds += runs["free"]["seconds"]
        found = found & runs["free"]["found"]
        if not found[keep].all():
            bound_ok, why = False, "a marker outside the effect-free run's mesh"
        else:
            diff = (runs["space2"]["displacements"][:, keep]
                    - runs["free"]["displacements"][:, keep]) / noise
            size = {"rms": float(np.sqrt(np.mean(diff ** 2))),
                    "max": float(np.abs(diff).max())}
    row = {"index": case["index"], "name": name, "family": case["family"],
           "category": case["category"], "concealed": case["concealed"],
           "magnitudes": case["magnitudes"], "effect_size_over_noise": size["rms"],
           "truth_error_bound_over_noise": bound, "refinements": level, "noise": noise,
           "markers": int(len(keep)), "user_tets": int(len(tets)),
           "truth_tets": tr["fine_tets"], "simulation_seconds": seconds}
    say(f"{name}: effect size {_num(size['rms'])} x noise")
    if not bound_ok:
        d.mkdir(parents=True, exist_ok=True)
        (d / "discarded.json").write_text(json.dumps(
            {"case": name, "reason": why, "convergence": conv, "draw": case}, indent=1) + "\n")
        for stale in ("truth.json", "recording.h5", "user.toml"):
            (d / stale).unlink(missing_ok=True)
        say(f"{name}: DISCARDED ({why})")
        return row | {"status": "discarded", "reason": why}
    markers = cand[keep]
    positions, hidden = rd.corrupt(markers[None] + disp["truth"], case)
    times = np.arange(len(positions)) * rd.STEP
    indep.write_recording(d / "recording.h5", markers, times, positions,
                          [f"m{i:02d}" for i in range(len(markers))], noise,
                          f"scripts/benchmarks/independent/generate.py --random {name} "
                          f"(DOLFINx P{degree})")
    (d / "user.toml").write_text(
        f"# {name}: the user's experiment (generate.py --random); the recording was made by "
        "DOLFINx\n" + indep.dumps_toml(user_toml(case, user_h)))
    truth = {
        "case": name, "shape": case["family"], "category": case["category"],
        "concealed": case["concealed"], "magnitudes": case["magnitudes"],
        "truth": {"youngs_modulus": case["material"]["youngs_modulus"],
                  "poisson_ratio": case["material"]["poisson_ratio"],
                  "density": case["material"]["density"], "material": "neohookean",
                  **case["truth"], "gravity": case["gravity"]},
        "user": case["user"], "geometry": case["geometry"], "excitation": case["excitation"],
        "effect_size_over_noise": size,
        "effect_size_definition": "rms (and max) over markers, frames and components of "
                                  "(truth - effect-free run) / noise, both noise-free, on the "
                                  "truth level's h x 1.96 mesh; the effect-free run: the truth "
                                  "without the concealed effect(s)",
        "effect_free_run": ({"seconds": runs["free"]["seconds"], "law": case["user"]["model"],
                             "gravity": case["user"]["gravity"]} if "free" in runs else None),
        "simulator": f"DOLFINx 0.5, P{degree} tetrahedra, Chung-Hulbert generalized-alpha "
                     f"(rho_inf {ALPHA_RADIUS}), Newton with MUMPS LU",
        "convergence": conv, "truth_tolerance_over_noise": TOLERANCE,
        "user_mesh": "mesh.msh", "coarse_tets": int(len(tets)), "user_h": user_h,
        "fine_h": tr["h"], "fine_tets": tr["fine_tets"], "fine_dofs": tr["dofs"],
        "step": tr["step"], "steps": tr["steps"], "user_step": rd.STEP, "end": case["end"],
        "newton_iterations": tr["newton"], "refactorizations": tr["refactors"],
        "seconds": tr["seconds"], "generation_seconds": seconds,
        "noise": hidden, "seed": case["seed"], "size": case["size"],
        "markers": int(len(markers)), "frames": int(len(times)),
        "max_marker_displacement": float(np.abs(disp["truth"]).max()),
    }
    (d / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    # an earlier run's verdict on this case (e.g. discarded at fewer refinements) is stale
    (d / "discarded.json").unlink(missing_ok=True)
    say(f"{name}: written ({time.perf_counter() - t0:.0f} s)")
    return row | {"status": "written"}


def write_json(path: Path, data: dict) -> None:
    """Atomically (processes given --only share draw.json)."""
    tmp = path.parent / f".{path.name}.{os.getpid()}"
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, path)


def manifest(out: Path, seed: int, n: int, size: str, cases: list[dict], rows: dict,
             generator: dict) -> dict:
    """DIR/draw.json from the draw and every case's state on disk (other processes' too);
    ``generator``: :func:`git_commit` when the process started (the code it runs)."""
    entries = []
    for c in cases:
        d = out / c["name"]
        if c["index"] in rows:
            e = rows[c["index"]]
        elif (d / "truth.json").exists():
            t = json.loads((d / "truth.json").read_text())
            e = {"status": "written", "effect_size_over_noise": t["effect_size_over_noise"]["rms"],
                 "truth_error_bound_over_noise": t["convergence"]["bound_rms_over_noise"],
                 "markers": t["markers"], "user_tets": t["coarse_tets"],
                 "truth_tets": t["fine_tets"], "simulation_seconds": t["generation_seconds"]}
        elif (d / "discarded.json").exists():
            t = json.loads((d / "discarded.json").read_text())
            e = {"status": "discarded", "reason": t["reason"],
                 "truth_error_bound_over_noise": (t["convergence"] or {}).get(
                     "bound_rms_over_noise")}
        else:
            e = {"status": "pending"}
        entries.append({"index": c["index"], "name": c["name"], "family": c["family"],
                        "category": c["category"], "concealed": c["concealed"],
                        "magnitudes": c["magnitudes"]} | e)
    count = {k: sum(e["category"] == k for e in entries) for k in ("control", "one", "two",
                                                                   "off")}
    status = {k: sum(e["status"] == k for e in entries) for k in ("written", "discarded",
                                                                  "pending")}
    return {"seed": seed, "N": n, "size": size, "generator": generator,
            "command": f"generate.py --random {n} --seed {seed} --size {size}",
            "case_seed": "numpy default_rng([seed, index]) (noise: [seed, index, 2], markers: "
                         "[seed, index, 1])",
            "controls": count["control"], "categories": count, "status": status,
            "discarded": status["discarded"], "truth_tolerance_over_noise": TOLERANCE,
            "cases": entries}


def main(n: int, seed: int, out: Path, size: str, only: list[int] | None,
         draw_only: bool, refine: int = 1) -> int:
    generator = git_commit()
    cases = rd.draw(seed, n, size)
    out.mkdir(parents=True, exist_ok=True)
    todo = [c for c in cases if only is None or c["index"] in only]
    rows: dict = {}
    if not draw_only:
        import gmsh

        gmsh.initialize()
        gmsh.option.setNumber("General.Terminal", 0)
        for c in todo:
            t0 = time.perf_counter()
            try:
                row = make_case(gmsh, c, out, refine)
            except RuntimeError as err:     # Newton failed, a region missed the mesh, ...
                say(f"{c['name']}: DISCARDED ({err})")
                (out / c["name"]).mkdir(parents=True, exist_ok=True)
                (out / c["name"] / "discarded.json").write_text(json.dumps(
                    {"case": c["name"], "reason": str(err), "convergence": None, "draw": c},
                    indent=1) + "\n")
                row = {"status": "discarded", "reason": str(err)}
                gmsh.clear()
            rows[c["index"]] = row | {"wall_seconds": time.perf_counter() - t0}
            write_json(out / "draw.json", manifest(out, seed, n, size, cases, rows, generator))
        gmsh.finalize()
    m = manifest(out, seed, n, size, cases, rows, generator)
    write_json(out / "draw.json", m)
    say(f"draw {seed}: N {n}, {m['controls']} controls, categories {m['categories']}; "
        f"{m['status']['written']} written, {m['discarded']} discarded, "
        f"{m['status']['pending']} pending -> {out / 'draw.json'}")
    return 0
