"""Does the truth's time check need the finest mesh? The step's effect |u(2 dt) - u(dt)| at the
markers on the level's mesh h against the same on its coarsest check mesh (1.96 h), from a
draw's cached runs (``DIR/.runs``; the missing run at 1.96 h and twice the step is made and
cached): ``python3 time_check_mesh.py SEED N DIR CASE [CASE ...]``. The time error is a phase
error of the body's frequencies, which differ by ~0.1 % between the meshes, so the two
differences should agree to a few per cent; the 1.96 h pair costs ~1/4 of the pair at h."""

import os
import sys
from pathlib import Path

os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import gmsh
import numpy as np
import random_cases as rc
import random_draw as rd
import random_shapes as rs

seed, n, cache = int(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3]) / ".runs"
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
cases = {c["name"]: c for c in rd.draw(seed, n, "realistic")}
for name in sys.argv[4:]:
    case = cases[name]
    h = rs.truth_h(case["geometry"])
    s = rc.SUBSTEPS
    fine = {k: np.load(cache / f"{name}-truth-h{h:.5g}-s{k}.npz") for k in (s, s // 2)}
    markers = fine[s]["markers"]
    coarse = {k: rc.run(gmsh, case, markers, f"truth-h{h * 1.96:.5g}-s{k}", cache,
                        h=h * 1.96, substeps=k) for k in (s, s // 2)}
    ok = np.logical_and.reduce([fine[s]["found"], fine[s // 2]["found"],
                                coarse[s]["found"], coarse[s // 2]["found"]])

    d_fine = rc.rms((fine[s // 2]["displacements"] - fine[s]["displacements"])[:, ok])
    d_coarse = rc.rms((coarse[s // 2]["displacements"] - coarse[s]["displacements"])[:, ok])
    print(f"{name}: the step's effect at h {d_fine * 1e6:.4g} um, at 1.96 h "
          f"{d_coarse * 1e6:.4g} um (ratio {d_coarse / d_fine:.4f}); {ok.sum()} markers",
          flush=True)
