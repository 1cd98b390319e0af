"""The convergence of a drawn case's truth at its surface: three meshes, one variant.

Runs generate.py's ``simulate_truth`` for case NAME of the random draw SEED (random_draw.py) at
h x 1.96, h x 1.4 and h, h the generator's truth size (random_shapes.truth_h), over the first
END seconds, at 20 surface nodes of a coarse mesh of the body, and prints the rms differences
D(1.96h, 1.4h), D(1.4h, h), the observed order log(D2 / D1) / log 1.4 and the eight markers with
the largest D(1.4h, h). A variant changes one thing of the truth's mesh (``a+b``: both)::

    generator      as the generator makes it
    flat           no second-order (curved) cells
    curved         second-order (curved) cells for the bars and brackets too
    flatbar        the bars' cells flat (the generator's before the bars were curved)
    uniform        no grading towards the clamp's edges (or any other)
    nostall        Newton never accepts a slow contraction below 1e-7 m (generate.newton_done)
    grade:K        the clamp's edges graded to h / K over 6 h (the generator: h / 4 over 4 h)
    thickness      a plate's h from its thickness alone (the rule before 01f283b)
    scale:F        the generator's h times F (the three meshes at F h x 1.96, 1.4, 1)

Run with the system python (DOLFINx, gmsh), one process per variant::

    /usr/bin/python3 scripts/benchmarks/independent/truth_convergence.py --seed 604960342 \\
        --case r000-plate --end 0.25 --variant generator

Measured (README.md, "A plate's thinnest section"): the test draw 604960342's r000-plate.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generate as indep  # noqa: E402
import random_cases as rc  # noqa: E402
import random_draw as rd  # noqa: E402
import random_shapes as rs  # noqa: E402

LEVELS = (1.96, 1.4, 1.0)


def apply_variant(variant: str) -> None:
    """Change the truth's meshing as ``variant`` says (module docstring)."""
    if variant == "generator":
        return
    if variant == "flat":
        rs.CURVED = ()
        return
    if variant == "curved":
        rs.CURVED = tuple(rs.CURVED) + ("bar", "bracket")
        return
    if variant == "flatbar":
        rs.CURVED = tuple(f for f in rs.CURVED if f != "bar")
        return
    if variant == "nostall":
        def done(size, last, tol, estimate):
            # no acceptance of a slow contraction below 1e-7 m: the tolerance or the estimate
            if size < tol:
                return True
            if not estimate or not np.isfinite(last) or last <= 0.0:
                return False
            rho = size / last
            return rho < 0.5 and size * rho / (1.0 - rho) < tol
        indep.newton_done = done
        return
    if variant == "uniform":
        def no_grading(gmsh, curves, h, field_only=False):
            return None
        indep.grade_towards = no_grading
        return
    if variant.startswith("grade:"):
        k = float(variant.split(":", 1)[1])
        generator_grading = indep.grade_towards

        def grade(gmsh, curves, h, field_only=False):
            generator_grading(gmsh, curves, h, field_only, finest=k, over=6.0, points=100)
        indep.grade_towards = grade
        return
    if variant == "thickness":
        generator_h = rs.truth_h

        def truth_h(g):
            return generator_h({**g, "section": g.get("thickness", g["section"])})
        rs.truth_h = truth_h
        return
    if variant.startswith("scale:"):
        factor = float(variant.split(":", 1)[1])
        generator_h = rs.truth_h

        def truth_h(g):
            return generator_h(g) * factor
        rs.truth_h = truth_h
        return
    raise SystemExit(f"unknown variant {variant!r}: generator, flat, uniform, grade:K, "
                     "thickness or scale:F")


def drawn_case_points(gmsh, seed: int, name: str, draw: int, inside: float = 1.0):
    """Case ``name`` among the first ``draw`` of the realistic draw ``seed``, and 20 points on its
    surface (nodes of a 15 mm mesh of the body, chosen by a fixed seed); ``inside`` < 1 moves a
    bar's points towards its axis by that factor of their distance (its sections are centred
    on x)."""
    found = [c for c in rd.draw(seed, draw, "realistic") if c["name"] == name]
    if not found:
        raise SystemExit(f"no case {name!r} among the first {draw} of seed {seed}")
    case = found[0]
    rs.mesh(gmsh, case["family"], case["geometry"], 0.015)
    points, tets = rs._nodes_tets(gmsh)
    gmsh.model.remove()
    surface = np.unique(indep.surface_nodes(tets))
    markers = points[np.random.default_rng(0).choice(surface, 20, replace=False)]
    if inside != 1.0:
        if case["family"] != "bar":
            raise SystemExit("--inside is for the bar family (its sections centred on x)")
        markers[:, 1:] *= inside
    return case, markers


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--case", required=True, help="e.g. r000-plate")
    ap.add_argument("--end", type=float, default=0.25, help="seconds simulated (default 0.25)")
    ap.add_argument("--variant", default="generator")
    ap.add_argument("--draw", type=int, default=40, help="cases drawn to find CASE in")
    ap.add_argument("--degree", type=int, default=2, help="the truth's element degree")
    ap.add_argument("--inside", type=float, default=1.0,
                    help="a bar's points moved towards its axis by this factor of their "
                         "distance (default 1: on the surface)")
    ap.add_argument("--substeps", type=int, default=rc.SUBSTEPS,
                    help="truth steps a frame of the user's (default the generator's: the "
                         "three meshes at one step; twice it halves the step)")
    args = ap.parse_args(argv)
    for part in args.variant.split("+"):        # e.g. uniform+scale:0.6
        apply_variant(part)
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    case, markers = drawn_case_points(gmsh, args.seed, args.case, args.draw, args.inside)
    g = case["geometry"]
    runs, found = {}, None
    for f in LEVELS:
        t0 = time.perf_counter()
        res = indep.simulate_truth(gmsh, case["name"], {"shape": case["family"],
                                                        "truth": case["truth"]},
                                   markers, lambda line: None, h_fine=rs.truth_h(g) * f,
                                   end=args.end, newton_tol=rc.NEWTON_TOL, body=rc.body(case),
                                   substeps=args.substeps, newton_estimate=True,
                                   degree=args.degree)
        runs[f] = res["displacements"]
        found = res["found"] if found is None else found & res["found"]
        print(f"{args.variant} {case['name']} h x{f} ({rs.truth_h(g) * f * 1e3:.2f} mm, "
              f"{args.substeps} steps a frame): "
              f"{res['fine_tets']} P2 tets, {time.perf_counter() - t0:.0f} s", flush=True)
    # a marker outside one of the meshes (a curved or twisted surface) is left out, as the
    # generator leaves it out
    print(f"{int(found.sum())} of {len(found)} markers inside every mesh")
    runs = {f: d[:, found] for f, d in runs.items()}
    markers = markers[found]
    d2 = float(np.sqrt(np.mean((runs[1.4] - runs[1.96]) ** 2)))
    d1 = float(np.sqrt(np.mean((runs[1.0] - runs[1.4]) ** 2)))
    order = np.log(d2 / d1) / np.log(1.4)
    print(f"{args.variant} {case['name']}: D(1.96h,1.4h) {d2:.3e} m, D(1.4h,h) {d1:.3e} m, "
          f"observed order {order:.2f}; largest displacement {np.abs(runs[1.0]).max():.3e} m")
    per = np.sqrt(np.mean((runs[1.0] - runs[1.4]) ** 2, axis=(0, 2)))
    axis = "xyz".index(g["axis"])
    for i in np.argsort(-per)[:8]:
        print(f"  marker at {np.round(markers[i], 4)} ({markers[i][axis]:.3f} of "
              f"{g['length']:.3f} along the axis): D(1.4h,h) {per[i]:.2e} m, largest "
              f"displacement {np.abs(runs[1.0][:, i]).max():.2e} m")
    gmsh.finalize()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
