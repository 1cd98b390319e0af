"""One truth run of a drawn case at its generator's h, both Newton stops; prints iterations,
time and the marker difference in noise units."""

import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
import generate as indep
import gmsh
import numpy as np
import random_cases as rc
import random_shapes as rs
import truth_convergence as tc

seed, name, n, end = int(sys.argv[1]), sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
case, markers = tc.drawn_case_points(gmsh, seed, name, n, inside=1.0)
g = case["geometry"]
out = {}
for est in (False, True):
    t0 = time.perf_counter()
    res = indep.simulate_truth(
        gmsh,
        name,
        {"shape": case["family"], "truth": case["truth"]},
        markers,
        lambda line: None,
        h_fine=rs.truth_h(g),
        end=end,
        newton_tol=rc.NEWTON_TOL,
        body=rc.body(case),
        newton_estimate=est,
    )
    out[est] = res["displacements"]
    print(
        f"estimate={est}: {res['fine_tets']} tets, {res['newton']} iterations in "
        f"{res['steps']} steps, "
        f"{res['refactors']} refactors, {time.perf_counter() - t0:.0f} s",
        flush=True,
    )
d = out[True] - out[False]
print(
    f"largest displacement {np.abs(out[False]).max():.3e} m; difference rms "
    f"{np.sqrt(np.mean(d**2)):.3e} m, max {np.abs(d).max():.3e} m"
)
