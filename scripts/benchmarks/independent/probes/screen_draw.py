"""The frequency screen's choice for drawn cases, without any time run:
``python3 screen_draw.py SEED N [INDEX ...]`` (frequency_screen.choose on each case of the draw
(SEED, N), or only those INDEXes), printing the ladder, every level's prediction and the
choice."""

import os
import sys
import time

os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
import frequency_screen as fs
import gmsh
import random_cases as rc
import random_draw as rd

seed, n = int(sys.argv[1]), int(sys.argv[2])
only = {int(i) for i in sys.argv[3:]}
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
for case in rd.draw(seed, n, "realistic"):
    if only and case["index"] not in only:
        continue
    t0 = time.perf_counter()
    print(f"{case['name']}: {case['category']} {case['concealed']}, end {case['end']} s, "
          f"noise fraction {case['noise_fraction']:.4f}, excitation {case['excitation']['kind']}",
          flush=True)
    c = fs.choose(gmsh, case, rc.TOLERANCE, say=lambda s: print(s, flush=True))
    for rung in c["ladder"]:
        print(f"  ladder h {rung['h']:.4g}: {rung['tets']} tets, f "
              + ", ".join(f"{f:.6g}" for f in rung["frequencies"]))
    ch = c["chosen"]
    print("  CHOICE: " + ("discard" if ch is None else
                           f"h {ch['h']:.4g} ({ch['tets']} tets) x{ch['substeps']}, predicted "
                           f"{ch['predicted']['bound']:.3g}, {ch['tet_steps']:.3g} tet-steps")
          + f"  [{time.perf_counter() - t0:.0f} s]", flush=True)
