"""The effect size of a written case measured at h (its truth and effect-free twin) and on the
1.96h mesh (that level's run and a twin there, made here): the twin's level change checked."""

import json
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
from pathlib import Path

import gmsh
import numpy as np
import random_cases as rc
import random_draw as rd
import random_shapes as rs

seed, name, n, cache = int(sys.argv[1]), sys.argv[2], int(sys.argv[3]), Path(sys.argv[4])
truth = json.load(open(sys.argv[5]))
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
case = [c for c in rd.draw(seed, n, "realistic") if c["name"] == name][0]
h = rs.truth_h(case["geometry"])
z = np.load(cache / f"{name}-truth-h{h:.5g}-s4.npz")
cand = z["markers"]


def get(label, **kw):
    return rc.run(gmsh, case, cand, label, cache, **kw)


t_h = get(f"truth-h{h:.5g}-s4", h=h)
f_h = get(f"free-h{h:.5g}-s4", h=h, effect_free=True)
h2 = h * rc.COARSER**2
t_2 = get(f"truth-h{h2:.5g}-s4", h=h2)
f_2 = get(f"free-h{h2:.5g}-s4", h=h2, effect_free=True)
found = t_h["found"] & f_h["found"] & t_2["found"] & f_2["found"]
keep = np.flatnonzero(found)[: case["markers"]]
noise = truth["noise"]["position_std"]
for lab, a, b in (("h", t_h, f_h), ("1.96h", t_2, f_2)):
    d = (a["displacements"][:, keep] - b["displacements"][:, keep]) / noise
    print(
        f"{name}: effect size at {lab}: rms {np.sqrt(np.mean(d**2)):.4f}, "
        f"max {np.abs(d).max():.4f} x noise"
    )
