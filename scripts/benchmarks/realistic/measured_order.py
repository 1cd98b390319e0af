"""The order of the truth's spatial error, measured from three meshes (README.md).

Reads the cached clean marker runs of a case (``out/realistic_runs/<case>-<level>-1.npz``, made
by ``generate_realistic.py``) on h = 11, 8 and 5.8 mm at one step (0.25 ms: the levels ``time``,
``fine``, ``finest``) and prints, over the whole record and its first and last 0.2 s, in units
of the noise (rms): D1 = |u11 - u8|, D2 = |u8 - u5.8|, the order p from D1 / D2 = r^p (r =
11/8 = 8/5.8, the nominal ratio), the cosine of the two difference fields (near 1: one error
shape, an order; far from 1: mesh-to-mesh scatter) and, if cached, D2 at 0.5 ms (``space``,
``finest-space``). Markers and frames as the generator takes them::

    /usr/bin/python3 scripts/benchmarks/realistic/measured_order.py nonlinear [payload ...]
"""

from __future__ import annotations

import sys

import numpy as np
from generate_realistic import CACHE_DIR, H_FINEST, H_REFINED, H_TRUTH, MARKERS, indep


def main(cases: list[str]) -> int:
    r = H_TRUTH / H_REFINED
    assert abs(H_REFINED / H_FINEST - r) < 0.01     # the nominal ratio of both pairs
    for case in cases:
        labels = ["time", "fine", "finest", "space", "finest-space"]
        runs = {k: np.load(CACHE_DIR / f"{case}-{k}-1.npz", allow_pickle=True)
                for k in labels if (CACHE_DIR / f"{case}-{k}-1.npz").exists()}
        missing = {"time", "fine", "finest"} - set(runs)
        if missing:
            print(f"{case}: runs {sorted(missing)} not cached (generate_realistic.py --only-run)")
            continue
        found = np.logical_and.reduce([z["found"] for z in runs.values()])
        keep = np.flatnonzero(found)[:MARKERS]
        u = {k: z["displacements"][:, keep] / indep.NOISE for k, z in runs.items()}
        frames = len(u["fine"])
        last = frames - int(round(0.2 / indep.STEP)) - 1
        for name, sl in (("all", slice(None)), ("first 0.2 s", slice(0, 101)),
                         ("last 0.2 s", slice(last, None))):
            d1 = u["time"][sl] - u["fine"][sl]
            d2 = u["fine"][sl] - u["finest"][sl]
            rms1, rms2 = np.sqrt(np.mean(d1 ** 2)), np.sqrt(np.mean(d2 ** 2))
            cos = np.sum(d1 * d2) / np.sqrt(np.sum(d1 ** 2) * np.sum(d2 ** 2))
            extra = ""
            if "space" in u and "finest-space" in u:
                extra = (f", D2 at 0.5 ms "
                         f"{np.sqrt(np.mean((u['space'][sl] - u['finest-space'][sl]) ** 2)):.3f}")
            print(f"{case} ({name}): D1 {rms1:.3f}, D2 {rms2:.3f}, D1/D2 {rms1 / rms2:.2f} -> "
                  f"p {np.log(rms1 / rms2) / np.log(r):.2f}, cosine {cos:.3f}{extra}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:] or ["nonlinear"]))
