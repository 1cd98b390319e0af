"""Can the truth's time error be removed by the step's effect measured on the coarsest check
mesh? From a draw's cached runs (``DIR/.runs``; missing runs are made and cached):
``python3 time_richardson.py SEED N DIR CASE [CASE ...]``. With u(h, s) the run on mesh h at s
steps a frame, the reference is Richardson's u(h, 8) + (u(h, 8) - u(h, 4)) / 3; printed, in
units of the case's noise (rms over markers and frames): the plain truth's time error
|u(h, 4) - ref| and the corrected truth's |u(h, 4) + (u(1.96 h, 4) - u(1.96 h, 2)) / 3 - ref|."""

import _cached  # first: one BLAS thread, the generator's folder on the path
import gmsh
import numpy as np
import random_cases as rc
import random_draw as rd

cache, todo = _cached.cases_from_argv()
for case, h in todo:
    name = case["name"]
    markers = np.load(cache / f"{name}-truth-h{h:.5g}-s4.npz")["markers"]
    runs = {(k, s): rc.run(gmsh, case, markers, f"truth-h{h * k:.5g}-s{s}", cache,
                           h=h * k, substeps=s)
            for k, s in ((1.0, 4), (1.0, 8), (1.96, 4), (1.96, 2))}
    ok = np.logical_and.reduce([r["found"] for r in runs.values()])
    u = {key: r["displacements"][:, ok] for key, r in runs.items()}
    # the case's noise as the generator set it: the drawn fraction of the largest marker
    # displacement (here over every marker found, not only the kept ones)
    noise = rd.noise_level(case["noise_fraction"],
                           float(np.linalg.norm(u[1.0, 4], axis=-1).max()))
    ref = u[1.0, 8] + (u[1.0, 8] - u[1.0, 4]) / 3
    plain = rc.rms(u[1.0, 4] - ref) / noise
    corrected = rc.rms(u[1.0, 4] + (u[1.96, 4] - u[1.96, 2]) / 3 - ref) / noise
    print(f"{name}: time error of the truth {plain:.4g} x noise, corrected by the coarse "
          f"mesh's step effect {corrected:.4g} x noise (ratio {corrected / plain:.3g}); "
          f"{ok.sum()} markers", flush=True)
