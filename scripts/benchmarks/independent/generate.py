"""Concealed-effect cases for ``petsoft diagnose`` made by an independent code (issue 14, part 3).

Run with the system python (DOLFINx 0.5 and gmsh are Debian packages there, not in the .venv)::

    nice /usr/bin/python3 scripts/benchmarks/independent/generate.py [--cases a,b] [--list]

or, for a random draw of cases (random_cases.py, issue 37)::

    nice /usr/bin/python3 scripts/benchmarks/independent/generate.py --random N --seed S \
        --out DIR [--size small|realistic]

For every case this writes, under ``cases/<name>/``:

* ``recording.h5``: marker trajectories in petsoft's recording format (formats.md section 2),
  simulated by DOLFINx -- not by petsoft -- on a gmsh mesh finer than the user's, with quadratic
  (P2) tetrahedra and a quarter of the user's step (Chung-Hulbert generalized-alpha, a Newton loop
  of our own with PETSc's LU), sampled at the markers by point evaluation on the fine mesh, then
  noise and dropped samples added the way ``petsoft synth`` adds them;
* ``user.toml``: the user's experiment, on the coarse P1 mesh *file* ``../../meshes/<shape>.msh``
  (written by gmsh), with the model the user believes: the truth minus the concealed effect(s),
  Young's modulus started 30 % low and calibrated;
* ``truth.json``: what was concealed and how the recording was made (no petsoft command reads it).

Every effect is written here as the physics says (weak forms below), in the same parameters as
petsoft's vocabulary (formats.md section 1) so a diagnosis can be compared with the truth:

* elastic: compressible neo-Hookean, psi = mu/2 (tr C - 3) - mu ln J + lam/2 (ln J)^2;
* ``damping.mass`` a: force -a rho v; ``damping.stiffness`` b: stress b C0 : eps(v) (C0 the
  reference elasticity tensor);
* ``boundary.compliance`` c: the clamp replaced by a Winkler foundation, traction -u / c on it;
* ``drag.linear`` c_l / ``drag.quadratic`` c_q: traction -c_l (v.n) n / -c_q |v.n| (v.n) n on
  the whole surface (reference normal);
* ``friction.dry`` mu_g, eps: body force -rho mu_g v / sqrt(|v|^2 + eps^2);
* ``material.viscoelastic`` g, tau: a standard linear solid, Maxwell stress g C0 : (eps(u) -
  eps_v), d eps_v/dt = (eps(u) - eps_v)/tau; eps_v is kept as eps(z) of a displacement-like field
  z with dz/dt = (u - z)/tau (exact: the strain is linear in u), stepped by the trapezoidal rule;
* ``material.heterogeneous`` / ``mass.added``: a sphere of stiffer / denser material (cells whose
  centroid is inside; or, with ``"conforming": true``, the ball as a part of the truth's
  geometry, meshed with curved second-order cells, so every mesh holds the same ball);
* ``gravity``: rho g (the user's model leaves it out);
* ``material.nonlinear``: the user's model is the linear law, the truth neo-Hookean at a large
  swing.

The cases, their shapes and parameters are the table CASES; README.md beside this file lists them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

# one BLAS thread: MUMPS's solves with the kept factor are most of a truth's time, and with
# OpenBLAS's default (a thread per core) they took twice as long beside another process
# (39 -> 76 ms a solve, 32,751 dofs); set before numpy and PETSc load OpenBLAS
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
CASES_DIR = HERE / "cases"
MESH_DIR = HERE / "meshes"

E_TRUE, NU, RHO = 2.0e7, 0.3, 1000.0
NOISE, DROPOUT, MARKERS = 1.0e-4, 0.1, 16
#: the user's step and span; the truth steps STEP / SUBSTEPS
STEP, END, SUBSTEPS, ALPHA_RADIUS = 0.002, 0.4, 4, 0.9
E_START = 0.7 * E_TRUE
GRAVITY = [0.0, 0.0, -9.81]

#: shape -> geometry, clamp (a petsoft `where` expression and its numpy twin), coarse and fine
#: characteristic lengths (m), initial velocity expressions (of x, y, z)
SHAPES = {
    "bracket": dict(clamp="z < 1e-9", h_coarse=0.02, h_fine=0.008,
                    velocity=["8*z*z", "4*z*z", "0"]),
    "finger": dict(clamp="x < 1e-9", h_coarse=0.02, h_fine=0.011,
                   velocity=["0", "3*x*x", "6*x*x"]),
    "plate": dict(clamp="x < 1e-9", h_coarse=0.02, h_fine=0.011,
                  velocity=["0", "0", "6*x*x"]),
}

STIFF = {"center": [0.04, 0.0, 0.0], "radius": 0.045}        # finger root
HEAVY = {"center": [0.14, 0.02, 0.18], "radius": 0.03}      # bracket arm's tip

#: name -> shape, concealed vocabulary terms, truth settings (petsoft keys), user edits
CASES: dict[str, dict] = {
    "control-bracket": dict(shape="bracket", physics=[], truth={}),
    "control-finger": dict(shape="finger", physics=[], truth={}),
    "control-plate": dict(shape="plate", physics=[], truth={}),
    "damping-mass": dict(shape="finger", physics=["damping.mass"],
                         truth={"damping": {"mass": 4.0}}),
    "damping-stiffness": dict(shape="bracket", physics=["damping.stiffness"],
                              truth={"damping": {"stiffness": 2e-4}}),
    "gravity": dict(shape="plate", physics=["gravity"], truth={},
                    user={"gravity": {"acceleration": [0.0, 0.0, 0.0]}}),
    "compliance": dict(shape="finger", physics=["boundary.compliance"],
                       truth={"compliance": 2e-9}),
    "drag-linear": dict(shape="plate", physics=["drag.linear"], truth={"drag": {"linear": 80.0}}),
    "drag-quadratic": dict(shape="plate", physics=["drag.quadratic"],
                           truth={"drag": {"quadratic": 300.0}}),
    "dry-friction": dict(shape="finger", physics=["friction.dry"],
                         truth={"friction": {"dry": 1.0, "speed": 0.003}}),
    "viscoelastic": dict(shape="bracket", physics=["material.viscoelastic"],
                         truth={"viscoelastic": {"ratio": 0.3, "relaxation_time": 0.015}}),
    "inclusion": dict(shape="finger", physics=["material.heterogeneous"],
                      truth={"sphere": {"where": STIFF, "youngs_modulus": 2 * E_TRUE}}),
    "added-mass": dict(shape="bracket", physics=["mass.added"],
                       truth={"sphere": {"where": HEAVY, "density": 4 * RHO}}),
    "nonlinear": dict(shape="finger", physics=["material.nonlinear"], truth={},
                      velocity=["0", "0", "60*x*x"], user={"material": {"model": "linear"}}),
    "damping+mass": dict(shape="bracket", physics=["damping.mass", "mass.added"],
                         truth={"damping": {"mass": 4.0},
                                "sphere": {"where": HEAVY, "density": 4 * RHO}}),
    "compliance+drag": dict(shape="plate", physics=["boundary.compliance", "drag.linear"],
                            truth={"compliance": 2e-9, "drag": {"linear": 80.0}}),
    # made and run once after the sixteen's table (88f63bb), nothing changed for them: effects
    # on shapes the suite had not paired them with
    "unseen-stiffdamp-plate": dict(shape="plate", physics=["damping.stiffness"],
                                   truth={"damping": {"stiffness": 5e-4}}),
    "unseen-drag-finger": dict(shape="finger", physics=["drag.linear"],
                               truth={"drag": {"linear": 80.0}}),
}


# ---------------------------------------------------------------------------------------------
# geometry (gmsh, OpenCASCADE kernel)

def region_tool(gmsh, reg: dict) -> tuple[int, int]:
    """A gmsh solid holding region ``reg``: its sphere, or its slab (|(x - center) . normal|
    < thickness / 2) as a box 2 m wide in its plane, turned from z to its normal."""
    occ = gmsh.model.occ
    c = np.asarray(reg["center"], dtype=float)
    if reg["kind"] == "sphere":
        return (3, occ.addSphere(*c, float(reg["radius"])))
    if reg["kind"] != "slab":
        raise ValueError(f"region kind {reg['kind']!r}")
    t = float(reg["thickness"])
    box = (3, occ.addBox(-1.0, -1.0, -t / 2, 2.0, 2.0, t))
    n = np.asarray(reg["normal"], dtype=float)
    n /= np.linalg.norm(n)
    axis = np.cross([0.0, 0.0, 1.0], n)
    if np.linalg.norm(axis) > 1e-12:   # (n = -z: the slab is symmetric about its plane)
        occ.rotate([box], 0.0, 0.0, 0.0, *axis, math.acos(float(np.clip(n[2], -1, 1))))
    occ.translate([box], *c)
    return box


def conform(gmsh, regions: list) -> dict[int, list[int]]:
    """Cut the current model's solid into parts that conform to ``regions`` (each region's part
    inside the solid, OCC intersect then fragment, so the truth's cells do not straddle a
    region's surface: assigned by their centroids, the material jump sat inside cells, and
    seed 5's bar with a stiff sphere converged at order 1.5, its truth discarded). The parts
    outside every region are the physical volume 1 ``body``; each part inside one is a
    physical volume of its own (tag 100 + its entity tag; a cell is in one group only, as
    DOLFINx's gmshio reads them). Returns region index -> the physical tags of its parts."""
    occ = gmsh.model.occ
    solid = gmsh.model.getEntities(3)
    pieces = []
    for i, reg in enumerate(regions):
        copy = occ.copy(solid)
        part, _ = occ.intersect(copy, [region_tool(gmsh, reg)], removeObject=True,
                                removeTool=True)
        if not part:
            raise RuntimeError(f"region {i} ({reg['kind']}) does not meet the solid")
        pieces.append(part)
    _, parts = occ.fragment(solid, [p for part in pieces for p in part])
    occ.synchronize()
    # parts[k] are the pieces made of input k: the solid's, then each region's in order
    sizes = [len(p) for p in pieces]
    inside: dict[int, set[int]] = {}
    k = len(solid)
    for i, n in enumerate(sizes):
        inside[i] = {t for piece in parts[k:k + n] for _, t in piece}
        k += n
    in_any = set().union(*inside.values())
    body = [t for _, t in gmsh.model.getEntities(3) if t not in in_any]
    if body:
        gmsh.model.addPhysicalGroup(3, body, 1)
        gmsh.model.setPhysicalName(3, 1, "body")
    for t in sorted(in_any):
        gmsh.model.addPhysicalGroup(3, [t], 100 + t)
    return {i: sorted(100 + t for t in tags) for i, tags in inside.items()}


def build_geometry(gmsh, shape: str, ball: dict | None = None) -> list[int]:
    """The solid of ``shape`` in the current gmsh model (metres), physical volume 1 ``body``.

    ``ball`` (``{"center": [x, y, z], "radius": r}``): the solid's part inside that ball is cut
    out as volumes of their own (:func:`conform`, so the mesh conforms to the ball's surface),
    whose physical groups it returns; volume 1 is then the rest. The committed truths with a
    conforming ball (../realistic: payload) were made before it shared :func:`conform` (its
    fragments then told apart by their centres of mass): remade now, the finger with the
    payload's ball meshes to 1,444 tets at h 11 mm instead of 1,448 (OCC's fragments cut in
    another order), its markers 4e-8 m apart after 10 ms."""
    occ = gmsh.model.occ
    if shape == "bracket":
        # an L: a post 0.04 x 0.04 x 0.2 clamped at z = 0 and an arm 0.16 long along x on top
        post = occ.addBox(0.0, 0.0, 0.0, 0.04, 0.04, 0.2)
        arm = occ.addBox(0.0, 0.0, 0.16, 0.17, 0.04, 0.04)
        occ.fuse([(3, post)], [(3, arm)])
    elif shape == "finger":
        # a tapered cantilever: 0.04 x 0.04 at the root (x = 0) to 0.02 x 0.016 at the tip (0.3)
        wires = []
        for x, hy, hz in ((0.0, 0.02, 0.02), (0.3, 0.01, 0.008)):
            p = [occ.addPoint(x, sy * hy, sz * hz) for sy, sz in
                 ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            lines = [occ.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]
            wires.append(occ.addWire(lines))
        occ.addThruSections(wires, makeSolid=True, makeRuled=True)
    elif shape == "plate":
        # a cantilever plate 0.25 x 0.08 x 0.02 with a hole of radius 0.02 through its thickness
        plate = occ.addBox(0.0, 0.0, 0.0, 0.25, 0.08, 0.02)
        hole = occ.addCylinder(0.13, 0.04, -0.01, 0.0, 0.0, 0.04, 0.02)
        occ.cut([(3, plate)], [(3, hole)])
    else:
        raise ValueError(shape)
    occ.synchronize()
    if ball:
        # the ball's part conforming, as the random cases' regions (its fragments found by
        # OCC's map of what was cut from what, not by their centres of mass)
        return conform(gmsh, [{"kind": "sphere", **ball}])[0]
    vols = [t for _, t in gmsh.model.getEntities(3)]
    gmsh.model.addPhysicalGroup(3, vols, 1)
    gmsh.model.setPhysicalName(3, 1, "body")
    return []


#: the bracket's re-entrant edge (the inner corner of the L, along y): the stress is singular
#: there, and uniform truth meshes converged very slowly at the markers (rms differences 0.32
#: and 0.22 x noise between h = 12, 8 and 6 mm), so the truth mesh is graded towards it
REENTRANT = {"bracket": ((0.04, 0.0, 0.16), (0.04, 0.04, 0.16))}


def grade_towards(gmsh, curves: list[int], h: float, field_only: bool = False,
                  finest: float = 4.0, over: float = 4.0, points: int = 50,
                  power: float | None = None, radius: float | None = None) -> None:
    """Element size h / ``finest`` (4) at ``curves`` (a re-entrant edge or the clamped face's
    edges, where the stress is singular), growing to h over ``over`` (4) h: a threshold on the
    distance to them (sampled at ``points`` a curve), as the background field.
    ``field_only``: the size comes from the field alone, not also extended from the sizes on
    the boundary's curves into the faces and the volume (gmsh's default, which the suite's
    bracket keeps: 4,483 instead of 3,487 tets on the finger graded at its clamp at h 11 mm,
    for no measured gain). gmsh's options are global: restore them with
    :func:`size_options` after meshing."""
    field = gmsh.model.mesh.field
    dist = field.add("Distance")
    field.setNumbers(dist, "CurvesList", curves)
    field.setNumber(dist, "NumPointsPerCurve", points)
    if power is not None:
        # a graded zone of fixed size ``radius`` (not shrinking with h): h (d / radius)^power,
        # floored at h / finest, so that refining h refines near the edge faster than h
        thr = field.add("MathEval")
        field.setString(thr, "F", f"{h}*Min(1, Max({1.0 / finest}, (F{dist}/{radius})^{power}))")
    else:
        thr = field.add("Threshold")
        field.setNumber(thr, "InField", dist)
        field.setNumber(thr, "SizeMin", h / finest)
        field.setNumber(thr, "SizeMax", h)
        field.setNumber(thr, "DistMin", h / finest)
        field.setNumber(thr, "DistMax", over * h)
    field.setAsBackgroundMesh(thr)
    if field_only:
        size_options(gmsh, 0)


#: gmsh's options deciding where element sizes come from besides the background field
SIZE_FROM = ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints",
             "Mesh.MeshSizeFromCurvature")


def size_options(gmsh, value: int | None = None) -> None:
    """Set :data:`SIZE_FROM` to ``value``, or (None) back to gmsh's defaults (1, 1, 0)."""
    for key, default in zip(SIZE_FROM, (1, 1, 0), strict=True):
        gmsh.option.setNumber(key, default if value is None else value)


def clamp_edges(gmsh, axis: int) -> list[int]:
    """The curves of the current model lying in the clamp's plane (coordinate ``axis`` = 0):
    the clamped face's edges, where it meets the free faces and the stress is singular (r^l, l
    ~ 0.7: P2 frequencies then converge at ~h^1.4, not h^4; README.md of ../realistic)."""
    eps = 1e-6
    lo, hi = np.full(3, -1e3), np.full(3, 1e3)
    lo[axis], hi[axis] = -eps, eps
    curves = [t for _, t in gmsh.model.getEntitiesInBoundingBox(*lo, *hi, dim=1)]
    if not curves:
        raise RuntimeError(f"no curve in the clamp's plane (axis {axis} = 0)")
    return curves


def generate_tets(gmsh) -> None:
    """Tetrahedra of the current model (Delaunay), optimised."""
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.optimize("")


def cached_run(path: Path, markers: np.ndarray, say) -> dict | None:
    """A truth run cached in ``path`` (npz: markers, displacements, found, meta) if it was made
    at ``markers``, else None."""
    if not path.exists():
        return None
    z = np.load(path, allow_pickle=True)
    if z["markers"].shape != markers.shape or not np.allclose(z["markers"], markers):
        return None
    say(f"  cached {path.name}")
    return json.loads(str(z["meta"])) | {"displacements": z["displacements"], "found": z["found"]}


def mesh_shape(gmsh, shape: str, h: float, graded: bool = False, ball: dict | None = None,
               clamp: bool = False) -> list[int]:
    """Mesh ``shape`` with element size ``h`` and return the ball's physical groups; ``graded``:
    down to h / 4 at a re-entrant edge (:data:`REENTRANT`), growing to h over 4 h (the truth's
    meshes only: the user's is uniform);
    ``clamp`` (with ``graded``): at the clamped face's edges too (:func:`clamp_edges`; the
    sizes from the field only), which the suite's committed truths were made without.
    ``ball``: a conforming ball part (:func:`build_geometry`), meshed with second-order (curved)
    cells: with flat facets the finger's ball part (28.53 cm^3) was 1.3 % too small at h = 11 mm
    and 0.66 % at 8 mm, a mass error of second order in h; curved, 2e-5 and 2e-6."""
    gmsh.model.add(f"{shape}-{h}")
    ball_groups = build_geometry(gmsh, shape, ball)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMin", h / 4 if graded else h)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
    curves = []
    if graded and shape in REENTRANT:
        (x0, y0, z0), (x1, y1, z1) = REENTRANT[shape]
        eps = 1e-6
        edges = gmsh.model.getEntitiesInBoundingBox(x0 - eps, y0 - eps, z0 - eps, x1 + eps,
                                                    y1 + eps, z1 + eps, dim=1)
        if not edges:
            raise RuntimeError(f"{shape}: no edge found at the re-entrant corner")
        curves = [e[1] for e in edges]
    if graded and clamp:
        curves += clamp_edges(gmsh, 2 if shape == "bracket" else 0)
    if curves:
        grade_towards(gmsh, curves, h, field_only=clamp)
    try:
        generate_tets(gmsh)
    finally:
        size_options(gmsh)
    if ball:
        gmsh.model.mesh.setOrder(2)     # the edges' midpoints placed on the ball's surface
    return ball_groups


def write_msh(gmsh, path: Path) -> None:
    """The current model's mesh to ``path`` (gmsh 4.1), atomically: two generate.py processes
    given cases of one shape write the same file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    tmp = path.parent / f".{path.stem}.{os.getpid()}.msh"
    gmsh.write(str(tmp))
    os.replace(tmp, path)


def coarse_mesh(gmsh, shape: str, h: float | None = None, path: Path | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Write the user's P1 mesh (default ``meshes/<shape>.msh`` at the shape's coarse size);
    return its nodes (N, 3) and tets."""
    mesh_shape(gmsh, shape, h or SHAPES[shape]["h_coarse"])
    write_msh(gmsh, Path(path) if path else MESH_DIR / f"{shape}.msh")
    return model_tets(gmsh)


def model_tets(gmsh) -> tuple[np.ndarray, np.ndarray]:
    """The current gmsh model's nodes (N, 3) and 4-node tets (indices into them); the model
    is removed."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    order = np.argsort(tags)
    points = coords.reshape(-1, 3)[order]
    index = {int(t): i for i, t in enumerate(tags[order])}
    etypes, _, enodes = gmsh.model.mesh.getElements(3)
    tets = np.array([index[int(t)] for t in enodes[list(etypes).index(4)]]).reshape(-1, 4)
    gmsh.model.remove()
    return points, tets


def save_run(path: Path, markers: np.ndarray, res: dict) -> None:
    """Cache a truth run (:func:`simulate_truth`'s result) for :func:`cached_run`."""
    meta = {k: v for k, v in res.items() if k not in ("displacements", "found")}
    np.savez(path, markers=markers, displacements=res["displacements"], found=res["found"],
             meta=json.dumps(meta))


def surface_nodes(tets: np.ndarray) -> np.ndarray:
    faces = np.sort(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    return np.unique(uniq[count == 1])


def clamp_mask(shape: str, x: np.ndarray) -> np.ndarray:
    """Numpy twin of SHAPES[shape]['clamp'] on points x (3, N)."""
    return x[2] < 1e-9 if shape == "bracket" else x[0] < 1e-9


def velocity_fn(exprs):
    def f(x):
        env = {"x": x[0], "y": x[1], "z": x[2]}
        return np.stack([np.broadcast_to(eval(e, {}, env), x[0].shape).astype(float)  # noqa: S307
                         for e in exprs])
    return f


# ---------------------------------------------------------------------------------------------
# the truth: DOLFINx

def newton_done(size: float, last: float, tol: float, estimate: bool) -> bool:
    """Whether Newton stops after an increment of ``size`` (m, infinity norm) that followed one
    of ``last`` (inf: the first): when it is below ``tol``, or stalled at the round-off floor
    below 1e-7 m (the graded bracket's 2 mm cells with stiffness damping: ~1e-9 m), or, with
    ``estimate``, when the error it leaves is below ``tol``: the iterations on a kept factor
    contract linearly (rho = size / last), leaving about size rho / (1 - rho); stopping then
    saves the iteration that would only confirm it."""
    if size < tol or (size < 1e-7 and size > 0.5 * last):
        return True
    if not estimate or not np.isfinite(last) or last <= 0.0:
        return False
    rho = size / last
    return rho < 0.5 and size * rho / (1.0 - rho) < tol


def simulate_truth(gmsh, name: str, case: dict, markers: np.ndarray, say, *,
                   h_fine: float | None = None, substeps: int = SUBSTEPS,
                   end: float = END, newton_tol: float = 1e-10, body: dict | None = None,
                   degree: int = 2, grade_clamp: bool = False,
                   newton_estimate: bool = False) -> dict:
    """Simulate the truth of ``case`` and return marker displacements at the user's frames
    (``h_fine``, ``substeps``, ``end``: the fine mesh size, steps per frame and the span,
    default the suite's; ``newton_tol``: the largest accepted last Newton increment, m, or
    with ``newton_estimate`` the error estimated to remain after it, from the iterations'
    contraction: one iteration fewer a step).

    ``body`` (the random cases, random_cases.py; default: the suite's shape ``case["shape"]``
    and constants): ``mesh(gmsh, h)`` meshes the solid in a new gmsh model, ``h_fine`` its
    default size, ``clamp(x)`` the clamped points of x (3, N), ``velocity`` / ``displacement``
    the initial fields (expressions of x, y, z; displacement optional), ``material``
    (``youngs_modulus``, ``poisson_ratio``, ``density``, ``law`` neohookean | linear) and
    ``gravity``, optionally ``base`` (the clamp moved by ``amplitude`` sin(``omega`` t)^3 along
    ``direction``). ``case["truth"]`` may also hold ``regions`` (a list of spheres ``center``,
    ``radius`` or slabs ``center``, ``normal``, ``thickness`` with their own ``youngs_modulus``
    and/or ``density``) and ``viscoelastic2``, a second standard-linear-solid branch.
    ``degree``: the elements' (2, the suite's; quadrature degree 2 x degree). ``grade_clamp``:
    the suite's shape meshed graded towards the clamped face's edges too (:func:`mesh_shape`)."""
    # imported here: DOLFINx is in the system python only, and --list works without it
    import ufl
    from dolfinx import fem, geometry
    from dolfinx import mesh as dmesh
    from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, set_bc
    from dolfinx.io import gmshio
    from mpi4py import MPI
    from petsc4py import PETSc

    shape = case["shape"]
    truth = case["truth"]
    sphere = truth.get("sphere")
    ball = sphere["where"] if sphere and sphere.get("conforming") else None
    tagged: dict = {}
    if body is None:
        sh = SHAPES[shape]
        ball_groups = mesh_shape(gmsh, shape, h_fine or sh["h_fine"], graded=True, ball=ball,
                                 clamp=grade_clamp)
        velocity = case.get("velocity", sh["velocity"])
        E0, nu, rho0, gravity, law = E_TRUE, NU, RHO, GRAVITY, "neohookean"

        def clamp(x):
            return clamp_mask(shape, x)
    else:
        if ball:
            raise ValueError(f"{name}: a conforming ball needs the suite's shapes, not a body")
        # a mesh conforming to the regions says which physical groups hold each one
        tagged = body["mesh"](gmsh, h_fine or body["h_fine"]) or {}
        velocity, clamp = body["velocity"], body["clamp"]
        mat = body["material"]
        E0, nu, rho0 = mat["youngs_modulus"], mat["poisson_ratio"], mat["density"]
        gravity, law = body["gravity"], mat.get("law", "neohookean")
    msh, cell_tags, _ = gmshio.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3)
    gmsh.model.remove()
    ncells = msh.topology.index_map(3).size_local
    V = fem.VectorFunctionSpace(msh, ("CG", degree))
    Q = fem.FunctionSpace(msh, ("DG", 0))
    Ef, rhof = fem.Function(Q), fem.Function(Q)
    Ef.x.array[:] = E0
    rhof.x.array[:] = rho0
    # regions (random cases): a cell belongs when it is in the region's conforming parts
    # (random_shapes.conform), else when its centroid (DG0's dof) is inside
    centroids = Q.tabulate_dof_coordinates()
    def in_groups(tags) -> np.ndarray:
        inside = np.zeros(len(centroids), dtype=bool)
        for tag in tags:
            inside[fem.locate_dofs_topological(Q, 3, cell_tags.find(tag))] = True
        return inside

    for i, reg in enumerate(truth.get("regions", [])):
        rel = centroids - np.asarray(reg["center"]) if i not in tagged else None
        if i in tagged:
            inside = in_groups(tagged[i])
        elif reg["kind"] == "sphere":
            inside = np.sum(rel ** 2, axis=1) < reg["radius"] ** 2
        elif reg["kind"] == "slab":
            inside = np.abs(rel @ np.asarray(reg["normal"])) < reg["thickness"] / 2
        else:
            raise ValueError(f"{name}: region kind {reg['kind']!r}")
        if not inside.any():
            raise RuntimeError(f"{name}: region {reg} holds no cell of the truth's mesh")
        for key, fld in (("youngs_modulus", Ef), ("density", rhof)):
            if key in reg:
                fld.x.array[inside] = reg[key]
    if ball:
        # the ball's cells (its conforming parts' groups): the same ball on every mesh
        inball = np.flatnonzero(in_groups(ball_groups))
        if not len(inball):
            raise RuntimeError(f"{name}: no cell of the truth mesh in the ball {ball}")
        if "youngs_modulus" in sphere:
            Ef.x.array[inball] = sphere["youngs_modulus"]
        if "density" in sphere:
            rhof.x.array[inball] = sphere["density"]
    elif sphere:
        c, r = np.array(sphere["where"]["center"]), sphere["where"]["radius"]

        def inside(x):
            return np.sum((x.T - c) ** 2, axis=1) < r * r

        if "youngs_modulus" in sphere:
            Ef.interpolate(lambda x: np.where(inside(x), sphere["youngs_modulus"], E0))
        if "density" in sphere:
            rhof.interpolate(lambda x: np.where(inside(x), sphere["density"], rho0))
    mu = Ef / (2 * (1 + nu))
    lam = Ef * nu / ((1 + nu) * (1 - 2 * nu))

    # clamp facets (Dirichlet, or the Winkler foundation of a compliant support)
    fdim = 2
    facets = dmesh.locate_entities_boundary(msh, fdim, clamp)
    tags = dmesh.meshtags(msh, fdim, np.sort(facets), np.full(len(facets), 1, dtype=np.int32))
    # degree 4: exact for the mass and the linear terms of P2, and the usual choice for the
    # neo-Hookean stress (UFL's estimate for ln J is a far higher degree, ~50x slower)
    md = {"quadrature_degree": 2 * degree}
    dx = ufl.Measure("dx", domain=msh, metadata=md)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=tags, metadata=md)
    compliance = truth.get("compliance")
    bcs = []
    if not compliance:
        dofs = fem.locate_dofs_topological(V, fdim, facets)
        bcs = [fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs, V)]
    base = body.get("base") if body is not None else None
    if base:
        # a base motion (random cases): the clamp translates by amplitude sin(omega t)^3
        # along direction, zero with its first two derivatives at t = 0 (so the initial rest
        # and the consistent initial acceleration hold there too)
        if compliance:
            raise ValueError(f"{name}: a base motion needs the rigid clamp")
        ubc = fem.Function(V)
        bcs = [fem.dirichletbc(ubc, dofs)]
        shift = np.asarray(base["direction"], dtype=float) * base["amplitude"]

        def move(t):
            ubc.x.array[:] = np.tile(shift * np.sin(base["omega"] * t) ** 3,
                                     len(ubc.x.array) // 3)

    # the truth always has gravity (the "gravity" case leaves it out of the user's model)
    g = fem.Constant(msh, PETSc.ScalarType(gravity))
    damping = truth.get("damping", {})
    drag = truth.get("drag", {})
    fric = truth.get("friction", {})
    visco = truth.get("viscoelastic", {})
    # standard-linear-solid branches (g, tau): the vocabulary's one, a second (random cases)
    branches = [(b["ratio"], b["relaxation_time"]) for b in
                (visco, truth.get("viscoelastic2", {})) if b.get("ratio")]
    n = ufl.FacetNormal(msh)
    I3 = ufl.Identity(3)

    def eps(w):
        return ufl.sym(ufl.grad(w))

    def sigma0(w):          # reference (linear) elasticity, the same E field
        return 2 * mu * eps(w) + lam * ufl.tr(eps(w)) * I3

    def piola(w):           # neo-Hookean first Piola-Kirchhoff stress
        F = ufl.variable(I3 + ufl.grad(w))
        J = ufl.det(F)
        psi = mu / 2 * (ufl.tr(F.T * F) - 3) - mu * ufl.ln(J) + lam / 2 * ufl.ln(J) ** 2
        return ufl.diff(psi, F)

    def forces(uu, vv, ww, zzs, test):
        """Every force but inertia, as the residual's weak form (internal minus external)."""
        # the linear law (the random cases' effect-free run of material.nonlinear): small strain
        stress = sigma0(uu) if law == "linear" else piola(uu)
        f = ufl.inner(stress, ufl.grad(test)) * dx - rhof * ufl.dot(g, test) * dx
        if damping.get("mass"):
            f += damping["mass"] * rhof * ufl.dot(vv, test) * dx
        if damping.get("stiffness"):
            f += damping["stiffness"] * ufl.inner(sigma0(vv), eps(test)) * dx
        if compliance:
            f += (1.0 / compliance) * ufl.dot(uu, test) * ds(1)
        if drag.get("linear"):
            f += drag["linear"] * ufl.dot(vv, n) * ufl.dot(test, n) * ds
        if drag.get("quadratic"):
            vn = ufl.dot(vv, n)
            f += drag["quadratic"] * abs(vn) * vn * ufl.dot(test, n) * ds
        if fric.get("dry"):
            f += (fric["dry"] * rhof / ufl.sqrt(ufl.dot(vv, vv) + fric["speed"] ** 2)
                  * ufl.dot(vv, test) * dx)
        for (ratio, _), zz in zip(branches, zzs, strict=True):
            f += ratio * ufl.inner(sigma0(ww - zz), eps(test)) * dx
        return f

    # Chung-Hulbert generalized-alpha
    rinf = ALPHA_RADIUS
    am, af = (2 * rinf - 1) / (rinf + 1), rinf / (rinf + 1)
    gamma, beta = 0.5 - am + af, 0.25 * (1 - am + af) ** 2
    h = STEP / substeps
    u, u0, v0, a0 = (fem.Function(V) for _ in range(4))
    z0s = [fem.Function(V) for _ in branches]
    v0.interpolate(velocity_fn(velocity))
    if body is not None and body.get("displacement"):
        # a release from a deflected shape; the branches start relaxed there (petsoft's
        # viscoelastic.py: z(0) = q(0), the body has rested at q(0) for long)
        u0.interpolate(velocity_fn(body["displacement"]))
        for z0 in z0s:
            z0.x.array[:] = u0.x.array
    w = ufl.TestFunction(V)
    du = ufl.TrialFunction(V)

    # consistent initial acceleration: M a0 = -forces(u0, v0)
    a_form = fem.form(rhof * ufl.dot(du, w) * dx)
    L_form = fem.form(-forces(u0, v0, u0, z0s, w))
    A0 = assemble_matrix(a_form, bcs=bcs)
    A0.assemble()
    b0 = assemble_vector(L_form)
    apply_lifting(b0, [a_form], bcs=[bcs])
    b0.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    set_bc(b0, bcs)
    ksp0 = _lu(A0)
    ksp0.solve(b0, a0.vector)
    a0.x.scatter_forward()

    a1 = (u - u0 - h * v0) / (beta * h * h) - (1 - 2 * beta) / (2 * beta) * a0
    v1 = v0 + h * ((1 - gamma) * a0 + gamma * a1)
    rs = [h / tau for _, tau in branches]
    z1s = [((1 - r / 2) * z0 + (r / 2) * (u0 + u)) / (1 + r / 2)
           for r, z0 in zip(rs, z0s, strict=True)]
    am_ = (1 - am) * a1 + am * a0
    uf, vf = ((1 - af) * x1 + af * x0 for x1, x0 in ((u, u0), (v1, v0)))
    zfs = [(1 - af) * z1 + af * z0 for z1, z0 in zip(z1s, z0s, strict=True)]
    R = rhof * ufl.dot(am_, w) * dx + forces(uf, vf, uf, zfs, w)
    R_form = fem.form(R)
    J_form = fem.form(ufl.derivative(R, u, du))

    # markers: cells of the fine mesh holding them
    tree = geometry.BoundingBoxTree(msh, 3)
    coll = geometry.compute_colliding_cells(
        msh, geometry.compute_collisions(tree, markers), markers)
    cells = np.array([_evaluable_cell(u, markers[i], coll.links(i))
                      for i in range(len(markers))])
    found = cells >= 0

    A = assemble_matrix(J_form, bcs=bcs)
    A.assemble()
    ksp = _lu(A)
    b = A.createVecRight()
    dx_ = A.createVecRight()
    nsteps = int(round(end / h))
    frames = [np.zeros((len(markers), 3))]
    newton_total, refactors = 0, 0
    t0 = time.perf_counter()
    u.x.array[:] = u0.x.array
    for step in range(1, nsteps + 1):
        if base:
            move(step * h)
        # predictor: constant velocity (with the acceleration term, the graded bracket's 2 mm
        # cells under stiffness damping got a0 ~ 1e4 m/s^2 from the initial velocity field
        # and the predictor inverted them: NaN); only Newton's start, not the solution
        u.x.array[:] = u0.x.array + h * v0.x.array
        last, halvings = np.inf, 0
        # whether u holds the Dirichlet values: then the lifting J (g - u) is zero and is not
        # assembled (it cost about a quarter of an iteration: the tangent on every cell at the
        # graded clamp). A Newton update puts u on them (the rows of the b.c. give dx = u - g)
        on_bc = False
        for it in range(40):
            with b.localForm() as bl:
                bl.set(0.0)
            assemble_vector(b, R_form)
            if not on_bc:
                apply_lifting(b, [J_form], bcs=[bcs], x0=[u.vector], scale=-1.0)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            set_bc(b, bcs, u.vector, -1.0)
            if not np.isfinite(b.norm()):
                # an inverted cell (ln J < 0): a random case's release threw the graded L's
                # small corner cells over in the predictor at 1 ms steps. Restart from the
                # last state, or go back half the last increment (never met by the suite's
                # cases, whose results this leaves unchanged)
                halvings += 1
                if halvings > 8:
                    raise RuntimeError(f"{name}: inverted cells at step {step}")
                if it == 0:
                    u.x.array[:] = u0.x.array
                else:
                    dx_.scale(0.5)
                    u.x.array[:] += dx_.array
                on_bc = False
                continue
            if it in (6, 15, 30):
                # slow: a fresh tangent (modified Newton keeps the factor while it contracts)
                A.zeroEntries()
                assemble_matrix(A, J_form, bcs=bcs)
                A.assemble()
                ksp.setOperators(A)
                refactors += 1
            ksp.solve(b, dx_)
            u.x.array[:] -= dx_.array
            on_bc = True
            newton_total += 1
            size = dx_.norm(PETSc.NormType.INFINITY)     # m; the noise is 2e-5 - 5e-4 m
            if newton_done(size, last, newton_tol, newton_estimate):
                break
            last = size
        else:
            raise RuntimeError(f"{name}: Newton did not converge at step {step}")
        # accept: a, v, z of the new step
        a_new = ((u.x.array - u0.x.array - h * v0.x.array) / (beta * h * h)
                 - (1 - 2 * beta) / (2 * beta) * a0.x.array)
        v0.x.array[:] = v0.x.array + h * ((1 - gamma) * a0.x.array + gamma * a_new)
        for r, z0 in zip(rs, z0s, strict=True):
            z0.x.array[:] = ((1 - r / 2) * z0.x.array
                             + (r / 2) * (u0.x.array + u.x.array)) / (1 + r / 2)
        a0.x.array[:] = a_new
        u0.x.array[:] = u.x.array
        if step % substeps == 0:
            disp = np.zeros((len(markers), 3))
            disp[found] = u.eval(markers[found], cells[found])
            frames.append(disp)
        if step % (nsteps // 4) == 0 or step == 10:
            say(f"  t = {step * h:.3f} s, {newton_total / step:.1f} iterations a step, "
                f"{time.perf_counter() - t0:.0f} s")
    # refresh the tangent every step was not needed: the factor is kept across steps and
    # refreshed on slow contraction (a few refactorisations over the run)
    return {"displacements": np.array(frames), "found": found, "fine_tets": int(ncells),
            "dofs": int(V.dofmap.index_map.size_global * 3), "newton": newton_total,
            "refactors": refactors, "steps": nsteps, "step": h,
            "seconds": time.perf_counter() - t0}


def _evaluable_cell(u, point: np.ndarray, candidates) -> int:
    """The first of a marker's colliding ``candidates`` cells where ``u`` can be evaluated at
    ``point``, -1 if none. On curved (second-order) cells DOLFINx pulls the point back by
    Newton's method, which fails in a candidate whose curved shape leaves the point just
    outside (seen: the test draw 604960342's r003-plate, "Newton method failed to converge
    for non-affine geometry"); the first candidate was taken before, whatever it was."""
    for cell in candidates:
        try:
            u.eval(point.reshape(1, 3), np.array([cell], dtype=np.int32))
        except RuntimeError:
            continue
        return int(cell)
    return -1


def _lu(A):
    from petsc4py import PETSc

    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    return ksp


# ---------------------------------------------------------------------------------------------
# the user's experiment

def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(type(v))


def dumps_toml(data: dict) -> str:
    """A minimal TOML writer: top-level tables (one level of sub-tables) and arrays of tables."""
    lines = []
    for key, value in data.items():
        if isinstance(value, dict):
            lines.append(f"[{key}]")
            subs = {k: v for k, v in value.items() if isinstance(v, dict)}
            for k, v in value.items():
                if not isinstance(v, dict):
                    lines.append(f"{json.dumps(k) if '.' in k else k} = {_toml_value(v)}")
            for k, v in subs.items():
                lines.append(f"\n[{key}.{k}]")
                lines.extend(f"{kk} = {_toml_value(vv)}" for kk, vv in v.items())
            lines.append("")
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            for item in value:
                lines.append(f"[[{key}]]")
                lines.extend(f"{k} = {_toml_value(v)}" for k, v in item.items())
                lines.append("")
    return "\n".join(lines) + "\n"


def user_experiment(name: str, case: dict, *, end: float = END,
                    mesh_file: str | None = None) -> dict:
    """The user's model: the truth without the concealed terms, E started 30 % low (``end``:
    the recording's span; ``mesh_file``: default ``../../meshes/<shape>.msh``)."""
    sh = SHAPES[case["shape"]]
    user = case.get("user", {})
    material = {"model": "neohookean", "youngs_modulus": E_START, "poisson_ratio": NU,
                "density": RHO}
    material.update(user.get("material", {}))
    return {
        "mesh": {"file": mesh_file or f"../../meshes/{case['shape']}.msh"},
        "material": material,
        "gravity": {"acceleration": user.get("gravity", {}).get("acceleration", GRAVITY)},
        "initial": {"velocity": case.get("velocity", sh["velocity"])},
        "boundary": [{"kind": "fixed", "where": sh["clamp"]}],
        "time": {"end": end, "step": STEP, "integrator": "alpha", "alpha_radius": ALPHA_RADIUS},
        "output": {"directory": "out"},
        "calibrate": {"material.youngs_modulus": [2.0e6, 2.0e8]},
    }


def write_recording(path: Path, reference, times, positions, names, noise: float, source: str):
    """petsoft's recording layout (formats.md section 2), written with h5py."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["format"] = "petsoft-recording"
        f.attrs["version"] = 1
        f.attrs["source"] = source
        f["markers/reference"] = np.asarray(reference, dtype=np.float64)
        f.create_dataset("markers/name", data=np.array(names, dtype=object),
                         dtype=h5py.string_dtype("utf-8"))
        f["frames/time"] = np.asarray(times, dtype=np.float64)
        f["frames/position"] = np.asarray(positions, dtype=np.float64)
        f.create_group("noise").attrs["position_std"] = float(noise)


def pick_markers(shape: str, points: np.ndarray, tets: np.ndarray, seed: int,
                 count: int) -> np.ndarray:
    """Candidate markers (3 ``count`` of them, (K, 3)): coarse-mesh surface nodes off the clamp
    (so they are inside the user's mesh), chosen like `petsoft synth` does; the caller keeps the
    first ``count`` the fine mesh holds (a curved face's chord can leave a node outside)."""
    cand = surface_nodes(tets)
    cand = cand[~clamp_mask(shape, points[cand].T)]
    rng_pick = np.random.default_rng([seed, 1])
    return points[np.sort(rng_pick.choice(cand, size=min(3 * count, len(cand)), replace=False))]


def write_case(d: Path, name: str, case: dict, markers: np.ndarray, displacements: np.ndarray,
               seed: int, user: dict, source: str, truth_extra: dict) -> dict:
    """Add noise and dropouts to the clean marker ``displacements`` (frames, K, 3) at the user's
    step as `petsoft synth` does, and write ``recording.h5``, ``user.toml`` (the dict ``user``)
    and ``truth.json`` (the case's truth plus ``truth_extra``) under ``d``; return the truth."""
    clean = markers[None] + displacements
    times = np.arange(len(clean)) * STEP
    rng = np.random.default_rng([seed, 2])
    noisy = clean + rng.normal(0.0, NOISE, clean.shape)
    dropped = rng.random(clean.shape[:2]) < DROPOUT
    noisy[dropped] = np.nan
    d.mkdir(parents=True, exist_ok=True)
    names = [f"m{i:02d}" for i in range(len(markers))]
    write_recording(d / "recording.h5", markers, times, noisy, names, NOISE, source)
    (d / "user.toml").write_text(
        f"# {name}: the user's experiment (generate.py); the recording was made by DOLFINx\n"
        + dumps_toml(user))
    truth = {
        "case": name, "shape": case["shape"], "concealed": case["physics"],
        "truth": {"youngs_modulus": E_TRUE, "poisson_ratio": NU, "density": RHO,
                  "material": "neohookean", **case["truth"],
                  "gravity": GRAVITY},
        "simulator": "DOLFINx 0.5, P2 tetrahedra, Chung-Hulbert generalized-alpha "
                     f"(rho_inf {ALPHA_RADIUS}), Newton with MUMPS LU",
        **truth_extra,
        "user_step": STEP,
        "noise": {"position_std": NOISE, "dropout": DROPOUT, "dropped_samples":
                  int(dropped.sum())},
        "seed": seed, "markers": len(markers), "frames": len(times),
        "max_marker_displacement": float(np.abs(displacements).max()),
    }
    (d / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return truth


def make_case(gmsh, name: str, meshes: dict, say) -> dict:
    case = CASES[name]
    shape = case["shape"]
    points, tets = meshes[shape]
    seed = 101 + sorted(CASES).index(name)
    markers = pick_markers(shape, points, tets, seed, MARKERS)
    res = simulate_truth(gmsh, name, case, markers, say)
    keep = np.flatnonzero(res["found"])[:MARKERS]
    extra = {"fine_tets": res["fine_tets"], "fine_dofs": res["dofs"],
             "coarse_tets": int(len(tets)), "step": res["step"], "steps": res["steps"],
             "newton_iterations": res["newton"], "refactorizations": res["refactors"],
             "seconds": res["seconds"]}
    return write_case(CASES_DIR / name, name, case, markers[keep], res["displacements"][:, keep],
                      seed, user_experiment(name, case),
                      f"scripts/benchmarks/independent/generate.py {name} (DOLFINx P2)", extra)


def convergence(gmsh, name: str, meshes: dict) -> None:
    """The truth's own discretisation error at the markers, from the coarse side (cheap on a
    busy machine): the suite's truth against one with the step doubled (still half the user's)
    and one on a 1.4x coarser P2 mesh. Differences well below the noise bound the suite's own
    error (smaller still, the scheme being second order in time and P2 third order in space)."""
    case = CASES[name]
    points, tets = meshes[case["shape"]]
    cand = surface_nodes(tets)
    markers = points[cand[~clamp_mask(case["shape"], points[cand].T)]]

    def say(line):
        print(line, flush=True)

    h = SHAPES[case["shape"]]["h_fine"]
    runs = {"suite": simulate_truth(gmsh, name, case, markers, say),
            "step x2": simulate_truth(gmsh, name, case, markers, say, substeps=SUBSTEPS // 2),
            "mesh x1.4": simulate_truth(gmsh, name, case, markers, say, h_fine=h * 1.4)}
    found = np.logical_and.reduce([r["found"] for r in runs.values()])
    ref = runs["suite"]["displacements"][:, found]
    print(f"{name}: truth's discretisation error at {found.sum()} surface nodes, "
          f"{len(ref)} frames (noise {NOISE:g} m, max displacement {np.abs(ref).max():.3g} m)")
    for label in ("step x2", "mesh x1.4"):
        d = runs[label]["displacements"][:, found] - ref
        print(f"  suite ({runs['suite']['fine_tets']} P2 tets, step {runs['suite']['step']:g} s)"
              f" vs {label} ({runs[label]['fine_tets']} P2 tets, step {runs[label]['step']:g} s):"
              f" max |diff| {np.abs(d).max():.3g} m = {np.abs(d).max() / NOISE:.3f} x noise, "
              f"rms {np.sqrt(np.mean(d ** 2)):.3g} m = {np.sqrt(np.mean(d ** 2)) / NOISE:.3f} x "
              "noise", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--convergence", metavar="CASE",
                    help="write nothing: the truth of CASE against the step doubled and a "
                         "coarser mesh (its discretisation error over the noise)")
    ap.add_argument("--random", type=int, metavar="N",
                    help="draw N random cases instead (random_cases.py; with --seed, --out)")
    ap.add_argument("--seed", type=int, help="the random draw's seed")
    ap.add_argument("--out", type=Path, help="the random draw's folder")
    ap.add_argument("--size", choices=("small", "realistic"), default="small",
                    help="the random cases' user meshes and record lengths (default small)")
    ap.add_argument("--only", help="random: only these case indices (comma-separated)")
    ap.add_argument("--refine", type=int, default=1,
                    help="random: refine a truth failing its error check up to this many "
                         "times before discarding the case (default 1)")
    ap.add_argument("--draw-only", action="store_true",
                    help="random: write draw.json (the drawn parameters), simulate nothing")
    args = ap.parse_args()
    if args.random is not None:
        if args.seed is None or args.out is None:
            ap.error("--random needs --seed and --out")
        import random_cases

        only = [int(i) for i in args.only.split(",")] if args.only else None
        return random_cases.main(args.random, args.seed, args.out, args.size, only,
                                 args.draw_only, args.refine)
    if args.list:
        for k, c in CASES.items():
            print(f"{k:<20} {c['shape']:<8} {'+'.join(c['physics']) or '-'}")
        return 0
    names = [args.convergence] if args.convergence else args.cases.split(",")
    bad = [n for n in names if n not in CASES]
    if bad:
        print(f"unknown case(s) {bad}; valid: {', '.join(CASES)}")
        return 2
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    meshes = {}
    for shape in sorted({CASES[n]["shape"] for n in names}):
        meshes[shape] = coarse_mesh(gmsh, shape)
        print(f"{shape}: coarse mesh {len(meshes[shape][1])} tets -> meshes/{shape}.msh",
              flush=True)
    if args.convergence:
        convergence(gmsh, args.convergence, meshes)
        gmsh.finalize()
        return 0
    for name in names:
        t0 = time.perf_counter()
        print(f"case {name} ({CASES[name]['shape']}, concealed "
              f"{'+'.join(CASES[name]['physics']) or 'nothing'})", flush=True)
        tr = make_case(gmsh, name, meshes, lambda s: print(s, flush=True))
        print(f"  {tr['fine_tets']} P2 tets ({tr['fine_dofs']} dofs) vs {tr['coarse_tets']} "
              f"user tets; step {tr['step']:g} s vs {STEP:g}; {tr['markers']} markers, "
              f"{tr['frames']} frames, max displacement {tr['max_marker_displacement']:.3g} m; "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
    gmsh.finalize()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
