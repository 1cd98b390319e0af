"""Is the clamp's edge singularity what limits the realistic truths' order in space? (README.md)

Run with the system python (DOLFINx 0.5, gmsh, SLEPc), one process, ``nice -n 10``::

    /usr/bin/python3 scripts/benchmarks/realistic/clamp_grading.py modes [--mesh V] [--h ...]
    /usr/bin/python3 scripts/benchmarks/realistic/clamp_grading.py run V H [--end 0.15]
    /usr/bin/python3 scripts/benchmarks/realistic/clamp_grading.py order V H1 H2 H3 [--end 0.15]

Two measurements on the realistic cases' body (the tapered cantilever "finger", clamped at x = 0)
and three families of P2 truth meshes (:data:`VARIANTS`): uniform, graded towards the clamped
face's four edges with the grading scaled with h (``../independent/generate.py``'s
``grade_towards``: h / 4 at the edges, h at 4 h from them), and graded with a fixed smallest size
at the edges (:data:`H_EDGE`), so that the ratio of the bulk size to the edge size grows as h
falls.

* ``modes``: the lowest natural frequencies of the linear-elastic body (E, nu, rho of the truth;
  SLEPc shift-invert, MUMPS) on each mesh, and the order of their convergence from three meshes,
  (f1 - f2) / (f2 - f3) = r^p. A linear problem with a smooth solution converges at h^4 in the
  frequencies for P2; the edge singularity r^lambda lowers that to ~h^(2 lambda).
  A phase error at the markers is the frequency error times t, so the markers' order is the
  frequencies'.
* ``run`` / ``order``: the control case's truth (neo-Hookean, gravity, initial velocity, 0.5 ms
  steps) over a short record on one mesh, sampled at the control case's 24 markers (the user's
  mesh file and the generator's seed), cached in ``out/clamp_grading/``; ``order``: from three
  cached runs of one family, D1 = |u1 - u2|, D2 = |u2 - u3| (rms over markers, components and
  frames, in units of the noise), p = log(D1 / D2) / log(r) and the cosine of the two difference
  fields. All runs share the step, so the time error cancels in the differences.

Never imports petsoft (the truth stays independent).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "independent"))
import generate as indep  # noqa: E402

CACHE = HERE.parents[2] / "out" / "clamp_grading"
#: the fixed smallest element size at the clamp's edges (m) of the "fixed" family
H_EDGE = 0.001
#: mesh families: uniform; graded towards the clamp's edges, h / 4 there (within h / 4 of them)
#: growing to h at 4 h; the same with H_EDGE at the edges; "curved": "scaled" with
#: second-order (curved) cells on curved faces (the plate's hole)
VARIANTS = ("uniform", "scaled", "fixed", "curved")


def mesh(gmsh, variant: str, h: float, shape: str = "finger") -> None:
    """``shape`` (the independent suite's) meshed in a new gmsh model: family ``variant``, bulk
    size ``h``. "uniform" and "scaled" are the truth meshes of ``generate.mesh_shape``
    (``graded=True``, and ``clamp=True`` for "scaled")."""
    if variant != "fixed":
        indep.mesh_shape(gmsh, shape, h, graded=True, clamp=variant != "uniform")
        if variant == "curved":
            gmsh.model.mesh.setOrder(2)
        return
    gmsh.model.add(f"{shape}-{variant}-{h}")
    indep.build_geometry(gmsh, shape)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMin", H_EDGE)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
    field = gmsh.model.mesh.field
    dist = field.add("Distance")
    field.setNumbers(dist, "CurvesList", indep.clamp_edges(gmsh, 2 if shape == "bracket" else 0))
    field.setNumber(dist, "NumPointsPerCurve", 200)
    thr = field.add("Threshold")
    field.setNumber(thr, "InField", dist)
    field.setNumber(thr, "SizeMin", H_EDGE)
    field.setNumber(thr, "SizeMax", h)
    field.setNumber(thr, "DistMin", H_EDGE)
    field.setNumber(thr, "DistMax", 4 * h)
    field.setAsBackgroundMesh(thr)
    indep.size_options(gmsh, 0)
    try:
        indep.generate_tets(gmsh)
    finally:
        indep.size_options(gmsh)


def modes(gmsh, variant: str, h: float, count: int = 4, shape: str = "finger") -> dict:
    """The lowest ``count`` natural frequencies (Hz) of the clamped linear-elastic ``shape``,
    P2."""
    import ufl
    from dolfinx import fem
    from dolfinx import mesh as dmesh
    from dolfinx.fem.petsc import assemble_matrix
    from dolfinx.io import gmshio
    from mpi4py import MPI
    from petsc4py import PETSc
    from slepc4py import SLEPc

    mesh(gmsh, variant, h, shape)
    msh, _, _ = gmshio.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3)
    gmsh.model.remove()
    V = fem.VectorFunctionSpace(msh, ("CG", 2))
    mu = indep.E_TRUE / (2 * (1 + indep.NU))
    lam = indep.E_TRUE * indep.NU / ((1 + indep.NU) * (1 - 2 * indep.NU))
    u, w = ufl.TrialFunction(V), ufl.TestFunction(V)

    def eps(v):
        return ufl.sym(ufl.grad(v))

    k = (2 * mu * ufl.inner(eps(u), eps(w)) + lam * ufl.div(u) * ufl.div(w)) * ufl.dx
    m = indep.RHO * ufl.dot(u, w) * ufl.dx
    facets = dmesh.locate_entities_boundary(msh, 2, lambda x: indep.clamp_mask(shape, x))
    bcs = [fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType),
                           fem.locate_dofs_topological(V, 2, facets), V)]
    K = assemble_matrix(fem.form(k), bcs=bcs, diagonal=1.0)
    K.assemble()
    # the clamped dofs' eigenvalues go to infinity (mass 0 there), far from the target
    M = assemble_matrix(fem.form(m), bcs=bcs, diagonal=0.0)
    M.assemble()
    eps_ = SLEPc.EPS().create(MPI.COMM_SELF)
    eps_.setOperators(K, M)
    eps_.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps_.setDimensions(count)
    eps_.setTarget(0.0)
    eps_.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    eps_.setTolerances(1e-12, 200)
    st = eps_.getST()
    st.setType("sinvert")
    ksp = st.getKSP()
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    eps_.solve()
    lams = sorted(eps_.getEigenvalue(i).real for i in range(eps_.getConverged()))[:count]
    if len(lams) < count:
        raise RuntimeError(f"{variant} h {h}: {len(lams)} eigenvalues converged")
    return {"shape": shape, "variant": variant, "h": h,
            "tets": int(msh.topology.index_map(3).size_local),
            "dofs": int(3 * V.dofmap.index_map.size_global),
            "hz": [float(np.sqrt(x) / (2 * np.pi)) for x in lams]}


def control_markers(gmsh) -> np.ndarray:
    """The control case's 24 markers' candidates: the user's mesh file (the committed
    ``meshes/taper.msh``) and the generator's seed for the control (401)."""
    gmsh.open(str(HERE / "meshes" / "taper.msh"))
    points, tets = indep.model_tets(gmsh)
    return indep.pick_markers("finger", points, tets, 401, 24)


def run(gmsh, variant: str, h: float, end: float) -> Path:
    """The control case's truth over ``end`` s on mesh (``variant``, ``h``), cached."""
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"control-{variant}-{h:g}-{end:g}.npz"
    markers = control_markers(gmsh)
    if indep.cached_run(path, markers, print) is not None:
        return path
    sh = indep.SHAPES["finger"]
    body = {"mesh": lambda g, hh: mesh(g, variant, hh), "h_fine": h,
            "clamp": lambda x: indep.clamp_mask("finger", x), "velocity": sh["velocity"],
            "material": {"youngs_modulus": indep.E_TRUE, "poisson_ratio": indep.NU,
                         "density": indep.RHO, "law": "neohookean"},
            "gravity": indep.GRAVITY}
    res = indep.simulate_truth(gmsh, "control", {"shape": "finger", "truth": {}}, markers,
                               print, h_fine=h, substeps=4, end=end, newton_tol=1e-9,
                               body=body)
    indep.save_run(path, markers, res)
    print(f"{variant} h {h:g}: {res['fine_tets']} P2 tets, {res['dofs']} dofs, "
          f"{res['seconds']:.0f} s")
    return path


def order(variant: str, hs: list[float], end: float) -> dict:
    """The order at the markers from three cached runs of one family (module docstring)."""
    runs = [np.load(CACHE / f"control-{variant}-{h:g}-{end:g}.npz", allow_pickle=True)
            for h in hs]
    found = np.logical_and.reduce([z["found"] for z in runs])
    keep = np.flatnonzero(found)[:24]
    u = [z["displacements"][:, keep] / indep.NOISE for z in runs]
    d1, d2 = u[0] - u[1], u[1] - u[2]
    rms1, rms2 = float(np.sqrt(np.mean(d1 ** 2))), float(np.sqrt(np.mean(d2 ** 2)))
    r = (hs[0] / hs[1] * hs[1] / hs[2]) ** 0.5
    cos = float(np.sum(d1 * d2) / np.sqrt(np.sum(d1 ** 2) * np.sum(d2 ** 2)))
    p = float(np.log(rms1 / rms2) / np.log(r))
    # the finest run's error from the last difference at the measured order
    out = {"variant": variant, "h": hs, "end": end, "D1": rms1, "D2": rms2, "p": p,
           "cosine": cos, "finest_error": rms2 / (r ** p - 1.0),
           "tets": [json.loads(str(z["meta"]))["fine_tets"] for z in runs],
           "dofs": [json.loads(str(z["meta"]))["dofs"] for z in runs]}
    print(json.dumps(out))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("modes")
    a.add_argument("--mesh", default="uniform", choices=VARIANTS)
    a.add_argument("--h", type=float, nargs="+", default=[0.011, 0.008, 0.0058])
    a.add_argument("--count", type=int, default=4)
    a.add_argument("--shape", default="finger", choices=sorted(indep.SHAPES))
    b = sub.add_parser("run")
    b.add_argument("variant", choices=VARIANTS)
    b.add_argument("h", type=float)
    b.add_argument("--end", type=float, default=0.15)
    c = sub.add_parser("order")
    c.add_argument("variant", choices=VARIANTS)
    c.add_argument("h", type=float, nargs=3)
    c.add_argument("--end", type=float, default=0.15)
    args = ap.parse_args()
    if args.cmd == "order":
        order(args.variant, args.h, args.end)
        return 0
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    if args.cmd == "modes":
        rows = []
        for h in args.h:
            rows.append(modes(gmsh, args.mesh, h, args.count, args.shape))
            print(json.dumps(rows[-1]), flush=True)
        f = np.array([r["hz"] for r in rows])
        for i in range(len(rows) - 2):
            r = (rows[i]["h"] / rows[i + 2]["h"]) ** 0.5
            d1, d2 = f[i] - f[i + 1], f[i + 1] - f[i + 2]
            print(f"h {rows[i]['h']:g}, {rows[i + 1]['h']:g}, {rows[i + 2]['h']:g}: "
                  f"f1 - f2 {np.array2string(d1, precision=4)} Hz, f2 - f3 "
                  f"{np.array2string(d2, precision=4)} Hz, p "
                  f"{np.array2string(np.log(np.abs(d1 / d2)) / np.log(r), precision=2)}")
    else:
        run(gmsh, args.variant, args.h, args.end)
    gmsh.finalize()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
