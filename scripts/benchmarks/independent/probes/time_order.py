"""The truth's order in time, from a draw's cached runs at 2, 4 and 8 steps a frame on one mesh:
``python3 time_order.py SEED N DIR CASE [CASE ...]`` (the runs ``DIR/.runs/CASE-truth-hH-sS``
at the truth's h; missing runs are made and cached). Printed (m, rms over markers and frames):
D(2, 4) = |u(4) - u(2)| and D(4, 8), the observed order log2(D(2, 4) / D(4, 8)), and the
difference between Richardson's R(4, 2) = u(4) + (u(4) - u(2)) / 3 and R(8, 4), which is far
below D(4, 8) only if the runs are in generalized-alpha's second-order regime."""

import _cached  # first: one BLAS thread, the generator's folder on the path
import gmsh
import numpy as np
import random_cases as rc

cache, todo = _cached.cases_from_argv()
for case, h in todo:
    name = case["name"]
    markers = np.load(cache / f"{name}-truth-h{h:.5g}-s4.npz")["markers"]
    runs = {s: rc.run(gmsh, case, markers, f"truth-h{h:.5g}-s{s}", cache, h=h, substeps=s)
            for s in (2, 4, 8)}
    ok = np.logical_and.reduce([r["found"] for r in runs.values()])
    u = {s: r["displacements"][:, ok] for s, r in runs.items()}
    d24, d48 = rc.rms(u[4] - u[2]), rc.rms(u[8] - u[4])
    r42, r84 = u[4] + (u[4] - u[2]) / 3, u[8] + (u[8] - u[4]) / 3
    print(f"{name}: D(2, 4) {d24:.4g} m, D(4, 8) {d48:.4g} m, observed order "
          f"{np.log2(d24 / d48):.2f}; |R(4, 2) - R(8, 4)| {rc.rms(r42 - r84):.4g} m", flush=True)
