"""A drawn case's body unclamped: its first three non-rigid natural frequencies (linear
elasticity at its true E, nu, rho) on the generator's graded truth meshes h x FACTOR:
``python3 free_frequencies.py SEED CASE N FACTOR [FACTOR ...]`` (DEGREE=3: P3 elements;
NOHOLE=1: a plate without its hole; UNGRADED=1: the uniform mesh). Without the clamp there is
no singular edge: what is left of a slow convergence is the elements' own (a plate's bending
on P2 tets)."""

import math
import os
import sys

os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
import frequency_screen as fs
import gmsh
import numpy as np
import random_draw as rd
import random_shapes as rs

seed, name, n = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
case = [c for c in rd.draw(seed, n, "realistic") if c["name"] == name][0]
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
if os.environ.get("NOHOLE"):            # the plate's hole cut away from nothing
    gmsh.model.occ.cut = lambda obj, tool, **k: gmsh.model.occ.remove(tool, recursive=True)
import ufl  # noqa: E402
from dolfinx import fem  # noqa: E402
from dolfinx.fem.petsc import assemble_matrix  # noqa: E402
from dolfinx.io import gmshio  # noqa: E402
from mpi4py import MPI  # noqa: E402

g, mat = case["geometry"], case["material"]
E, nu, rho = mat["youngs_modulus"], mat["poisson_ratio"], mat["density"]
mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
for factor in (float(f) for f in sys.argv[4:]):
    rs.mesh(gmsh, case["family"], g, rs.truth_h(g) * factor, graded=not os.environ.get("UNGRADED"))
    msh, _, _ = gmshio.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3)
    gmsh.model.remove()
    V = fem.VectorFunctionSpace(msh, ("CG", int(os.environ.get("DEGREE", 2))))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)

    def eps(w):
        return ufl.sym(ufl.grad(w))

    K = assemble_matrix(fem.form(2 * mu * ufl.inner(eps(u), eps(v)) * ufl.dx
                                 + lam * ufl.div(u) * ufl.div(v) * ufl.dx))
    K.assemble()
    M = assemble_matrix(fem.form(rho * ufl.inner(u, v) * ufl.dx))
    M.assemble()
    # below the six rigid modes' zeros: K alone is singular
    lams = fs.lowest_eigenvalues(K, M, 9, target=-1000.0)
    f = np.sqrt(np.maximum(lams, 0.0)) / (2 * math.pi)
    print(f"{name} h x {factor:g} ({msh.topology.index_map(3).size_local} tets): first "
          f"non-rigid frequencies {', '.join(f'{x:.6f}' for x in f[6:9])} Hz", flush=True)
