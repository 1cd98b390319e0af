"""Rest shape from a captured equilibrium and the X/u splitting, on synthetic data.

A neo-Hookean body (a cantilever sagging under gravity, or a soft block hanging from its top
face) is "captured" at equilibrium: the captured mesh is the deformed shape x of the true rest
mesh X. A recording of markers (given on the captured shape) follows a kick from that state.
The script then

1. recovers X from x for the true E (inverse statics) and prints the relative error;
2. calibrates E from the recording with 0.5 % marker noise (std = 0.5 % of the markers' peak
   motion) twice: wrongly taking the captured mesh as the rest shape, and with the X/u
   splitting (``petsoft calibrate --rest-shape``); prints both errors side by side.

Run:
    mpiexec -n 2 python scripts/examples/demo_rest_shape.py [--case cantilever|block|both]

Things to try: ``-rest_shape_snes_monitor`` (the inverse-statics Newton), a softer material
(``--scale-E 0.3``) until no rest shape exists (the error names the residual history).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.calibrate import build_forward, run_calibration
from petsoft.calibration.rest_shape import calibrate_rest_shape, compute_rest_shape
from petsoft.experiment import load_experiment
from petsoft.io.recording import Recording
from petsoft.mesh.serial import box_mesh
from petsoft.physics.model import build_model
from petsoft.solvers.static import StaticSolver

CASES = {
    # size, cells, where fixed, gravity, true E, initial velocity
    "cantilever": ((0.3, 0.04, 0.04), (6, 2, 2), "x < 1e-9", (0.0, 0.0, -9.81), 3e5,
                   ("0", "0", "2*x*x")),
    "block": ((0.06, 0.06, 0.1), (2, 2, 3), "z > 0.1 - 1e-9", (0.0, 0.0, -9.81), 2e4,
              ("0", "0", "-3*(0.1 - z)")),
}


def experiment_text(case: str, mesh_file: str, E: float) -> str:
    size, cells, where, g, _, vel = CASES[case]
    return f"""
[mesh]
file = "{mesh_file}"
[material]
model = "neohookean"
youngs_modulus = {E}
poisson_ratio = 0.3
density = 1000.0
[gravity]
acceleration = [{g[0]}, {g[1]}, {g[2]}]
[[boundary]]
kind = "fixed"
where = "{where}"
[initial]
from = "static"
velocity = ["{vel[0]}", "{vel[1]}", "{vel[2]}"]
[time]
end = 0.15
step = 0.005
integrator = "be"
[calibrate]
"material.youngs_modulus" = [{E / 1000}, {E * 20}]
"""


def write_mesh(path: Path, mesh, comm=PETSc.COMM_WORLD) -> None:
    """Write ``mesh`` on the first rank of ``comm`` (every rank has it); the others wait."""
    import meshio
    if comm.getRank() == 0:
        meshio.write(path, meshio.Mesh(mesh.points, [("tetra", mesh.tets)]))
    comm.tompi4py().Barrier()


def synthetic_case(case: str, work: Path, comm=PETSc.COMM_WORLD, noise_pct: float = 0.5,
                   seed: int = 0):
    """(experiment on the captured mesh, true rest mesh, captured mesh, clean and noisy
    recordings, true E)."""
    size, cells, *_ = CASES[case]
    E_true = CASES[case][4]
    rest = box_mesh(list(size), list(cells))
    write_mesh(work / f"{case}_rest.vtu", rest, comm)
    exp_true = load_experiment_text(work / f"{case}_true.toml",
                                    experiment_text(case, f"{case}_rest.vtu", E_true), comm)
    model = build_model(exp_true, comm, mesh=rest)
    solver = StaticSolver(model, load_steps=2)
    u = solver.solve().displacement
    x_local = model.dmesh.points + model.dmesh.to_local(u)
    solver.destroy()
    captured = comm.tompi4py().bcast(model.dmesh.gather(x_local), root=0)
    captured = dataclasses.replace(rest, points=captured)
    write_mesh(work / f"{case}_captured.vtu", captured, comm)
    exp = load_experiment_text(work / f"{case}.toml",
                               experiment_text(case, f"{case}_captured.vtu", E_true), comm)
    # markers: the nodes of the boundary faces away from the support, every other one
    far = np.flatnonzero(np.isin(np.arange(len(rest.points)), np.unique(rest.tets)))
    free = far[np.linalg.norm(rest.points[far] - rest.points[far].min(axis=0), axis=1) > 0.03]
    nodes = free[::max(1, len(free) // 8)][:8]
    names = [f"m{i}" for i in range(len(nodes))]
    times = np.arange(0.0, 0.15 + 1e-12, 0.005)
    template = Recording(reference=rest.points[nodes], names=names, times=times,
                         positions=np.zeros((len(times), len(nodes), 3)))
    fm = build_forward(exp_true, ["material.youngs_modulus"], template, times, comm,
                       mesh=rest)
    clean = fm.simulate(np.array([E_true]))
    fm.destroy()
    peak = float(np.abs(clean - clean[:1]).max())
    rng = np.random.default_rng(seed)
    noisy = clean + rng.normal(0.0, noise_pct / 100 * peak, clean.shape)
    rec = dict(reference=captured.points[nodes], names=names, times=times)
    return (exp, rest, captured, Recording(positions=clean, **rec),
            Recording(positions=noisy, noise={"position_std": noise_pct / 100 * peak}, **rec),
            E_true)


def load_experiment_text(path: Path, text: str, comm=PETSc.COMM_WORLD):
    """The experiment of ``text``, written to ``path`` on the first rank of ``comm`` and read on
    every rank once it is there (every rank writing the same file raced: a rank read it while
    another had just truncated it, "mesh is missing", and the other ranks then waited in the
    next collective call for good)."""
    if comm.getRank() == 0:
        path.write_text(text)
    comm.tompi4py().Barrier()
    return load_experiment(path)


def run(case: str, comm=PETSc.COMM_WORLD, say=None):
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(comm.tompi4py().bcast(tmp, root=0))
        exp, rest, captured, clean, noisy, E_true = synthetic_case(case, tmp, comm)
        rs = compute_rest_shape(exp, comm, captured=captured)
        out["rest_rel_error"] = float(np.linalg.norm(rs.points - rest.points)
                                      / np.linalg.norm(rest.points))
        out["sag"] = float(np.abs(captured.points - rest.points).max())
        from petsoft.experiment import with_parameters
        start = with_parameters(exp, {"material.youngs_modulus": 0.6 * E_true})
        naive = run_calibration(start, noisy, comm=comm)
        split = calibrate_rest_shape(start, noisy, comm=comm, say=say)
        out["E_naive_rel_error"] = float(naive.values[0] / E_true - 1)
        out["E_split_rel_error"] = float(split.values[0] / E_true - 1)
        out["rounds"] = len(split.rounds)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=["cantilever", "block", "both"], default="both")
    args, _ = parser.parse_known_args()
    cases = ["cantilever", "block"] if args.case == "both" else [args.case]
    rank0 = PETSc.COMM_WORLD.rank == 0
    rows = [(c, run(c)) for c in cases]
    if rank0:
        print(f"{'case':<11} {'sag (m)':>9} {'rest rel err':>13} {'E err captured-as-rest':>23} "
              f"{'E err split':>12} {'rounds':>7}")
        for c, r in rows:
            print(f"{c:<11} {r['sag']:9.4f} {r['rest_rel_error']:13.2e} "
                  f"{100 * r['E_naive_rel_error']:22.2f}% {100 * r['E_split_rel_error']:11.3f}% "
                  f"{r['rounds']:7d}")


if __name__ == "__main__":
    main()
