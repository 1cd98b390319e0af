"""Independent reference data for petsoft's quadratic (10-node P2) tetrahedra, made by DOLFINx.

Run with the system python (DOLFINx 0.5 and gmsh are Debian packages there, not in the .venv)::

    OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \\
        nice /usr/bin/python3 scripts/benchmarks/independent/p2_reference.py \\
        [--cook-h 0.006] [--dry]

(serial; a few seconds, plus FFCx's one-time JIT compilation of the forms). ``--dry`` writes
nothing (for convergence checks such as ``--cook-h 0.003 --dry``). It writes, into
``tests/data/p2_reference/`` (float64 arrays, ``np.savez_compressed``):

``cook.npz`` -- 3D Cook's membrane, LINEAR elasticity, P2 Lagrange on a straight-sided P1 tet mesh
    (gmsh, characteristic length ``--cook-h``). The trapezoid (0,0), (0.048,0.044), (0.048,0.060),
    (0,0.044) in x-y (metres), extruded in z over [0, 0.01]; E = 1e6 Pa, nu = 0.3, energy
    psi = mu eps:eps + lam/2 tr(eps)^2; the face x = 0 clamped (every dof on it, all components);
    a uniform traction (0, 1e3, 0) Pa (force per reference area) on the face x = 0.048; no gravity.
    Solved with MUMPS LU (two steps of iterative refinement); the backward error
    ||K u - f|| / (||K|| ||u|| + ||f||) is checked (< 1e-14). Arrays:

    * ``points`` (N,3) mesh vertices, ``tets`` (E,4) int64 corner connectivity, 0-based into
      ``points``, every tet positively oriented (det[p1-p0, p2-p0, p3-p0] > 0);
    * ``dof_coords`` (M,3) every P2 node (vertices and edge midpoints), ``u`` (M,3) the
      displacement there (the node order is DOLFINx's, no meaning of its own; match by coordinate
      or use the two index arrays below);
    * ``tets10`` (E,10) int64 into ``dof_coords``: the four corners in the order of ``tets`` and
      then the midpoints of the edges 01, 12, 02, 03, 13, 23 (VTK's quadratic-tet order);
      ``tets10_gmsh`` (E,10) the same in gmsh's 10-node order, edges 01, 12, 20, 30, 32, 31
      (the last two swapped with respect to VTK);
    * ``vertex_dof`` (N,) int64: the row of ``dof_coords`` / ``u`` of each mesh vertex;
    * ``E``, ``nu``, ``traction`` (3,), ``energy`` = 1/2 u.K.u (= 1/2 the external work; both are
      computed and must agree), ``tip`` (3,) the displacement at (0.048, 0.060, 0.005) if that is
      a P2 node, else the average over the P2 nodes of the edge x = 0.048, y = 0.060
      (``tip_is_node`` says which), ``tip_eval`` (3,) the P2 field evaluated at that point
      (always), ``tip_p1`` (3,) the same point evaluated from a P1 solve on the same mesh
      (self-check: P1 locks/stiffens, so |tip_p1| < |tip|).

``beam_modes.npz`` -- a clamped-free beam [0,0.2] x [0,0.01] x [0,0.02] (dolfinx create_box, 20x1x2
    hexes each split into 6 tets, P1 geometry), E = 1e6, nu = 0.3, rho = 1000, face x = 0 clamped.

    * ``points``, ``tets``, ``tets10``, ``vertex_dof``, ``dof_coords`` as above (tets reoriented
      where DOLFINx's were negative: ``reoriented`` counts them);
    * ``frequencies_hz`` (8,) the first 8 natural frequencies of K x = omega^2 M x with the
      CONSISTENT P2 mass matrix (exact quadrature), by SLEPc shift-and-invert about 0 with MUMPS;
      the Dirichlet rows are 1 on K's diagonal and 0 on M's, so they give infinite eigenvalues
      that shift-and-invert never finds; ``modes`` (8, M, 3) the mass-normalised mode shapes;
    * ``u_gravity`` (M,3) at ``dof_coords_gravity`` (the same nodes as ``dof_coords``): the
      static linear solution under body force rho g, g = (0, 0, -9.81); ``tip_deflection_gravity``
      the mean u_z over the P2 nodes at x = 0.2; ``rho``, ``E``, ``nu``, ``g``.

Checks made when the data were written (h = 0.006: 464 tets; beam 240 tets, 615 P2 nodes):

* Cook P2 tip u_y (m): 3.9620e-4 (h 0.006), 3.9838e-4 (h 0.003, 3114 tets), 3.9932e-4
  (h 0.0015, 21136 tets) -- converging (rate ~1.2 in h, the clamp's corner singularity); P1 on
  the same meshes 3.527e-4, 3.784e-4, 3.905e-4;
* beam frequencies (Hz) 1.2871 2.5494 7.9885 15.298 19.222 22.054 39.649 40.321 against
  Euler-Bernoulli 1.2771 (bending in y, the 0.01 direction), 2.5542 (in z), 8.0034 (y),
  16.007 (z), torsion ~18.2 (St-Venant, free warping), 22.410 (y), axial 39.529, 44.82 (z): the
  higher bending modes in z fall below Euler-Bernoulli by shear (Timoshenko); the mode shapes'
  dominant components confirm the pairing (printed);
* gravity tip u_z -5.8765e-2 m against q L^4 / (8 E I) = -5.886e-2 m;
* an independent numpy/scipy P2 assembly (throwaway, not kept) on the saved ``tets10`` /
  ``dof_coords`` reproduced ``u`` (1e-13), ``energy``, ``frequencies_hz`` (all digits printed)
  and ``u_gravity`` (2e-10: the gravity solve's conditioning; compare at ~1e-8).

How the data are used: petsoft's P2 tests load these files and compare petsoft's own P2 solution
on the same ``points`` / ``tets`` (petsoft makes its own edge-midpoint nodes) with ``u`` at
``dof_coords`` (match by coordinate), the energy, the tip, and the frequencies. Nothing here is
computed by petsoft. A summary is printed, including the P1 Cook tip so the P2/P1 difference is
visible, and Euler-Bernoulli frequencies of the beam for comparison.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE.parents[2] / "tests" / "data" / "p2_reference"

E, NU, RHO = 1.0e6, 0.3, 1000.0
TRACTION = np.array([0.0, 1.0e3, 0.0])
GRAVITY = np.array([0.0, 0.0, -9.81])
COOK_TIP = np.array([0.048, 0.060, 0.005])
BEAM = dict(L=0.2, h=0.01, b=0.02, cells=(20, 1, 2))
NMODES = 8

VTK_EDGES = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]
GMSH_EDGES = [(0, 1), (1, 2), (2, 0), (3, 0), (3, 2), (3, 1)]


def lame():
    mu = E / (2 * (1 + NU))
    lam = E * NU / ((1 + NU) * (1 - 2 * NU))
    return mu, lam


def cook_gmsh(gmsh, h: float):
    """The Cook membrane in the current gmsh model, P1 tets of characteristic length h."""
    gmsh.model.add(f"cook-{h}")
    occ = gmsh.model.occ
    p = [occ.addPoint(x, y, 0.0) for x, y in
         ((0.0, 0.0), (0.048, 0.044), (0.048, 0.060), (0.0, 0.044))]
    lines = [occ.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]
    surf = occ.addPlaneSurface([occ.addCurveLoop(lines)])
    occ.extrude([(2, surf)], 0.0, 0.0, 0.01)
    occ.synchronize()
    vols = gmsh.model.getEntities(3)
    gmsh.model.addPhysicalGroup(3, [v[1] for v in vols], 1)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMin", h)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
    gmsh.option.setNumber("Mesh.ElementOrder", 1)
    gmsh.model.mesh.generate(3)


def corners(msh):
    """Vertices (N,3) and corner connectivity (E,4) of a serial P1 DOLFINx mesh, as DOLFINx has
    them (geometry nodes = vertices for a P1 mesh)."""
    x = np.array(msh.geometry.x[:, :3], dtype=np.float64)
    cells = np.array(msh.geometry.dofmap.array, dtype=np.int64).reshape(-1, 4)
    return x, cells


def orient(points, tets):
    """Swap corners 2 and 3 of negatively oriented tets; return (tets, number swapped)."""
    p = points[tets]
    det = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    assert np.all(np.abs(det) > 0), "degenerate tet"
    neg = det < 0
    out = tets.copy()
    out[neg, 2], out[neg, 3] = tets[neg, 3], tets[neg, 2]
    p = points[out]
    det = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    assert np.all(det > 0)
    return out, int(neg.sum())


def p2_connectivity(V, points, tets):
    """(tets10 VTK order, tets10 gmsh order, vertex_dof) into the node list of V, found by
    coordinates within each cell (robust to DOLFINx's internal numbering)."""
    X = V.tabulate_dof_coordinates()
    cd = np.array(V.dofmap.list.array, dtype=np.int64).reshape(len(tets), -1)
    assert cd.shape[1] == 10
    pc = points[tets]                                          # (E,4,3)

    def find(edges):
        targets = np.concatenate(
            [pc, np.stack([(pc[:, a] + pc[:, b]) / 2 for a, b in edges], axis=1)], axis=1)
        d = np.linalg.norm(X[cd][:, None, :, :] - targets[:, :, None, :], axis=3)  # (E,10,10)
        j = d.argmin(axis=2)
        assert d.min(axis=2).max() < 1e-12, "a P2 node not at a corner or edge midpoint"
        out = np.take_along_axis(cd, j, axis=1)
        assert all(len(set(r)) == 10 for r in out[:50])
        return out

    t10 = find(VTK_EDGES)
    vertex_dof = np.full(len(points), -1, dtype=np.int64)
    vertex_dof[tets.ravel()] = t10[:, :4].ravel()
    assert np.all(vertex_dof >= 0)
    assert np.allclose(X[vertex_dof], points, atol=1e-14)
    return t10, find(GMSH_EDGES), vertex_dof


def lu(A):
    from petsc4py import PETSc

    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    return ksp


def solve_linear(V, a, L, bcs):
    """Assemble and solve a(u, v) = L(v) with MUMPS; return (u Function, backward error)."""
    from dolfinx import fem
    from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, set_bc
    from petsc4py import PETSc

    af, Lf = fem.form(a), fem.form(L)
    A = assemble_matrix(af, bcs=bcs)
    A.assemble()
    b = assemble_vector(Lf)
    apply_lifting(b, [af], bcs=[bcs])
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    set_bc(b, bcs)
    u = fem.Function(V)
    ksp = lu(A)
    ksp.solve(b, u.vector)
    r, du = b.duplicate(), b.duplicate()
    for _ in range(2):              # iterative refinement: LU alone leaves ~1e-10 on the beam
        A.mult(u.vector, r)
        r.aypx(-1.0, b)             # r = b - A u
        ksp.solve(r, du)
        u.vector.axpy(1.0, du)
    u.x.scatter_forward()
    A.mult(u.vector, r)
    r.axpy(-1.0, b)
    # normwise backward error ||r|| / (||A|| ||u|| + ||b||) (infinity norms): round-off is
    # ~1e-16 of it, while ||r|| / ||b|| alone has a floor of eps ||A|| ||u|| / ||b|| (~1e-10
    # for the gravity beam, where the clamp's reactions cancel large stiffness terms)
    inf = PETSc.NormType.INFINITY
    return u, r.norm(inf) / (A.norm(inf) * u.vector.norm(inf) + b.norm(inf))


def elasticity_forms(msh, V):
    import ufl

    mu, lam = lame()
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)

    def eps(w):
        return ufl.sym(ufl.grad(w))

    def sigma(w):
        return 2 * mu * eps(w) + lam * ufl.tr(eps(w)) * ufl.Identity(3)

    return u, v, eps, sigma


def cook(gmsh, h: float, degree: int):
    """Solve Cook's membrane with P<degree>; return a dict of results."""
    import ufl
    from dolfinx import fem, geometry
    from dolfinx import mesh as dmesh
    from dolfinx.io import gmshio
    from mpi4py import MPI
    from petsc4py import PETSc

    cook_gmsh(gmsh, h)
    msh, _, _ = gmshio.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3)
    gmsh.model.remove()
    V = fem.VectorFunctionSpace(msh, ("CG", degree))
    u_, v, eps, sigma = elasticity_forms(msh, V)
    clamp = dmesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 0.0))
    load = dmesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 0.048))
    tags = dmesh.meshtags(msh, 2, load, np.full(len(load), 1, dtype=np.int32))
    ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
    bcs = [fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType),
                           fem.locate_dofs_topological(V, 2, clamp), V)]
    t = fem.Constant(msh, PETSc.ScalarType(TRACTION))
    u, res = solve_linear(V, ufl.inner(sigma(u_), eps(v)) * ufl.dx, ufl.dot(t, v) * ds(1), bcs)
    energy = fem.assemble_scalar(fem.form(0.5 * ufl.inner(sigma(u), eps(u)) * ufl.dx))
    work = fem.assemble_scalar(fem.form(ufl.dot(t, u) * ds(1)))
    load_area = fem.assemble_scalar(fem.form(1.0 * ds(1)))
    X = V.tabulate_dof_coordinates()
    U = u.x.array.reshape(-1, 3).copy()
    assert X.shape == U.shape
    # the tip: a node at the point, else the mean over the nodes of the edge x=0.048, y=0.060
    hit = np.flatnonzero(np.linalg.norm(X - COOK_TIP, axis=1) < 1e-10)
    if len(hit):
        tip, tip_is_node = U[hit[0]], True
    else:
        edge = np.flatnonzero((np.abs(X[:, 0] - 0.048) < 1e-10) & (np.abs(X[:, 1] - 0.060) < 1e-10))
        tip, tip_is_node = U[edge].mean(axis=0), False
    tree = geometry.BoundingBoxTree(msh, 3)
    cand = geometry.compute_collisions(tree, COOK_TIP[None])
    cell = geometry.compute_colliding_cells(msh, cand, COOK_TIP[None]).links(0)[0]
    tip_eval = np.asarray(u.eval(COOK_TIP[None], np.array([cell], dtype=np.int32))).ravel()[:3]
    points, tets0 = corners(msh)
    tets, flipped = orient(points, tets0)
    out = dict(points=points, tets=tets, flipped=flipped, dof_coords=X, u=U, energy=energy,
               work=work, residual=res, tip=tip, tip_is_node=tip_is_node, tip_eval=tip_eval,
               load_area=load_area, dofs=U.size)
    if degree == 2:
        out["tets10"], out["tets10_gmsh"], out["vertex_dof"] = p2_connectivity(V, points, tets)
    return out


def beam():
    """Clamped-free beam: modes (consistent mass) and the static gravity solution, P2."""
    import ufl
    from dolfinx import fem
    from dolfinx import mesh as dmesh
    from dolfinx.fem.petsc import assemble_matrix
    from mpi4py import MPI
    from petsc4py import PETSc
    from slepc4py import SLEPc

    L, hy, bz = BEAM["L"], BEAM["h"], BEAM["b"]
    msh = dmesh.create_box(MPI.COMM_SELF, [np.zeros(3), np.array([L, hy, bz])],
                           list(BEAM["cells"]), dmesh.CellType.tetrahedron)
    V = fem.VectorFunctionSpace(msh, ("CG", 2))
    u_, v, eps, sigma = elasticity_forms(msh, V)
    clamp = dmesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 0.0))
    bcs = [fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType),
                           fem.locate_dofs_topological(V, 2, clamp), V)]
    k_form = fem.form(ufl.inner(sigma(u_), eps(v)) * ufl.dx)
    m_form = fem.form(RHO * ufl.dot(u_, v) * ufl.dx)     # P2 x P2: degree 4, exact
    K = assemble_matrix(k_form, bcs=bcs, diagonal=1.0)
    K.assemble()
    M = assemble_matrix(m_form, bcs=bcs, diagonal=0.0)
    M.assemble()
    eps_ = SLEPc.EPS().create(MPI.COMM_SELF)
    eps_.setOperators(K, M)
    eps_.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps_.setDimensions(NMODES + 4)
    eps_.setTolerances(1e-12, 500)
    st = eps_.getST()
    st.setType(SLEPc.ST.Type.SINVERT)
    st.setShift(0.0)
    ksp = st.getKSP()
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    eps_.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    eps_.setTarget(0.0)
    eps_.solve()
    nconv = eps_.getConverged()
    assert nconv >= NMODES, nconv
    vr = K.createVecRight()
    pairs = []
    for i in range(nconv):
        lam_ = eps_.getEigenpair(i, vr).real
        err = eps_.computeError(i, SLEPc.EPS.ErrorType.RELATIVE)
        Mx = vr.duplicate()
        M.mult(vr, Mx)
        vr.scale(1.0 / np.sqrt(vr.dot(Mx)))
        pairs.append((lam_, err, vr.getArray().copy()))
    pairs.sort(key=lambda p: p[0])
    pairs = pairs[:NMODES]
    lams = np.array([p[0] for p in pairs])
    assert np.all(lams > 0) and np.all(np.isfinite(lams))
    errs = np.array([p[1] for p in pairs])
    freqs = np.sqrt(lams) / (2 * np.pi)
    X = V.tabulate_dof_coordinates()
    modes = np.array([p[2].reshape(-1, 3) for p in pairs])

    g = fem.Constant(msh, PETSc.ScalarType(GRAVITY))
    u, res = solve_linear(V, ufl.inner(sigma(u_), eps(v)) * ufl.dx, RHO * ufl.dot(g, v) * ufl.dx,
                          bcs)
    U = u.x.array.reshape(-1, 3).copy()
    tipn = np.abs(X[:, 0] - L) < 1e-10
    points, tets0 = corners(msh)
    tets, flipped = orient(points, tets0)
    t10, t10g, vdof = p2_connectivity(V, points, tets)
    return dict(points=points, tets=tets, reoriented=flipped, tets10=t10, tets10_gmsh=t10g,
                vertex_dof=vdof, dof_coords=X, frequencies_hz=freqs, eig_rel_error=errs,
                modes=modes, u_gravity=U, dof_coords_gravity=X.copy(),
                tip_deflection_gravity=U[tipn, 2].mean(), tip_nodes=int(tipn.sum()),
                residual=res, dofs=U.size)


def beam_theory():
    """Euler-Bernoulli bending (both axes), St-Venant torsion and axial frequencies (Hz)."""
    L, hy, bz = BEAM["L"], BEAM["h"], BEAM["b"]
    A = hy * bz
    G = E / (2 * (1 + NU))
    out = []
    for bl in (1.875104, 4.694091, 7.854757):
        for name, I in (("bend y (thin)", bz * hy ** 3 / 12), ("bend z", hy * bz ** 3 / 12)):
            out.append((bl ** 2 / (2 * np.pi) * np.sqrt(E * I / (RHO * A * L ** 4)),
                        f"{name}, beta L = {bl:.4f}"))
    a, b = bz / 2, hy / 2                           # St-Venant J of a 2a x 2b rectangle, a >= b
    J = a * b ** 3 * (16 / 3 - 3.36 * b / a * (1 - b ** 4 / (12 * a ** 4)))
    Ip = A * (hy ** 2 + bz ** 2) / 12
    out.append((1 / (4 * L) * np.sqrt(G * J / (RHO * Ip)), "torsion 1"))
    out.append((1 / (4 * L) * np.sqrt(E / RHO), "axial 1"))
    return sorted(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cook-h", type=float, default=0.006, help="Cook mesh size (m)")
    ap.add_argument("--dry", action="store_true", help="print, write nothing")
    args = ap.parse_args()
    import logging

    import gmsh

    logging.getLogger().setLevel(logging.WARNING)      # FFCx's JIT compiler logs at INFO
    t0 = time.perf_counter()
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    c2 = cook(gmsh, args.cook_h, 2)
    c1 = cook(gmsh, args.cook_h, 1)
    gmsh.finalize()
    assert len(c1["tets"]) == len(c2["tets"])
    rel = abs(c2["energy"] - 0.5 * c2["work"]) / c2["energy"]
    assert c1["residual"] < 1e-14
    print(f"Cook (h = {args.cook_h:g} m): {len(c2['tets'])} tets, {len(c2['points'])} vertices; "
          f"P2 {c2['dofs']} dofs, backward error {c2['residual']:.1e}, energy {c2['energy']:.6e} J "
          f"(vs work/2: rel diff {rel:.1e}), load area {c2['load_area']:.6e} m^2, "
          f"{c2['flipped']} tets reoriented")
    print(f"  tip P2 ({'node' if c2['tip_is_node'] else 'edge mean'}) {c2['tip']}, "
          f"evaluated {c2['tip_eval']}")
    print(f"  tip P1 ({'node' if c1['tip_is_node'] else 'edge mean'}) {c1['tip']}, "
          f"evaluated {c1['tip_eval']}; P1 {c1['dofs']} dofs, energy {c1['energy']:.6e} J; "
          f"P1/P2 tip u_y {c1['tip_eval'][1] / c2['tip_eval'][1]:.4f}")
    assert c2["residual"] < 1e-14 and rel < 1e-8

    b = beam()
    print(f"beam: {len(b['tets'])} tets, {b['dofs']} P2 dofs, {b['reoriented']} tets reoriented; "
          f"eigen rel errors <= {b['eig_rel_error'].max():.1e}")
    theory = beam_theory()
    print("  f (Hz) P2:   " + " ".join(f"{f:.4f}" for f in b["frequencies_hz"]))
    share = (b["modes"] ** 2).sum(axis=1)
    share /= share.sum(axis=1, keepdims=True)
    print("  share of |mode|^2 in (x, y, z): " + " ".join(
        "(" + ",".join(f"{s:.2f}" for s in row) + ")" for row in share))
    print("  beam theory: " + "; ".join(f"{f:.4f} {n}" for f, n in theory[:NMODES + 1]))
    q, EI = RHO * 9.81 * BEAM["h"] * BEAM["b"], E * BEAM["h"] * BEAM["b"] ** 3 / 12
    print(f"  gravity: tip u_z {b['tip_deflection_gravity']:.6e} m ({b['tip_nodes']} nodes), "
          f"backward error {b['residual']:.1e}; Euler-Bernoulli qL^4/(8EI) "
          f"{q * BEAM['L'] ** 4 / (8 * EI):.6e} m")
    assert b["residual"] < 1e-14

    if not args.dry:
        OUT.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            OUT / "cook.npz", points=c2["points"], tets=c2["tets"].astype(np.int64),
            tets10=c2["tets10"], tets10_gmsh=c2["tets10_gmsh"], vertex_dof=c2["vertex_dof"],
            dof_coords=c2["dof_coords"], u=c2["u"], E=np.float64(E), nu=np.float64(NU),
            traction=TRACTION, energy=np.float64(c2["energy"]), tip=c2["tip"],
            tip_is_node=np.bool_(c2["tip_is_node"]), tip_point=COOK_TIP,
            tip_eval=c2["tip_eval"], tip_p1=c1["tip_eval"], h=np.float64(args.cook_h))
        np.savez_compressed(
            OUT / "beam_modes.npz", points=b["points"], tets=b["tets"].astype(np.int64),
            reoriented=np.int64(b["reoriented"]), tets10=b["tets10"],
            tets10_gmsh=b["tets10_gmsh"], vertex_dof=b["vertex_dof"], dof_coords=b["dof_coords"],
            frequencies_hz=b["frequencies_hz"], modes=b["modes"], E=np.float64(E),
            nu=np.float64(NU), rho=np.float64(RHO), g=GRAVITY, u_gravity=b["u_gravity"],
            dof_coords_gravity=b["dof_coords_gravity"],
            tip_deflection_gravity=np.float64(b["tip_deflection_gravity"]))
        for f in ("cook.npz", "beam_modes.npz"):
            print(f"wrote {OUT / f} ({(OUT / f).stat().st_size / 1024:.0f} kB)")
    print(f"{time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
