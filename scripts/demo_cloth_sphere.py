"""Cloth dropped on a sphere (the lecture notes' example, 000): BE, SI, midpoint, ERE and BE by
local/global iteration from the same start, with an energy profile per method.

A 1 m square cloth (a triangulated grid of n x n nodes; structural, shear and bending springs;
0.2 kg) is released flat, 0.15 m above a sphere of radius 0.3 m, and falls on it under gravity.
Contact is the quadratic penalty of :mod:`petsoft.physics.colliders` (stiffness 1000 x the
spring stiffness per node by default). Every method runs the same experiment at the same step.

For each method the script prints the largest penetration of a node into the sphere over the
run (checked against the stated tolerance, ``--tolerance``), the largest step-to-step rise of the
total energy (kinetic + springs + contact + gravity: backward Euler and semi-implicit must never
gain energy), the iterations, and the cost per step of backward Euler by Newton (SNES, direct
solve) and by the local/global iteration of Liu et al. 2013 (:mod:`petsoft.dynamics.local_global`)
measured in the same run, with the largest difference between their trajectories.

Run::

    .venv/bin/python scripts/demo_cloth_sphere.py --out cloth-sphere
    mpiexec -n 2 .venv/bin/python scripts/demo_cloth_sphere.py --out cloth-sphere

Writes ``energy.png`` (energy profile per method), ``frames-<method>.png`` (four snapshots),
``<method>/trajectory.xdmf`` (ParaView: warp by vector ``displacement``), ``energies.csv`` and
``summary.json`` per method. Exit status 1 if a check fails.

Things to try:

* ``--methods be be-lg`` for the solver comparison only; ``--nodes 31`` for a finer cloth (the
  local/global advantage grows with the size: its factorization is reused);
* ``--step 0.002``: smaller steps, less numerical damping by BE and SI, fewer local/global
  iterations; ``--contact 1e4`` for a softer sphere (deeper penetration);
* local/global options: ``-lg_rtol 1e-6`` (looser), ``-lg_anderson 0`` (the plain iteration of
  Liu et al.: many more iterations), ``-lg_ksp_type cg -lg_pc_type gamg`` (iterative global
  solves instead of the Cholesky factorization);
* Newton options: ``-ksp_type preonly -pc_type cholesky -pc_factor_mat_solver_type mumps``
  (the default here), ``-snes_monitor``, ``-ksp_type cg -pc_type gamg``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import petsc4py

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="cloth-sphere")
    p.add_argument("--methods", nargs="+", default=["be", "be-lg", "si", "midpoint", "ere"])
    p.add_argument("--nodes", type=int, default=21, help="nodes per side of the cloth")
    p.add_argument("--step", type=float, default=0.01)
    p.add_argument("--end", type=float, default=1.0)
    p.add_argument("--stiffness", type=float, default=200.0, help="spring stiffness (N/m)")
    p.add_argument("--bending", type=float, default=2.0, help="bending springs (N/m)")
    p.add_argument("--contact", type=float, default=None,
                   help="penalty stiffness of the sphere (N/m; default 1000 x stiffness)")
    p.add_argument("--tolerance", type=float, default=2e-3,
                   help="largest penetration allowed (m)")
    p.add_argument("--quick", action="store_true", help="a small cloth, a few steps")
    args, petsc_args = p.parse_known_args(argv)
    petsc4py.init([sys.argv[0], *petsc_args])
    import numpy as np
    from petsc4py import PETSc

    from _cloth_common import (
        METHODS,
        cloth_experiment,
        cloth_mesh,
        energy_growth,
        frames,
        max_penetration,
        plot_energies,
        plot_frames,
        run_method,
        write_cloth,
    )
    from petsoft.errors import PetsoftError
    from petsoft.options import set_default_option

    if args.quick:
        args.nodes, args.end = 7, 0.3
    # Newton's linear solves: a direct Cholesky factorization like the local/global solver's,
    # so that the cost comparison is between the iterations, not between linear solvers
    for key, value in (("ksp_type", "preonly"), ("pc_type", "cholesky"),
                       ("pc_factor_mat_solver_type", "mumps")):
        set_default_option(key, value)
    comm = PETSc.COMM_WORLD
    rank0 = comm.rank == 0
    out = Path(args.out)
    size, height, radius, mass = 1.0, 0.45, 0.3, 0.2
    mesh = write_cloth(out, args.nodes, size, height, comm)
    points, tris = cloth_mesh(args.nodes, size, height)
    node_mass = mass / len(points)
    curves, rows, finals, ok = {}, [], {}, True
    for method in args.methods:
        if method not in METHODS:
            if rank0:
                print(f"{method}: unknown (valid: {', '.join(METHODS)})")
            continue
        exp = cloth_experiment(mesh, stiffness=args.stiffness, bending=args.bending,
                               mass=node_mass, radius=radius, contact=args.contact,
                               step=args.step, end=args.end, integrator=METHODS[method][0],
                               out=out / method)
        try:
            result, spent, steps, _ = run_method(method, exp, out / method)
        except PetsoftError as exc:     # report it and go on with the other methods
            rows.append((method, None))
            if rank0:
                print(f"{method}: failed: {exc}")
            continue
        curves[method] = result.energies
        finals[method] = result.q.getArray(readonly=True).copy()
        rows.append((method, (result, spent, steps)))
    if not rank0:
        return 0
    print(f"\ncloth {args.nodes}x{args.nodes} nodes on a sphere, step {args.step:g} s, "
          f"{comm.size} rank(s)")
    print(f"{'method':<10}{'max pen. (m)':>14}{'max dE/E':>11}{'its/step':>10}"
          f"{'retries':>8}{'ms/step':>9}  checks")
    cost = {}
    for method, data in rows:
        if data is None:
            print(f"{method:<10}{'failed':>14}")
            continue
        result, spent, steps = data
        times, disp = frames(out / method)
        pen = max_penetration(points, disp, radius)
        growth = energy_growth(result.energies)
        n_steps = len(result.energies) - 1
        cost[method] = 1e3 * spent / steps
        checks = [f"penetration {'ok' if pen <= args.tolerance else 'FAIL'}"]
        if method in ("be", "si", "be-lg"):
            # energy may only fall; a rise above round-off (1e-9 of the energy scale) fails
            checks.append(f"energy {'never grows' if growth <= 1e-9 else 'GROWS: FAIL'}")
        ok &= all("FAIL" not in c for c in checks)
        print(f"{method:<10}{pen:>14.3e}{growth:>11.1e}{result.newton_iterations / n_steps:>10.1f}"
              f"{result.retries:>8d}{cost[method]:>9.2f}  {', '.join(checks)}")
        plot_frames(points, tris, times, disp, radius, out / f"frames-{method}.png",
                    f"{method}: cloth on a sphere")
    if "be" in cost and "be-lg" in cost:
        diff = float(np.abs(finals["be"] - finals["be-lg"]).max())
        print(f"\nbackward Euler cost per step: Newton {cost['be']:.2f} ms, local/global "
              f"{cost['be-lg']:.2f} ms (ratio Newton / local-global {cost['be'] / cost['be-lg']:.2f})"
              f"; final states differ by {diff:.2e} m (rank 0's nodes)")
    plot_energies(curves, out / "energy.png",
                  f"cloth on a sphere: energy profile per method (step {args.step:g} s)")
    print(f"wrote {out / 'energy.png'}, {out}/frames-<method>.png and "
          f"{out}/<method>/trajectory.xdmf")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
