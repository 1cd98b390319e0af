"""The first natural frequencies of a drawn case's body (linear elasticity at its true E, nu,
rho; clamped as its truth; P2 on the generator's truth mesh, DOLFINx + SLEPc shift-invert at
0) against the draw's estimate (random_draw.first_frequency) and a base drive's frequency:
``python3 first_frequencies.py SEED CASE N [FACTOR ...]`` (the truth's h times each FACTOR,
default 1; GRADE=K: graded to h / K over 6 h instead of the generator's h / 4 over 4 h;
UNGRADED=clamp or inner: that edge left ungraded)."""

import os
import sys

os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
import gmsh
import numpy as np
import random_draw as rd
import random_shapes as rs
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_matrix
from dolfinx.io import gmshio
from mpi4py import MPI
from petsc4py import PETSc
from slepc4py import SLEPc

seed, name, n = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
factors = [float(f) for f in sys.argv[4:]] or [1.0]
if os.environ.get("GRADE"):
    # GRADE=K: the clamp's edges (and a bracket's inner edge) graded to h / K over 6 h
    import generate as indep

    finest, graded = float(os.environ["GRADE"]), indep.grade_towards

    def grade(gmsh, curves, h, field_only=False):
        graded(gmsh, curves, h, field_only, finest=finest, over=6.0, points=100)

    indep.grade_towards = grade
if os.environ.get("UNGRADED") == "clamp":      # only a bracket's inner edge graded
    import generate as indep

    indep.clamp_edges = lambda gmsh, axis: []
elif os.environ.get("UNGRADED") == "inner":    # only the clamp's edges graded
    rs.reentrant_edges = lambda gmsh, g: []
case = [c for c in rd.draw(seed, n, "realistic") if c["name"] == name][0]
g, mat = case["geometry"], case["material"]
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)


def eps(w):
    return ufl.sym(ufl.grad(w))


for factor in factors:
    rs.mesh(gmsh, case["family"], g, rs.truth_h(g) * factor, graded=True)
    msh, _, _ = gmshio.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3)
    gmsh.model.remove()
    V = fem.VectorFunctionSpace(msh, ("CG", 2))
    E, nu, rho = mat["youngs_modulus"], mat["poisson_ratio"], mat["density"]
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)

    k = fem.form(
        2 * mu * ufl.inner(eps(u), eps(v)) * ufl.dx + lam * ufl.div(u) * ufl.div(v) * ufl.dx
    )
    m = fem.form(rho * ufl.inner(u, v) * ufl.dx)
    axis = "xyz".index(g["axis"])
    dofs = fem.locate_dofs_geometrical(V, lambda x, axis=axis: x[axis] < 1e-9)
    bc = fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs, V)
    K = assemble_matrix(k, bcs=[bc])
    K.assemble()
    M = assemble_matrix(m, bcs=[bc], diagonal=0.0)
    M.assemble()
    es = SLEPc.EPS().create(MPI.COMM_SELF)
    es.setOperators(K, M)
    es.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    es.setDimensions(4)
    es.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    es.setTarget(0.0)
    st = es.getST()
    st.setType("sinvert")
    st.getKSP().setType("preonly")
    st.getKSP().getPC().setType("lu")
    st.getKSP().getPC().setFactorSolverType("mumps")
    es.solve()
    freqs = sorted(
        np.sqrt(max(es.getEigenvalue(i).real, 0.0)) / (2 * np.pi) for i in range(es.getConverged())
    )
    est = rd.first_frequency(case["family"], g, mat)
    base = case["excitation"].get("base")
    drive = f", base drive {base['omega'] / (2 * np.pi):.3g} Hz" if base else ""
    print(
        f"{name} h x {factor:g} ({msh.topology.index_map(3).size_local} tets): first "
        f"frequencies {', '.join(f'{f:.6g}' for f in freqs[:4])} Hz, "
        f"split {freqs[1] - freqs[0]:.5g}; "
        f"the draw's estimate {est:.3g} Hz{drive}"
    )
