"""The first natural frequencies of a drawn case's body (linear elasticity at its true E, nu,
rho; clamped as its truth; P2 on the generator's truth mesh, frequency_screen.frequencies)
against the draw's estimate (random_draw.first_frequency) and a base drive's frequency:
``python3 first_frequencies.py SEED CASE N [FACTOR ...]`` (the truth's h times each FACTOR,
default 1; GRADE_FINEST=K GRADE_OVER=L: graded to h / K over L h instead of the family's
random_shapes.GRADING; GRADE_POWER=P GRADE_RADIUS=R: h (d / (R h_truth))^P instead, floored at
h / GRADE_FINEST; UNGRADED=clamp or inner: that edge left ungraded; DEGREE=3: P3 elements;
NOHOLE=1: a plate without its hole)."""

import os
import sys

os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
import frequency_screen as fs
import generate as indep
import gmsh
import numpy as np
import random_draw as rd
import random_shapes as rs

seed, name, n = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
factors = [float(f) for f in sys.argv[4:]] or [1.0]
if os.environ.get("UNGRADED") == "clamp":      # only a bracket's inner edge graded
    indep.clamp_edges = lambda gmsh, axis: []
elif os.environ.get("UNGRADED") == "inner":    # only the clamp's edges graded
    rs.reentrant_edges = lambda gmsh, g: []
case = [c for c in rd.draw(seed, n, "realistic") if c["name"] == name][0]
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
if os.environ.get("NOHOLE"):            # the plate's hole cut away from nothing
    gmsh.model.occ.cut = lambda obj, tool, **k: gmsh.model.occ.remove(tool, recursive=True)

for factor in factors:
    freqs, tets = fs.frequencies(gmsh, case, rs.truth_h(case["geometry"]) * factor, modes=4,
                                 degree=int(os.environ.get("DEGREE", 2)))
    est = rd.first_frequency(case["family"], case["geometry"], case["material"])
    base = case["excitation"].get("base")
    drive = f", base drive {base['omega'] / (2 * np.pi):.3g} Hz" if base else ""
    print(f"{name} h x {factor:g} ({tets} tets): first frequencies "
          f"{', '.join(f'{f:.6g}' for f in freqs)} Hz, split {freqs[1] - freqs[0]:.5g}; "
          f"the draw's estimate {est:.3g} Hz{drive}", flush=True)
