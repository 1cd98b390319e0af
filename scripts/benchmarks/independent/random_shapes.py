"""gmsh solids of the random cases' shape families (random_draw.py draws their dimensions).

Every family is clamped at the plane where its axis coordinate is 0 (x = 0, or z = 0 for the
L-shapes): :func:`clamp_expression` is petsoft's ``where`` and :func:`clamp_mask` its numpy twin.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generate as indep  # noqa: E402


def build(gmsh, family: str, g: dict, regions: list | None = None) -> dict[int, list[int]]:
    """The solid of ``family`` with dimensions ``g`` in the current gmsh model (metres), as the
    physical volume ``body``; with ``regions`` (the truth's spheres and slabs, random_draw.py)
    cut into parts that conform to them (``generate.conform``), whose physical groups it returns
    by region index."""
    occ = gmsh.model.occ
    if family == "bar":
        # ruled sections root -> mid -> tip, each turned by its share of the twist about x
        wires = []
        for f in (0.0, 0.5, 1.0):
            hy = g["width"] / 2 * (1 + f * (g["taper_w"] - 1))
            hz = g["height"] / 2 * (1 + f * (g["taper_h"] - 1))
            a = math.radians(g["twist_deg"]) * f
            ca, sa = math.cos(a), math.sin(a)
            p = [occ.addPoint(f * g["length"], ca * sy * hy - sa * sz * hz,
                              sa * sy * hy + ca * sz * hz)
                 for sy, sz in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            wires.append(occ.addWire([occ.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]))
        occ.addThruSections(wires, makeSolid=True, makeRuled=True)
    elif family in ("bracket", "fillet"):
        a = g["thickness"]
        post = occ.addBox(0.0, 0.0, 0.0, a, a, g["post"])
        arm = occ.addBox(0.0, 0.0, g["post"] - a, g["arm"], a, a)
        out, _ = occ.fuse([(3, post)], [(3, arm)])
        if family == "fillet":
            occ.synchronize()
            edges = reentrant_edges(gmsh, g)
            occ.fillet([v[1] for v in out], edges, [g["fillet_radius"]], removeVolume=True)
    elif family == "plate":
        plate = occ.addBox(0.0, 0.0, 0.0, g["length"], g["width"], g["thickness"])
        hole = occ.addCylinder(g["hole_x"], g["width"] / 2, -0.01, 0.0, 0.0,
                               g["thickness"] + 0.02, g["hole_radius"])
        occ.cut([(3, plate)], [(3, hole)])
    elif family == "shell":
        # an annular sector in the y-z plane (mid-surface radius R about (0, 0, -R), its top
        # at the origin), extruded along x
        R, t, phi = g["radius"], g["thickness"], g["width"] / g["radius"]
        centre = occ.addPoint(0.0, 0.0, -R)
        pts = [[occ.addPoint(0.0, r * math.sin(s * phi / 2), r * math.cos(s * phi / 2) - R)
                for s in (-1, 1)] for r in (R - t / 2, R + t / 2)]
        inner = occ.addCircleArc(pts[0][0], centre, pts[0][1])
        outer = occ.addCircleArc(pts[1][0], centre, pts[1][1])
        occ.remove([(0, centre)])       # else gmsh meshes it: a stray node
        side1 = occ.addLine(pts[0][1], pts[1][1])
        side0 = occ.addLine(pts[1][0], pts[0][0])
        loop = occ.addCurveLoop([inner, side1, -outer, side0])
        surf = occ.addPlaneSurface([loop])
        occ.extrude([(2, surf)], g["length"], 0.0, 0.0)
    else:
        raise ValueError(family)
    occ.synchronize()
    if regions:
        return indep.conform(gmsh, regions)
    vols = gmsh.model.getEntities(3)
    gmsh.model.addPhysicalGroup(3, [v[1] for v in vols], 1)
    gmsh.model.setPhysicalName(3, 1, "body")
    return {}


def reentrant_edges(gmsh, g: dict) -> list[int]:
    """The L's inner corner edge (along y at x = a, z = post - a), after the fuse."""
    a, z, eps = g["thickness"], g["post"] - g["thickness"], 1e-6
    edges = gmsh.model.getEntitiesInBoundingBox(a - eps, -eps, z - eps, a + eps, a + eps,
                                                z + eps, dim=1)
    if not edges:
        raise RuntimeError("no edge found at the L's re-entrant corner")
    return [e[1] for e in edges]


def mesh(gmsh, family: str, g: dict, h: float, graded: bool = False,
         regions: list | None = None) -> dict[int, list[int]]:
    """Mesh the solid in a new gmsh model with element size ``h``; ``graded`` (the truth's
    meshes): down to h / finest at the clamped face's edges and at a sharp L's re-entrant edge,
    where the stress is singular, growing to h over ``over`` h (:data:`GRADING`: 4 and 4, a
    bracket's 10 and 6; ``generate.grade_towards``, the sizes from the field only; the
    environment's GRADE_FINEST, GRADE_OVER, GRADE_POINTS for probes), with curved
    (second-order) cells for the :data:`CURVED` families. Uniform
    P2 meshes of the realistic cases' clamped bar converged at ~h^1-1.6 at the markers and
    ~h^1.1-1.8 in the first frequencies: the clamp's edges (../realistic/README.md).
    ``regions``: the cells conform to them, curved (``generate.conform``; returned as there)."""
    gmsh.model.add(f"{family}-{h}")
    tagged = build(gmsh, family, g, regions)
    finest, over = GRADING.get(family, GRADING["default"])
    finest = float(os.environ.get("GRADE_FINEST", finest))      # probes: another grading
    over = float(os.environ.get("GRADE_OVER", over))
    # the size floor follows the grading: gmsh clips the field's sizes to it
    gmsh.option.setNumber("Mesh.CharacteristicLengthMin", h / finest if graded else h)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
    if graded:
        curves = indep.clamp_edges(gmsh, "xyz".index(g["axis"]))
        if family == "bracket":
            curves += reentrant_edges(gmsh, g)
        power = os.environ.get("GRADE_POWER")
        indep.grade_towards(gmsh, curves, h, field_only=True, finest=finest, over=over,
                            points=int(os.environ.get("GRADE_POINTS", 50)),
                            power=None if power is None else float(power),
                            radius=float(os.environ.get("GRADE_RADIUS", 4.0)) * truth_h(g))
    try:
        indep.generate_tets(gmsh)
    finally:
        indep.size_options(gmsh)
    if graded and (family in CURVED or tagged):
        # second-order cells on the curved faces: on the suite's plate (its hole) they halved
        # the first frequency's error of the graded mesh (../realistic/README.md); a sphere's
        # surface likewise (generate.mesh_shape's ball: its volume 1.3 % short with flat facets)
        gmsh.model.mesh.setOrder(2)
    return tagged


#: the truth meshes' grading towards the singular edges, per family: (finest, over) -- the size
#: h / finest at the edges, growing to h over ``over`` h (:func:`generate.grade_towards`)
GRADING = {"default": (4.0, 4.0),
           # the L's first frequency stalled at h / 4 over 4 h (test draw 59653812's
           # r003-bracket: 10.4459, 10.4408, 10.4356 Hz at 1.96 h, 1.4 h, h; order ~0) and
           # converged at h / 10 over 6 h (10.4344, 10.4326, 10.4321: order 3.8; ~5x the tets)
           "bracket": (10.0, 6.0)}


#: families with curved faces (a hole, a fillet, a shell's arcs, a twisted bar's ruled faces):
#: their truths' cells curved. The bar's flat facets (before 2026-11-29, so in the test draw
#: 188067709) stalled its convergence: the faceted twisted faces held 1.4e-4, 1.1e-4 and
#: 0.09e-4 more volume than the solid at 1.96 h, 1.4 h and h (not a smooth h^2), and the
#: markers' differences stayed at ~3e-6 m (order 0.1); curved, order 1.8
#: (truth_convergence.py --seed 188067709 --case r001-bar --draw 2 --inside 0.7 --variant curved)
CURVED = ("plate", "shell", "fillet", "bar")


def truth_h(g: dict) -> float:
    """The truth's (P2) element size: a third of the thinnest section (three P2 cells across
    it), 4 to 11 mm. Seed 1's 0.6 x the section (7-11 mm) left its plates and shells one or two
    cells thick, and their runs at h, 1.4 h and 1.96 h did not converge monotonically (the
    count of cells across the thickness changed between them)."""
    return float(np.clip(g["section"] / 3, 0.004, 0.011))


def _nodes_tets(gmsh) -> tuple[np.ndarray, np.ndarray]:
    tags, coords, _ = gmsh.model.mesh.getNodes()
    order = np.argsort(tags)
    points = coords.reshape(-1, 3)[order]
    index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
    index[tags[order].astype(np.int64)] = np.arange(len(tags))
    etypes, _, enodes = gmsh.model.mesh.getElements(3)
    tets = index[enodes[list(etypes).index(4)].astype(np.int64)].reshape(-1, 4)
    return points, tets


def user_mesh(gmsh, family: str, g: dict, target: int, path: Path, lo: int, hi: int
              ) -> tuple[np.ndarray, np.ndarray, float]:
    """The user's P1 mesh with about ``target`` tets (within [lo, hi]; gmsh's count is not a
    formula of h, so h is corrected by (count / target)^(1/3) up to eight times; the mesh in
    range closest to the target is kept), written to
    ``path`` (MSH 4.1); returns its nodes, tets and h."""
    h = best = None

    def rank(n):
        return (not lo <= n <= hi, abs(n - target))
    for _ in range(8):
        if h is None:
            gmsh.model.add("probe")
            build(gmsh, family, g)
            vol = gmsh.model.occ.getMass(3, gmsh.model.getEntities(3)[0][1])
            gmsh.model.remove()
            # a regular tet of edge h has volume h^3 / (6 sqrt 2); gmsh's are ~ that
            h = (6 * math.sqrt(2) * vol / target) ** (1 / 3)
        mesh(gmsh, family, g, h)
        points, tets = _nodes_tets(gmsh)
        n = len(tets)
        # in range first, then the closest to the target (gmsh's count jumps where h crosses
        # a thickness's half: 446 -> 788 tets between h 17.1 and 15.9 mm on an L)
        if best is None or rank(n) < rank(len(best[1])):
            best = (points, tets, h)
            indep.write_msh(gmsh, path)
        gmsh.model.remove()
        if lo <= n <= hi and abs(n - target) <= 0.15 * target:
            break
        h *= (n / target) ** (1 / 3)
    points, tets, h = best
    if not lo <= len(tets) <= hi:
        raise RuntimeError(f"{family}: no user mesh within {lo}-{hi} tets "
                           f"(closest {len(tets)} at h {h:.4g})")
    return points, tets, h


def clamp_expression(g: dict) -> str:
    """petsoft's ``where`` of the clamp."""
    return f"{g['axis']} < 1e-9"


def clamp_mask(g: dict, x: np.ndarray) -> np.ndarray:
    """Numpy twin of :func:`clamp_expression` on points x (3, N)."""
    return x["xyz".index(g["axis"])] < 1e-9
