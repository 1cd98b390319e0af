"""Realistic cases for ``petsoft diagnose`` made by an independent code (issue 40, item 5).

Run with the system python (DOLFINx 0.5 and gmsh are Debian packages there), one process::

    nice -n 10 /usr/bin/python3 scripts/benchmarks/realistic/generate_realistic.py \
        [--cases control,damping] [--fine | --finest] [--force] [--check-end 0.5] [--no-check]
        [--only-run LEVEL] [--list]

What made the committed cases (README.md): ``--no-check`` (all), then ``--fine --force
--cases control``, ``--fine --force --cases damping,damping-5k --check-end 0.5``, ``--fine
--force --cases payload`` (its ball a conforming part of the truth's geometry) and ``--finest
--force --cases nonlinear``, their check runs made first in parallel processes by ``--only-run``
(``time``, ``space``; ``fine``, ``finest-space``).

The cases are like the independent suite's (``../independent/generate.py``, whose functions this
module reuses: geometry, the DOLFINx truth, markers, noise, the recording and user.toml writers)
but sized like a real experiment: a user mesh of 711 P1 tets (and one of 5,007), 1.0 s recorded at
2 ms (501 frames), 24 markers, noise 0.1 mm, ~10 % of the samples dropped.

The truth is P2 on a gmsh mesh of h = :data:`H_TRUTH` at a quarter of the user's step (the base
level) or, with ``--fine``, on h = :data:`H_REFINED` at an eighth (the fine level), or, with
``--finest``, on h = :data:`H_FINEST` at an eighth. It is checked by one refinement in space and
one in time, at the recorded markers, noise-free: the base level by the runs refined in space (h
= H_REFINED) and in time (the step halved), the fine and finest levels by the runs each coarser
than it in one of the two (:data:`CHECKS`). The differences, in units of the
noise, and the truth's error estimated from them are written to ``truth.json`` under
``"convergence"`` (with ``"converged"``: the bound below :data:`TOLERANCE` x the noise, rms). A
case whose truth fails the check is written only with ``--force``.

The error from one refinement (Richardson): with a difference D between two runs of ratio r in a
quantity of order p (p = 2 in time for generalized-alpha, r = 2; p = 3 in space for P2
displacements, r the ratio of the two mesh sizes), the coarser run's error is D / (1 - r^-p) and the
finer's D / (r^p - 1); the space and time estimates are added as signed fields (they partly
cancel: the spatial error stiffens, the temporal one lengthens the period) and, as a bound that
does not rely on that cancellation, their rms values are summed. The pass test is on the bound.

Cases sharing a truth (``truth_of``) are simulated once, with the union of their markers: the
5,000-tet case's recording comes from the damping case's truth simulation, sampled at markers on
its own user mesh. Clean marker runs are cached in ``out/realistic_runs/`` (so an interrupted
generation resumes); delete them to recompute.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "independent"))
import generate as indep  # noqa: E402  (the independent suite's generator, reused)

CASES_DIR = HERE / "cases"
CACHE_DIR = HERE.parents[2] / "out" / "realistic_runs"

END, MARKERS = 1.0, 24
#: the truth's (P2) and the refined check's mesh sizes, steps per user frame (2 ms); H_FINEST:
#: one refinement beyond H_REFINED, same ratio (``--finest``)
H_TRUTH, H_REFINED, H_FINEST = 0.011, 0.008, 0.0058
SUBSTEPS = 4
#: the truth levels (cache labels) -> mesh size, steps per frame. A level's truth is checked by
#: one refinement in space and one in time: the base level ("truth") by the runs finer in one of
#: the two, "fine" and "finest" by the runs coarser in one of the two (CHECKS)
LEVELS = {"truth": (H_TRUTH, SUBSTEPS), "space": (H_REFINED, SUBSTEPS),
          "time": (H_TRUTH, 2 * SUBSTEPS), "fine": (H_REFINED, 2 * SUBSTEPS),
          "finest-space": (H_FINEST, SUBSTEPS), "finest": (H_FINEST, 2 * SUBSTEPS)}
#: level -> (the run differing from it in space only, the one differing in time only); the
#: "time" level (h 11 mm at 0.25 ms, the truth with ``--graded``) is checked by the run finer
#: in space and the one coarser in time: the cheapest pair of a converged graded truth
CHECKS = {"truth": ("space", "time"), "fine": ("time", "space"),
          "finest": ("fine", "finest-space"), "time": ("fine", "truth")}
#: Newton's last increment (m): 1e-5 of the noise, so that even a systematic error of this size
#: every step (2000 steps) stays at 0.02 x the noise (the independent suite: 1e-10)
NEWTON_TOL = 1e-9
#: the largest accepted truth error (rms over all markers and frames) in units of the noise
TOLERANCE = 0.2
#: truth.json's description of a graded truth mesh (``--graded``; generate.py's mesh_shape)
GRADED = "graded towards the clamped face's edges: h / 4 within h / 4 of them, h from 4 h"

#: user meshes: name -> gmsh shape of the independent suite and element size (m)
MESHES = {
    "taper": dict(shape="finger", h=0.0135),        # 711 tets
    "taper-5k": dict(shape="finger", h=0.0066),     # 5007 tets
}

PAYLOAD = {"center": [0.24, 0.0, 0.0], "radius": 0.03}      # a weight near the tip

#: name -> user mesh, concealed terms, truth settings (petsoft keys), user edits; ``truth_of``:
#: the case whose truth simulation this one samples (same physics, another user mesh)
CASES: dict[str, dict] = {
    "control": dict(mesh="taper", physics=[], truth={}),
    "damping": dict(mesh="taper", physics=["damping.mass"], truth={"damping": {"mass": 2.0}}),
    "payload": dict(mesh="taper", physics=["mass.added"],
                    # conforming: the ball is a part of the truth's geometry, the same on
                    # every mesh (a staircase of cells moved with the mesh: README.md)
                    truth={"sphere": {"where": PAYLOAD, "density": 4 * indep.RHO,
                                      "conforming": True}}),
    "nonlinear": dict(mesh="taper", physics=["material.nonlinear"], truth={},
                      velocity=["0", "0", "24*x*x"], user={"material": {"model": "linear"}}),
    "damping-5k": dict(mesh="taper-5k", physics=["damping.mass"],
                       truth={"damping": {"mass": 2.0}}, truth_of="damping"),
}


def say(line: str) -> None:
    print(line, flush=True)


def _case(name: str) -> dict:
    """CASES[name] with the independent suite's ``shape`` key."""
    return dict(CASES[name], shape=MESHES[CASES[name]["mesh"]]["shape"])


def run_truth(gmsh, group: str, markers: np.ndarray, label: str, graded: bool = False,
              **kw) -> dict:
    """One truth simulation of case ``group`` at ``markers`` (cached by label; ``graded``: on a
    mesh graded towards the clamp's edges, cached as ``graded-<label>``)."""
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    end = kw.get("end", END)
    if graded:
        label = f"graded-{label}"
        kw["grade_clamp"] = True
    path = CACHE_DIR / f"{group}-{label}-{end:g}.npz"
    if (cached := indep.cached_run(path, markers, say)) is not None:
        return cached
    say(f"  {label}: {kw}")
    res = indep.simulate_truth(gmsh, group, _case(group), markers, say, newton_tol=NEWTON_TOL,
                               **kw)
    indep.save_run(path, markers, res)
    say(f"  {label}: {res['fine_tets']} P2 tets, {res['dofs']} dofs, step {res['step']:g} s, "
        f"{res['newton']} Newton iterations, {res['seconds']:.0f} s")
    return res


def difference(a: np.ndarray, b: np.ndarray) -> dict:
    """rms and max of ``a - b`` (frames, markers, 3) in units of the noise."""
    d = (a - b) / indep.NOISE
    return {"rms_over_noise": float(np.sqrt(np.mean(d ** 2))),
            "max_over_noise": float(np.abs(d).max())}


def convergence(truth: np.ndarray, space: np.ndarray, time_: np.ndarray, r_space: float,
                finer: bool | tuple[bool, bool] = True) -> dict:
    """The truth's error at the markers from one refinement in space and one in time (module
    docstring): the differences and the Richardson estimates, in units of the noise.
    ``space``/``time_``: the runs one level finer (``finer``) or one level coarser (the truth
    is then the finer run of each pair) in space / in time; a pair (space, time) of flags: each
    on its own side ("mixed")."""
    fs, ft = (finer, finer) if isinstance(finer, bool) else finer
    rs, rt = r_space ** 3, 2.0 ** 2         # P2 displacements: third order; the step halved,
    #                                         generalized-alpha: second order
    # finer: D = e_truth - e_truth / r^p; coarser: D = e_truth r^p - e_truth
    e_space = (truth - space) / (1.0 - 1.0 / rs) if fs else (space - truth) / (rs - 1.0)
    e_time = (truth - time_) / (1.0 - 1.0 / rt) if ft else (time_ - truth) / (rt - 1.0)
    zero = np.zeros_like(truth)
    sides = ["refined" if f else "coarser" for f in (fs, ft)]
    out = {
        "checked_from": sides[0] if fs == ft else "mixed",
        f"space_{sides[0]}_difference": difference(space, truth),
        f"time_{sides[1]}_difference": difference(time_, truth),
        "space_error_estimate": difference(e_space, zero),
        "time_error_estimate": difference(e_time, zero),
        "combined_error_estimate": difference(e_space + e_time, zero),
    }
    out["bound_rms_over_noise"] = (out["space_error_estimate"]["rms_over_noise"]
                                   + out["time_error_estimate"]["rms_over_noise"])
    return out


def make_group(gmsh, group: str, members: list[str], meshes: dict, check: bool, end: float,
               force: bool, check_end: float | None = None, cases_dir: Path = CASES_DIR,
               level: str = "truth", only_run: str | None = None, graded: bool = False
               ) -> None:
    """Simulate the truth of ``group`` at ``level`` (:data:`LEVELS`) once for every case in
    ``members`` (their markers together), check it by refinement (over the first ``check_end``
    s, default all), and write the cases. ``only_run``: simulate that level (a label of
    :data:`LEVELS`, over ``check_end``) into the cache and stop (so that the runs of one check
    can go in separate processes). ``graded``: every run's mesh graded towards the clamp's
    edges (README.md)."""
    check_end = min(check_end or end, end)
    picks = {}
    for name in members:
        points, tets = meshes[CASES[name]["mesh"]]
        seed = 401 + sorted(CASES).index(name)
        picks[name] = (seed, indep.pick_markers(_case(name)["shape"], points, tets, seed,
                                                MARKERS))
    allm = np.concatenate([m for _, m in picks.values()])
    if only_run:
        h, sub = LEVELS[only_run]
        run_truth(gmsh, group, allm, only_run, graded, h_fine=h, substeps=sub,
                  end=min(check_end or end, end))
        return
    levels, label = LEVELS, level
    # the runs checking the truth: "space" differs from it in the mesh only, "time" in the step
    checks = dict(zip(("space", "time"), CHECKS[label], strict=True))
    h, sub = levels[label]
    # each check run is finer or coarser than the truth (the base level: both finer; "fine"
    # and "finest": both coarser; "time": finer in space, coarser in time)
    finer = (levels[checks["space"]][0] < h, levels[checks["time"]][1] > sub)
    r_space = (levels[checks["space"]][0] / h) ** (-1 if finer[0] else 1)
    runs = {"truth": run_truth(gmsh, group, allm, label, graded, h_fine=h, substeps=sub,
                               end=end)}
    if check:
        for key, lab in checks.items():
            h, sub = levels[lab]
            runs[key] = run_truth(gmsh, group, allm, lab, graded, h_fine=h, substeps=sub,
                                  end=check_end)
    # the frames the check covers (the truth's first ones when it is shortened)
    checked = int(round(check_end / indep.STEP)) + 1
    found = np.logical_and.reduce([r["found"] for r in runs.values()])
    start = 0
    for name in members:
        seed, cand = picks[name]
        sl = slice(start, start + len(cand))
        start += len(cand)
        keep = np.flatnonzero(found[sl])[:MARKERS]
        disp = {k: r["displacements"][:, sl][:, keep] for k, r in runs.items()}
        conv = None
        if check:
            # the time-refined run's frames are the truth's (both sample every 2 ms)
            conv = convergence(disp["truth"][:checked], disp["space"], disp["time"],
                               r_space, finer=finer)
            conv["span"] = check_end
            for key in ("space", "time"):
                r = runs[key]
                conv[f"{key}_run"] = {"h": levels[checks[key]][0], "tets": r["fine_tets"],
                                      "dofs": r["dofs"], "step": r["step"],
                                      "seconds": r["seconds"]}
            ok = conv["bound_rms_over_noise"] < TOLERANCE
            conv["converged"] = bool(ok)
            say(f"{name}: truth error (rms x noise): space {conv['space_error_estimate']}, "
                f"time {conv['time_error_estimate']}, combined "
                f"{conv['combined_error_estimate']}, bound {conv['bound_rms_over_noise']:.3f}"
                f" -> {'converged' if ok else 'NOT converged'}")
            if not ok and not force:
                say(f"{name}: not written (truth error bound above {TOLERANCE} x noise)")
                continue
            if not ok:
                say(f"{name}: written with its truth error above {TOLERANCE} x the noise "
                    "(--force), truth.json says so")
        points, tets = meshes[CASES[name]["mesh"]]
        tr = runs["truth"]
        mesh_file = f"../../meshes/{CASES[name]['mesh']}.msh"
        extra = {"user_mesh": mesh_file, "coarse_tets": int(len(tets)),
                 "coarse_dofs_p1": int(3 * len(np.unique(tets))),
                 "fine_h": levels[label][0], "fine_tets": tr["fine_tets"],
                 "fine_mesh": GRADED if graded else "uniform",
                 "fine_dofs": tr["dofs"],
                 "step": tr["step"], "steps": tr["steps"], "end": end,
                 "newton_iterations": tr["newton"], "refactorizations": tr["refactors"],
                 "truth_of": group, "seconds": tr["seconds"],
                 # the simulations' seconds (the truth's and the checks'), whether run now or
                 # read from the cache
                 "generation_seconds": sum(r["seconds"] for r in runs.values()),
                 "convergence": conv, "truth_tolerance_over_noise": TOLERANCE}
        case = _case(name)
        truth = indep.write_case(
            cases_dir / name, name, case, cand[keep], disp["truth"], seed,
            indep.user_experiment(name, case, end=end, mesh_file=mesh_file),
            f"scripts/benchmarks/realistic/generate_realistic.py {name} (DOLFINx P2)", extra)
        say(f"{name}: written; {truth['coarse_tets']} user tets, {truth['fine_tets']} P2 tets "
            f"({truth['fine_dofs']} dofs), {truth['markers']} markers, {truth['frames']} frames, "
            f"max displacement {truth['max_marker_displacement']:.3g} m")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--no-check", dest="check", action="store_false",
                    help="skip the refinement check of the truth")
    ap.add_argument("--force", action="store_true",
                    help="write a case even if its truth error bound is above the tolerance")
    ap.add_argument("--fine", action="store_true",
                    help="the truth on the refined mesh at the halved step, checked from the "
                         "coarse side (by the runs refined in one of the two only)")
    ap.add_argument("--finest", action="store_true",
                    help="the truth one refinement in space beyond --fine (h = H_FINEST, the "
                         "same step), checked from the coarse side: by the --fine run and "
                         "the run on H_FINEST at twice the step")
    ap.add_argument("--graded", action="store_true",
                    help="every truth mesh graded towards the clamp's edges (README.md); the "
                         "truth is the level h 11 mm at 0.25 ms, checked by h 8 mm (same "
                         "step) and by 0.5 ms (same mesh)")
    ap.add_argument("--only-run", choices=sorted(LEVELS), default=None,
                    help="simulate this level into the cache (out/realistic_runs) and stop: "
                         "run a check's levels in parallel processes, then generate")
    ap.add_argument("--check-end", type=float, default=None,
                    help="check the truth over its first CHECK_END s only (default: all)")
    ap.add_argument("--out", type=Path, default=HERE,
                    help="write cases/ and meshes/ here (default: beside this script)")
    ap.add_argument("--end", type=float, default=END,
                    help=f"span (s; default {END}); shorter only to estimate the cost")
    args = ap.parse_args()
    if args.list:
        for k, c in CASES.items():
            print(f"{k:<12} {c['mesh']:<9} {'+'.join(c['physics']) or '-'}")
        return 0
    names = args.cases.split(",")
    bad = [n for n in names if n not in CASES]
    if bad:
        print(f"unknown case(s) {bad}; valid: {', '.join(CASES)}")
        return 2
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    meshes = {}
    for m in sorted({CASES[n]["mesh"] for n in names}):
        spec = MESHES[m]
        meshes[m] = indep.coarse_mesh(gmsh, spec["shape"], spec["h"],
                                      args.out / "meshes" / f"{m}.msh")
        say(f"{m}: user mesh {len(meshes[m][1])} tets -> meshes/{m}.msh")
    groups: dict[str, list[str]] = {}
    for n in names:
        groups.setdefault(CASES[n].get("truth_of", n), []).append(n)
    for group, members in groups.items():
        t0 = time.perf_counter()
        say(f"truth of {group} for {', '.join(members)}")
        make_group(gmsh, group, members, meshes, args.check, args.end, args.force,
                   args.check_end, args.out / "cases",
                   "time" if args.graded else "finest" if args.finest else "fine" if args.fine
                   else "truth", args.only_run, args.graded)
        say(f"{group}: {time.perf_counter() - t0:.0f} s")
    gmsh.finalize()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
