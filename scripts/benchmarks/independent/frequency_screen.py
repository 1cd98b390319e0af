"""Choose a random case's truth level from its natural frequencies, before any time run.

A case's truth runs cost 10-45 minutes of a core, and the generator's check (three meshes and a
halved step, random_cases.truth_error) used to find out only after them that a truth would not
converge to 0.2x the noise: in the test draw 59653812 four of the first six cases were
discarded so, ~2 core-hours spent for nothing. The truth's error at the markers is mostly a
phase error (a frequency a little off, accumulated over the record), and the body's first
natural frequencies on the same graded P2 meshes cost seconds (linear elasticity, SLEPc
shift-invert at 0). Their convergence over a ladder of meshes h x 1.4^k predicts the marker
error of a level (h, steps a frame) as

    space:  K_space 2 pi e_f(h) T / fraction       e_f: the frequency's extrapolated error
    time:   K_time  2 pi f T / fraction (w dt)^2 / 12
                                                    (w dt)^2 / 12: the trapezoidal rule's
                                                    relative period error, generalized-alpha's
                                                    to leading order at rho_inf near 1

(T the record, fraction the noise over the largest displacement, f the first mode's: the
excitations are transverse to the body, mostly in its first bending mode, and the constants
were read off it; the second mode's is kept in the ladder for the record). The constants come
from the generator's own verdicts (never a diagnosis) on the test draw 59653812's first six
cases, that draw then abandoned: its three discarded free vibrations (r001-fillet,
r003-bracket, r005-fillet; the markers' difference between the h and 1.4 h runs over this
prediction 0.113-0.133, between 1.4 h and 1.96 h 0.117-0.167; the step's difference 0.29-0.86)
and its two written base drives (r000-bar, r004-plate: time 0.19 and 0.06, space ~0.03):
the largest seen (:data:`K`). The prediction only *chooses* the level (the cheapest predicted
to pass with a margin, within a cost cap) or discards a case no affordable level is predicted
to pass; the written case is still checked by the three meshes and the halved step.

System python (DOLFINx 0.5, gmsh, SLEPc).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import random_draw as rd  # noqa: E402
import random_shapes as rs  # noqa: E402

#: the marker error over the frequency prediction (space, time) by excitation: a free
#: vibration (an initial velocity, a release) accumulates the phase error; a base drive's
#: motion mostly follows the drive, and the test draw 59653812's two base-driven cases (r000-bar,
#: r004-plate, written) had 0.16 and ~0.1 of the free vibrations' space error and 0.15 and
#: 0.06 of their time error for the same prediction: the largest seen, rounded up
K = {"velocity": (0.17, 0.9), "release": (0.17, 0.9), "base": (0.05, 0.2)}
#: a level is chosen when its predicted bound is below this fraction of the tolerance (the
#: constants' spread: the ratios above vary by 1.5x in space and 3x in time)
MARGIN = 0.8
#: the mesh ladder: h x LADDER^k, k from COARSEST down to FINEST (the three-mesh check's ratio)
LADDER, COARSEST, FINEST = 1.4, 4, -3
#: the largest mesh the ladder meshes (P2 tets: the eigen solve's and a truth's memory)
MAX_TETS = 40_000
#: steps a frame tried (the truth's check halves them: at least 2)
SUBSTEPS = (4, 8, 16)
#: the affordable truth run: P2 tets x steps (a 13,484-tet plate over 1,308 steps took 852 s
#: of a core, 4.8e-5 s a tet-step; a case costs ~2.1 such runs: the check's coarser meshes,
#: its halved step and the effect-free twin)
MAX_TET_STEPS = 3.0e7
#: the truth's element degrees the screen weighs
DEGREES = (2,)
#: a degree's cost a tet-step over P2's: P3 (quadrature degree 6) took 0.488 and 0.245 s a
#: step on 5,802 and 3,085 tets of the test draw 728634199's r001-plate, P2 0.237 s on 11,497
#: (generate.simulate_truth, 8 steps a frame, one core): 4.1 and 3.9x a tet
COST = {2: 1.0, 3: 4.0}


def frequencies(gmsh, case: dict, h: float, modes: int = 2,
                degree: int = 2) -> tuple[np.ndarray, int]:
    """The first ``modes`` natural frequencies (Hz) of ``case``'s body (its true E, nu, rho;
    clamped as its truth) on the generator's graded truth mesh of size ``h``, Lagrange elements
    of ``degree``; and the mesh's tet count."""
    import ufl
    from dolfinx import fem
    from dolfinx.fem.petsc import assemble_matrix
    from dolfinx.io import gmshio
    from mpi4py import MPI
    from petsc4py import PETSc

    g, mat = case["geometry"], case["material"]
    rs.mesh(gmsh, case["family"], g, h, graded=True, regions=case["truth"].get("regions"))
    msh, _, _ = gmshio.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3)
    gmsh.model.remove()
    V = fem.VectorFunctionSpace(msh, ("CG", degree))
    E, nu, rho = mat["youngs_modulus"], mat["poisson_ratio"], mat["density"]
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)

    def eps(w):
        return ufl.sym(ufl.grad(w))

    k = fem.form(2 * mu * ufl.inner(eps(u), eps(v)) * ufl.dx
                 + lam * ufl.div(u) * ufl.div(v) * ufl.dx)
    m = fem.form(rho * ufl.inner(u, v) * ufl.dx)
    axis = "xyz".index(g["axis"])
    dofs = fem.locate_dofs_geometrical(V, lambda x: x[axis] < 1e-9)
    bc = fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs, V)
    K = assemble_matrix(k, bcs=[bc])
    K.assemble()
    M = assemble_matrix(m, bcs=[bc], diagonal=0.0)      # the clamped dofs' eigenvalues: inf
    M.assemble()
    lam_ = lowest_eigenvalues(K, M, modes)[:modes]
    if len(lam_) < modes:
        raise RuntimeError(f"{case['name']}: {len(lam_)} of {modes} eigenvalues converged")
    tets = msh.topology.index_map(3).size_local
    for obj in (K, M):
        obj.destroy()
    return np.sqrt(np.maximum(lam_, 0.0)) / (2 * math.pi), tets


def lowest_eigenvalues(K, M, count: int, target: float = 0.0) -> list[float]:
    """The converged eigenvalues of K x = lam M x nearest ``target`` (at least ``count``
    sought), sorted: SLEPc shift-invert with MUMPS LU, on one process."""
    from mpi4py import MPI
    from slepc4py import SLEPc

    es = SLEPc.EPS().create(MPI.COMM_SELF)
    es.setOperators(K, M)
    es.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    es.setDimensions(count)
    es.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    es.setTarget(target)
    st = es.getST()
    st.setType("sinvert")
    st.getKSP().setType("preonly")
    st.getKSP().getPC().setType("lu")
    st.getKSP().getPC().setFactorSolverType("mumps")
    es.solve()
    out = sorted(es.getEigenvalue(i).real for i in range(es.getConverged()))
    es.destroy()
    return out


def frequency_error(f: np.ndarray, max_order: float = 4.0) -> float | None:
    """The extrapolated error at h of a frequency ``f`` (3,) on meshes h, 1.4 h, 1.96 h, from
    its observed order (at most ``max_order``: 2 x the degree, P2's 4 for frequencies); None
    when it does not converge (the coarser difference not larger: no order, no estimate)."""
    d1, d2 = abs(f[0] - f[1]), abs(f[1] - f[2])
    if d2 <= d1:
        return None
    p = min(math.log(d2 / max(d1, 1e-300)) / math.log(LADDER), max_order)
    return float(d1 / (LADDER ** p - 1.0))


def predicted(case: dict, f: float, error_f: float, substeps: int) -> dict:
    """The marker error (x noise) predicted for a truth at a mesh whose first frequency is
    ``f`` with error ``error_f``, at ``substeps`` steps a frame."""
    k_space, k_time = K[case["excitation"]["kind"]]
    scale = 2 * math.pi * case["end"] / case["noise_fraction"]
    space = k_space * scale * error_f
    wdt = 2 * math.pi * f * rd.STEP / substeps
    time_ = k_time * scale * f * wdt ** 2 / 12.0
    return {"space": space, "time": time_, "bound": space + time_}


def choose(gmsh, case: dict, tolerance: float, say=print, degrees: tuple = None) -> dict:
    """The cheapest truth level (degree, h, steps a frame) predicted below ``MARGIN`` x
    ``tolerance`` within :data:`MAX_TET_STEPS` (P2-equivalent: :data:`COST` per degree), from
    the frequencies on the ladder h_truth x 1.4^k at each of ``degrees`` (default
    :data:`DEGREES`); its ``"h"`` is None when no affordable level is (the case is to be
    discarded). Returns the ladders (h, tets, frequencies), the levels predicted and the
    choice."""
    degrees = DEGREES if degrees is None else degrees
    h0 = rs.truth_h(case["geometry"])
    steps = case["end"] / rd.STEP
    ladders, levels, best = {}, [], None
    for degree in degrees:
        # no rung finer than the dearest affordable level (its eigen solve alone took ~6 GB
        # and minutes at 60,000 P2 tets): the next rung's tets are predicted from the last's
        affordable = min(MAX_TETS / COST[degree],
                         MAX_TET_STEPS / (steps * SUBSTEPS[0] * COST[degree]))
        ladder = ladders.setdefault(degree, [])
        for k in range(COARSEST, FINEST - 1, -1):
            if ladder and ladder[-1]["tets"] * LADDER ** 3 > 1.25 * affordable:
                break
            h = h0 * LADDER ** k
            f, tets = frequencies(gmsh, case, h, degree=degree)
            ladder.append({"k": k, "h": h, "tets": tets, "frequencies": f.tolist()})
        for i in range(2, len(ladder)):
            # level at ladder[i] (finest of three), checked by ladder[i-1] and ladder[i-2]
            f = [ladder[i]["frequencies"][0], ladder[i - 1]["frequencies"][0],
                 ladder[i - 2]["frequencies"][0]]
            err = frequency_error(f, max_order=2.0 * degree)
            for s in SUBSTEPS:
                cost = ladder[i]["tets"] * steps * s * COST[degree]
                level = {"degree": degree, "h": ladder[i]["h"], "tets": ladder[i]["tets"],
                         "substeps": s, "tet_steps": cost}
                if err is None:
                    level["predicted"] = None
                else:
                    level["predicted"] = predicted(case, f[0], err, s)
                    level["frequency_error"] = err
                levels.append(level)
                ok = (level["predicted"] is not None and cost <= MAX_TET_STEPS
                      and level["predicted"]["bound"] < MARGIN * tolerance)
                if ok and (best is None or cost < best["tet_steps"]):
                    best = level
    for lv in levels:
        p = lv["predicted"]
        say(f"  screen P{lv['degree']} h {lv['h']:.4g} ({lv['tets']} tets) x{lv['substeps']}: "
            + ("no convergence seen" if p is None else
               f"space {p['space']:.3g} + time {p['time']:.3g} = {p['bound']:.3g} x noise")
            + f", {lv['tet_steps']:.3g} P2 tet-steps")
    k_space, k_time = K[case["excitation"]["kind"]]
    return {"ladder": ladders[degrees[0]], "ladders": {str(d): v for d, v in ladders.items()},
            "levels": levels, "margin": MARGIN,
            "constants": {"space": k_space, "time": k_time}, "max_tet_steps": MAX_TET_STEPS,
            "cost_per_degree": {str(d): COST[d] for d in degrees},
            "h": None if best is None else best["h"],
            "degree": None if best is None else best["degree"],
            "substeps": None if best is None else best["substeps"], "chosen": best}
