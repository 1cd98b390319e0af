"""The truth's step effect D(dt, dt/2) at generalized-alpha rho_inf 0.9 and 0.5 on a drawn case
(at 1.4 h; a bar's points 30 % inside): python3 rinf.py SEED CASE N END (environment: RINFS,
the two rho_inf compared, default "0.9,0.5"; HFACTOR, the mesh's h over the truth's, 1.4)."""

import os
import sys

os.environ["OPENBLAS_NUM_THREADS"] = "1"
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
case, markers = tc.drawn_case_points(gmsh, seed, name, n)
g = case["geometry"]
if case["family"] == "bar":
    markers[:, 1:] *= 0.7          # inside every mesh (truth_convergence.py --inside)
out = {}
rinfs = tuple(float(r) for r in os.environ.get("RINFS", "0.9,0.5").split(","))
for rinf in rinfs:
    indep.ALPHA_RADIUS = rinf
    for sub in (4, 8):
        res = indep.simulate_truth(
            gmsh,
            name,
            {"shape": case["family"], "truth": case["truth"]},
            markers,
            lambda l: None,
            h_fine=rs.truth_h(g) * float(os.environ.get("HFACTOR", 1.4)),
            end=end,
            substeps=sub,
            newton_tol=rc.NEWTON_TOL,
            body=rc.body(case),
            newton_estimate=True,
        )
        out[rinf, sub] = res["displacements"][:, res["found"]]
        print(rinf, sub, res["newton"], "iterations", flush=True)
for rinf in rinfs:
    d = out[rinf, 4] - out[rinf, 8]
    print(f"rho_inf {rinf}: D(dt, dt/2) rms {np.sqrt(np.mean(d**2)):.3e} m")
d = out[rinfs[0], 8] - out[rinfs[1], 8]
print(
    f"rho_inf {rinfs[0]} vs {rinfs[1]} at dt/2: rms {np.sqrt(np.mean(d**2)):.3e} m; largest "
    f"displacement {np.abs(out[rinfs[0], 8]).max():.3e}"
)
