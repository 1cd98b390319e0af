"""A drawn case's truth on one of its meshes (h x FACTOR) for END seconds, printing each step's
Newton increments (RINF=rho_inf, default 0.9): ``python3 release_blowup.py [SEED CASE N FACTOR
END]``, default the test draw 188067709's r002-bar on its 1.96 h check mesh for 3 ms, which
blows up at rho_inf 0.9."""

import os
import sys

os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
import generate as indep
import gmsh
import numpy as np
import random_cases as rc
import random_draw as rd
import random_shapes as rs

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
args = sys.argv[1:] or ["188067709", "r002-bar", "3", "1.96", "0.003"]
seed, name, n, factor, end = int(args[0]), args[1], int(args[2]), float(args[3]), float(args[4])
case = [c for c in rd.draw(seed, n, "realistic") if c["name"] == name][0]
g = case["geometry"]
rs.mesh(gmsh, case["family"], g, 0.015)
pts, tets = rs._nodes_tets(gmsh)
gmsh.model.remove()
markers = pts[np.unique(indep.surface_nodes(tets))[:10]]
indep.ALPHA_RADIUS = float(os.environ.get("RINF", "0.9"))
orig = indep.newton_done
log = []


def done(size, last, tol, est):
    log.append(size)
    r = orig(size, last, tol, est)
    if r:
        print("step sizes", " ".join(f"{s:.2e}" for s in log))
        log.clear()
    return r


indep.newton_done = done
try:
    indep.simulate_truth(
        gmsh,
        name,
        {"shape": case["family"], "truth": case["truth"]},
        markers,
        lambda l: None,
        h_fine=rs.truth_h(g) * factor,
        end=end,
        newton_tol=rc.NEWTON_TOL,
        body=rc.body(case),
        newton_estimate=True,
    )
except RuntimeError as e:
    print("FAILED", e, "sizes so far", " ".join(f"{s:.2e}" for s in log))
