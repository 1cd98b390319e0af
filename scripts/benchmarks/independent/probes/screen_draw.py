"""The frequency screen's choice for drawn cases, without any time run:
``python3 screen_draw.py SEED N [INDEX ...]`` (frequency_screen.choose on each case of the draw
(SEED, N), or only those INDEXes), printing the ladder, every level's prediction and the
choice; DEGREES=2,3 weighs those element degrees (default frequency_screen.DEGREES); SIZE=small
draws that size (default realistic); END=LO,HI draws the record length (s) from that range
instead of the size's."""

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
size = os.environ.get("SIZE", "realistic")
if os.environ.get("END"):
    rd.SIZES[size] = dict(rd.SIZES[size], end=tuple(float(e) for e in os.environ["END"].split(",")))
for case in rd.draw(seed, n, size):
    if only and case["index"] not in only:
        continue
    t0 = time.perf_counter()
    print(f"{case['name']}: {case['category']} {case['concealed']}, end {case['end']} s, "
          f"noise fraction {case['noise_fraction']:.4f}, excitation {case['excitation']['kind']}",
          flush=True)
    degrees = os.environ.get("DEGREES")
    c = fs.choose(gmsh, case, rc.TOLERANCE, say=lambda s: print(s, flush=True),
                  degrees=None if degrees is None else tuple(int(d) for d in degrees.split(",")))
    for degree, ladder in c["ladders"].items():
        for rung in ladder:
            print(f"  ladder P{degree} h {rung['h']:.4g}: {rung['tets']} tets, f "
                  + ", ".join(f"{f:.6g}" for f in rung["frequencies"]))
    ch = c["chosen"]
    print("  CHOICE: " + ("discard" if ch is None else
                           f"P{ch['degree']} h {ch['h']:.4g} ({ch['tets']} tets) "
                           f"x{ch['substeps']}, predicted {ch['predicted']['bound']:.3g}, "
                           f"{ch['tet_steps']:.3g} tet-steps")
          + f"  [{time.perf_counter() - t0:.0f} s]", flush=True)
