"""Wall time per step of a forward run: petsoft at HEAD, petsoft at an earlier commit, DOLFINx.

What is measured
----------------
A neo-Hookean cantilever (0.3 x 0.04 x 0.04 m box, clamped at x = 0, E = 2e5 Pa, nu = 0.3,
rho = 1000, gravity, kicked by an initial velocity 6 x^2 m/s up), generalized-alpha (spectral
radius 0.9), h = 2 ms over ``--seconds`` of motion (default 2 s: 1000 steps; ``--max-steps``
caps the steps of the big sizes), at about 600, 5,000 and 50,000 dofs. Per size and code:

* ``simulate``: the command ``petsoft simulate`` (XDMF output of every step, summary), timed as a
  whole process; per step = (time of the full run - time of a 5-step run) / (steps - 5), so
  interpreter start, set-up and the first steps drop out (each the fastest of ``--repeat``
  processes below 20,000 dofs: a process's start varies by tenths of a second, as much as a
  millisecond a step at 1000 steps);
* ``forward``: ``ForwardModel.simulate`` (what every calibration run does: 8 markers at 40
  frames), the second of two calls (the first builds solvers), per step;
* ``DOLFINx``: DOLFINx 0.5's Newmark loop (trapezoidal rule, beta = 1/4, gamma = 1/2) on the same
  points and tetrahedra: the same energy in UFL, ``NonlinearProblem`` + ``NewtonSolver`` for the
  displacement, direct solve (MUMPS) up to 6000 dofs and CG + GAMG above, as petsoft's defaults;
  timed over the loop, per step (set-up and JIT excluded). Only when the system python imports
  dolfinx (Debian's ``python3-dolfinx-real``).

The earlier commit (``--base``, default 57eb1aa, the start of issue 15) runs from its own git
worktree and virtual environment (``--base-dir``; made with ``git worktree add --detach DIR REV``
and ``bash scripts/bootstrap.sh`` there). Every measurement is a separate process, run one after
another (never two at once); the table gives ratios from the same run.

Run (never while another MPI job or benchmark runs)::

    .venv/bin/python scripts/benchmarks/bench_forward.py                   # ~600, 5e3, 5e4 dofs
    .venv/bin/python scripts/benchmarks/bench_forward.py --sizes 600 --seconds 0.2   # smoke
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
L = (0.3, 0.04, 0.04)
H = 2e-3


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[600, 5000, 50000],
                    help="approximate dof counts (default 600 5000 50000)")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated time (default 2 s)")
    ap.add_argument("--max-steps", type=int, default=1000,
                    help="at most this many steps per run (default 1000)")
    ap.add_argument("--big-steps", type=int, default=60,
                    help="steps of the sizes above 20,000 dofs (default 60)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="simulate runs of each length below 20,000 dofs; the fastest counts "
                         "(a process's start varies by tenths of a second; default 3)")
    ap.add_argument("--base", default="57eb1aa", help="the earlier commit (label)")
    ap.add_argument("--base-dir", default="/work/wt/start",
                    help="its worktree with a .venv (skipped when absent)")
    ap.add_argument("--worker", choices=["forward", "dolfinx"], help=argparse.SUPPRESS)
    ap.add_argument("--case", help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def cells_for(dofs: float) -> list[int]:
    """Box cells (7.5 m, m, m) whose vertex count x 3 is closest to ``dofs``."""
    best = None
    for m in range(1, 40):
        for nx in (round(7.5 * m), round(7.5 * m) + 1):
            d = 3 * (nx + 1) * (m + 1) ** 2
            if best is None or abs(d - dofs) < abs(best[0] - dofs):
                best = (d, [nx, m, m])
    return best[1]


def experiment_text(cells, steps: int, out: Path) -> str:
    return f"""
[mesh]
box = {{ size = [{L[0]}, {L[1]}, {L[2]}], cells = [{cells[0]}, {cells[1]}, {cells[2]}] }}
[material]
model = "neohookean"
youngs_modulus = 2e5
poisson_ratio = 0.3
density = 1000.0
[gravity]
acceleration = [0.0, 0.0, -9.81]
[[boundary]]
kind = "fixed"
where = "x < 1e-9"
[initial]
velocity = ["0", "0", "6*x*x"]
[time]
end = {steps * H!r}
step = {H!r}
integrator = "alpha"
alpha_radius = 0.9
[output]
directory = "{out}"
"""


MARKERS = [[0.3, 0.0, 0.0], [0.3, 0.04, 0.04], [0.3, 0.02, 0.02], [0.2, 0.0, 0.02],
           [0.15, 0.04, 0.02], [0.1, 0.02, 0.04], [0.05, 0.02, 0.0], [0.25, 0.04, 0.0]]


def worker_forward(case: dict) -> dict:
    """ForwardModel.simulate in this interpreter's petsoft: seconds per step of a second call."""
    import numpy as np

    from petsoft.calibration.forward import ForwardModel
    from petsoft.calibration.observation import MarkerObserver
    from petsoft.experiment import load_experiment

    exp = load_experiment(case["toml"])
    T = case["steps"] * H
    frames = np.linspace(T / 40, T, 40)
    fm = ForwardModel(exp, ["material.youngs_modulus"],
                      lambda s: MarkerObserver(s, np.array(MARKERS)), frames)
    fm.simulate(fm.p0)
    t0 = time.perf_counter()
    fm.simulate(fm.p0)
    return {"per_step": (time.perf_counter() - t0) / case["steps"]}


def worker_dolfinx(case: dict) -> dict:
    """DOLFINx's Newmark loop on the same mesh: seconds per step."""
    import numpy as np
    import ufl
    from dolfinx import fem, nls
    from dolfinx import mesh as dmesh
    from mpi4py import MPI
    from petsc4py import PETSc

    data = np.load(case["mesh"])
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.tetrahedron, 1))
    msh = dmesh.create_mesh(MPI.COMM_WORLD, data["tets"].astype(np.int64), data["points"],
                            domain)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 1))
    u, u0, v0, a0 = (fem.Function(V) for _ in range(4))
    v0.interpolate(lambda x: np.vstack([0 * x[0], 0 * x[0], 6 * x[0] ** 2]))
    dofs = fem.locate_dofs_geometrical(V, lambda p: p[0] < 1e-9)
    bc = fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs, V)
    E, nu, rho = 2e5, 0.3, 1000.0
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    beta, gamma = 0.25, 0.5
    w = ufl.TestFunction(V)
    F = ufl.Identity(3) + ufl.grad(u)
    J = ufl.det(F)
    psi = mu / 2 * (ufl.tr(F.T * F) - 3) - mu * ufl.ln(J) + lam / 2 * ufl.ln(J) ** 2
    a1 = (u - u0 - H * v0) / (beta * H**2) - (1 - 2 * beta) / (2 * beta) * a0
    g = fem.Constant(msh, np.array([0.0, 0.0, -9.81], dtype=PETSc.ScalarType))
    dx1 = ufl.dx(metadata={"quadrature_degree": 1})
    dx2 = ufl.dx(metadata={"quadrature_degree": 2})
    residual = (rho * ufl.inner(a1, w) * dx2 + ufl.derivative(psi * dx1, u, w)
                - rho * ufl.inner(g, w) * dx1)
    problem = fem.petsc.NonlinearProblem(residual, u, [bc])
    solver = nls.petsc.NewtonSolver(MPI.COMM_WORLD, problem)
    solver.convergence_criterion = "incremental"
    solver.rtol, solver.atol, solver.max_it = 1e-10, 1e-12, 25
    ksp = solver.krylov_solver
    if case["dofs"] <= 6000 and MPI.COMM_WORLD.size == 1:
        ksp.setType("preonly")
        ksp.getPC().setType("lu")
        ksp.getPC().setFactorSolverType("mumps")
    else:
        ksp.setType("cg")
        ksp.getPC().setType("gamg")
        ksp.setTolerances(rtol=1e-12)
    # the initial acceleration from M a0 = f - grad W(u0) (u0 = 0: a0 = g)
    a0.interpolate(lambda x: np.vstack([0 * x[0], 0 * x[0], -9.81 + 0 * x[0]]))

    def step():
        u.x.array[:] = u0.x.array + H * v0.x.array
        solver.solve(u)
        a_new = ((u.x.array - u0.x.array - H * v0.x.array) / (beta * H**2)
                 - (1 - 2 * beta) / (2 * beta) * a0.x.array)
        v0.x.array[:] = v0.x.array + H * ((1 - gamma) * a0.x.array + gamma * a_new)
        a0.x.array[:] = a_new
        u0.x.array[:] = u.x.array

    step()                      # JIT and first factorisation
    t0 = time.perf_counter()
    for _ in range(case["steps"] - 1):
        step()
    return {"per_step": (time.perf_counter() - t0) / (case["steps"] - 1)}


def run_json(cmd: list[str], case: dict) -> dict | None:
    out = subprocess.run(cmd + ["--case", json.dumps(case)], capture_output=True, text=True,
                         cwd=ROOT)
    if out.returncode:
        print(f"  (failed: {' '.join(cmd[:3])} ...)\n{out.stderr[-2000:]}", file=sys.stderr)
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def time_simulate(python: str, toml: Path) -> float:
    t0 = time.perf_counter()
    petsoft = str(Path(python).parent / "petsoft")      # the venv's console script
    subprocess.run([petsoft, "simulate", str(toml)], check=True, capture_output=True, cwd=ROOT)
    return time.perf_counter() - t0


def main() -> None:
    args = _args()
    if args.worker:
        case = json.loads(args.case)
        result = worker_forward(case) if args.worker == "forward" else worker_dolfinx(case)
        print(json.dumps(result))
        return
    import numpy as np

    from petsoft.mesh.serial import box_mesh

    codes = {"HEAD": str(ROOT / ".venv/bin/python")}
    base_python = Path(args.base_dir) / ".venv/bin/python"
    if base_python.exists():
        codes[args.base] = str(base_python)
    else:
        print(f"(no {base_python}: the earlier commit is skipped)")
    have_dolfinx = subprocess.run(["/usr/bin/python3", "-c", "import dolfinx"],
                                  capture_output=True).returncode == 0
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="bench_forward_"))
    for target in args.sizes:
        cells = cells_for(target)
        m = box_mesh(L, cells)
        dofs = 3 * len(m.points)
        steps = min(args.max_steps, math.ceil(args.seconds / H))
        if dofs > 20000:
            steps = min(steps, args.big_steps)
        print(f"[progress] {dofs} dofs ({len(m.tets)} tets), {steps} steps ...", file=sys.stderr,
              flush=True)
        np.savez(tmp / "mesh.npz", points=m.points, tets=m.tets)
        full, short = tmp / "full.toml", tmp / "short.toml"
        full.write_text(experiment_text(cells, steps, tmp / "out_full"))
        short.write_text(experiment_text(cells, 5, tmp / "out_short"))
        row = {"dofs": dofs, "steps": steps}
        for label, python in codes.items():
            repeat = args.repeat if dofs <= 20000 else 1
            t_full = min(time_simulate(python, full) for _ in range(repeat))
            t_short = min(time_simulate(python, short) for _ in range(repeat))
            row[f"simulate {label}"] = (t_full - t_short) / (steps - 5)
            res = run_json([python, __file__, "--worker", "forward"],
                           {"toml": str(full), "steps": steps})
            row[f"forward {label}"] = res and res["per_step"]
        if have_dolfinx:
            res = run_json(["/usr/bin/python3", __file__, "--worker", "dolfinx"],
                           {"mesh": str(tmp / "mesh.npz"), "steps": steps, "dofs": dofs})
            row["DOLFINx"] = res and res["per_step"]
        rows.append(row)
        print("  " + ", ".join(f"{k} {v * 1e3:.2f} ms" if isinstance(v, float) else f"{k} {v}"
                               for k, v in row.items()), file=sys.stderr, flush=True)

    def ms(x):
        return f"{x * 1e3:9.2f}" if x else f"{'-':>9}"

    def ratio(a, b):
        return f"{a / b:7.2f}" if a and b else f"{'-':>7}"

    base = args.base if args.base in codes else None
    print("\nms per step (generalized-alpha, neo-Hookean); ratios from this run")
    head = f"{'dofs':>7} {'steps':>6} {'simulate':>9} {'forward':>9}"
    if base:
        head += f" {'sim ' + base[:7]:>12} {'fwd ' + base[:7]:>12} {'x sim':>7} {'x fwd':>7}"
    head += f" {'DOLFINx':>9} {'sim/DFX':>7} {'fwd/DFX':>7}"
    print(head)
    for r in rows:
        line = (f"{r['dofs']:>7} {r['steps']:>6} {ms(r['simulate HEAD'])} "
                f"{ms(r['forward HEAD'])}")
        if base:
            line += (f" {ms(r[f'simulate {base}']):>12} {ms(r[f'forward {base}']):>12} "
                     f"{ratio(r[f'simulate {base}'], r['simulate HEAD'])} "
                     f"{ratio(r[f'forward {base}'], r['forward HEAD'])}")
        d = r.get("DOLFINx")
        line += f" {ms(d)} {ratio(r['simulate HEAD'], d)} {ratio(r['forward HEAD'], d)}"
        print(line)
    print("(x sim, x fwd: the earlier commit's time over HEAD's, the speed-up; sim/DFX, "
          "fwd/DFX: HEAD's time over DOLFINx's)")


if __name__ == "__main__":
    main()
