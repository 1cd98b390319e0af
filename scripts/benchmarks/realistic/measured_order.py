"""The order of the truth's spatial error, measured from three meshes (README.md).

Reads the cached clean marker runs of a case (``out/realistic_runs/<case>-<level>-1.npz``, made
by ``generate_realistic.py``) on h = 11, 8 and 5.8 mm at one step (0.25 ms: the levels ``time``,
``fine``, ``finest``) and prints, over the whole record and its first and last 0.2 s, in units
of the noise (rms): D1 = |u11 - u8|, D2 = |u8 - u5.8|, the order p from D1 / D2 = r^p (r =
11/8 = 8/5.8, the nominal ratio), the cosine of the two difference fields (near 1: one error
shape, an order; far from 1: mesh-to-mesh scatter) and, if cached, D2 at 0.5 ms (``space``,
``finest-space``). Markers and frames as the generator takes them. ``--span S``: the runs on
5.8 mm cover the first S s only (``generate_realistic.py --only-run finest --check-end S``); all
runs are compared over those frames. ``--write``: record the order (whole span) in the case's
``truth.json`` -> ``convergence`` -> ``measured_order``, with the truth's space error
re-estimated at that order from the check's own space difference (``D / (r^p - 1)`` when the
truth is the finer run of the pair, ``D / (1 - r^-p)`` when it is the coarser: a graded truth)
and the bound with the time estimate; ``converged`` then also requires that bound below the
tolerance. ``--graded``: the runs on meshes graded towards the clamp's edges
(``generate_realistic.py --graded``; cache labels ``graded-<level>``)::

    /usr/bin/python3 scripts/benchmarks/realistic/measured_order.py [--span 0.5] [--graded] \
        [--write] case ...
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from generate_realistic import CACHE_DIR, CASES_DIR, H_FINEST, H_REFINED, H_TRUTH, MARKERS, indep


def record(case: str, p: float, span: float, cosine: float, graded: bool = False,
           used: tuple[float, str] | None = None) -> None:
    """Write the measured order ``p`` into ``cases/<case>/truth.json`` (module docstring);
    ``used``: (order, why): estimate the error at that order instead (the case's own
    measurement recorded beside it), e.g. when its difference fields are not one shape."""
    path = CASES_DIR / case / "truth.json"
    truth = json.loads(path.read_text())
    conv = truth["convergence"]
    if truth.get("fine_mesh", "uniform").startswith("graded") != graded:
        raise ValueError(f"{case}: its truth mesh is {truth.get('fine_mesh', 'uniform')}, the "
                         f"runs measured {'graded' if graded else 'uniform'}")
    meshes = "graded towards the clamp's edges" if graded else "uniform"
    own = {"p": p, "from": f"h 11, 8, 5.8 mm at 0.25 ms, {meshes} (measured_order.py)",
           "span": span, "cosine": cosine}
    if used is not None:
        p = used[0]
    h_other, h = conv["space_run"]["h"], truth["fine_h"]
    if h_other > h:     # the truth is the finer of the pair: D = e (r^p - 1)
        space = conv["space_coarser_difference"]["rms_over_noise"] / ((h_other / h) ** p - 1.0)
    else:               # the coarser: D = e (1 - r^-p)
        space = conv["space_refined_difference"]["rms_over_noise"] / (1.0 - (h_other / h) ** p)
    bound = space + conv["time_error_estimate"]["rms_over_noise"]
    tol = truth["truth_tolerance_over_noise"]
    conv["measured_order"] = (own if used is None else
                              {"p": used[0], "from": used[1], "this_case": own}) | {
        "space_error_estimate_rms": space, "bound_rms_over_noise": bound}
    conv["converged"] = bool(conv["bound_rms_over_noise"] < tol and bound < tol)
    path.write_text(json.dumps(truth, indent=1) + "\n")
    print(f"{case}: at p {p:.2f} the truth's space error is {space:.3f}, bound {bound:.3f} x the "
          f"noise -> converged {conv['converged']} (truth.json written)")


def main(cases: list[str], span: float = 1.0, write: bool = False, graded: bool = False,
         used: tuple[float, str] | None = None) -> int:
    r = H_TRUTH / H_REFINED
    assert abs(H_REFINED / H_FINEST - r) < 0.01     # the nominal ratio of both pairs
    for case in cases:
        pre = "graded-" if graded else ""
        runs = {}
        for k in ("time", "fine", "finest", "space", "finest-space"):
            # the 5.8 mm runs over ``span``; the others over the longest span cached (a check
            # run over the first 0.5 s only: all runs are compared over the common frames)
            stems = [f.stem.rsplit("-", 1) for f in CACHE_DIR.glob(f"{case}-{pre}{k}-*.npz")]
            spans = [float(tail) for head, tail in stems if head == f"{case}-{pre}{k}"]
            spans = [sp for sp in spans if sp == span or not k.startswith("finest")]
            if spans:
                runs[k] = np.load(CACHE_DIR / f"{case}-{pre}{k}-{max(spans):g}.npz",
                                  allow_pickle=True)
        missing = {"time", "fine", "finest"} - set(runs)
        if missing:
            print(f"{case}: runs {sorted(missing)} not cached (generate_realistic.py --only-run)")
            continue
        found = np.logical_and.reduce([z["found"] for z in runs.values()])
        keep = np.flatnonzero(found)[:MARKERS]
        frames = min(len(z["displacements"]) for z in runs.values())
        u = {k: z["displacements"][:frames, keep] / indep.NOISE for k, z in runs.items()}
        last = frames - int(round(0.2 / indep.STEP)) - 1
        windows = {"all": slice(None)}
        if frames > 101:
            windows |= {"first 0.2 s": slice(0, 101), "last 0.2 s": slice(last, None)}
        if frames > 251:        # comparable with a run over 0.5 s
            windows["first 0.5 s"] = slice(0, 251)
        for name, sl in windows.items():
            d1 = u["time"][sl] - u["fine"][sl]
            d2 = u["fine"][sl] - u["finest"][sl]
            rms1, rms2 = np.sqrt(np.mean(d1 ** 2)), np.sqrt(np.mean(d2 ** 2))
            cos = np.sum(d1 * d2) / np.sqrt(np.sum(d1 ** 2) * np.sum(d2 ** 2))
            extra = ""
            if "space" in u and "finest-space" in u:
                extra = (f", D2 at 0.5 ms "
                         f"{np.sqrt(np.mean((u['space'][sl] - u['finest-space'][sl]) ** 2)):.3f}")
            print(f"{case} ({name} of {(frames - 1) * indep.STEP:g} s): D1 {rms1:.3f}, "
                  f"D2 {rms2:.3f}, D1/D2 {rms1 / rms2:.2f} -> p "
                  f"{np.log(rms1 / rms2) / np.log(r):.2f}, cosine {cos:.3f}{extra}")
            if name == "all":
                whole = (float(np.log(rms1 / rms2) / np.log(r)), float(cos))
        if write:
            record(case, whole[0], (frames - 1) * indep.STEP, whole[1], graded, used)
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--span", type=float, default=1.0,
                    help="the 5.8 mm runs' span (s; their cache files' suffix)")
    ap.add_argument("--graded", action="store_true",
                    help="the runs on meshes graded towards the clamp's edges (graded-<level>)")
    ap.add_argument("--use-order", type=float, default=None,
                    help="with --write: estimate the error at this order (measured elsewhere, "
                         "--why says where), recording the case's own beside it")
    ap.add_argument("--why", default="", help="where --use-order was measured")
    ap.add_argument("--write", action="store_true",
                    help="record the order and the bound at it in the cases' truth.json")
    args = ap.parse_args()
    if args.use_order is not None and not args.why:
        ap.error("--use-order needs --why (where that order was measured)")
    used = None if args.use_order is None else (args.use_order, args.why)
    raise SystemExit(main(args.cases, args.span, args.write, args.graded, used))
