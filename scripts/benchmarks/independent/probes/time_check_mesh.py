"""Does the truth's time check need the finest mesh? The step's effect |u(2 dt) - u(dt)| at the
markers on the level's mesh h against the same on its coarsest check mesh (1.96 h), from a
draw's cached runs (``DIR/.runs``; the missing run at 1.96 h and twice the step is made and
cached): ``python3 time_check_mesh.py SEED N DIR CASE [CASE ...]``. The time error is a phase
error of the body's frequencies, which differ by ~0.1 % between the meshes, so the two
differences should agree to a few per cent; the 1.96 h pair costs ~1/4 of the pair at h."""

import _cached  # first: one BLAS thread, the generator's folder on the path
import gmsh
import numpy as np
import random_cases as rc

cache, todo = _cached.cases_from_argv()
for case, h in todo:
    name = case["name"]
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
