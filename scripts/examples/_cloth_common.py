"""Shared pieces of the cloth demos: the cloth mesh, the experiment, one run per method, checks.

A square cloth of n x n nodes (triangulated grid: structural, shear and bending springs) held
horizontally above a sphere at the origin and released under gravity. Every method runs the same
experiment from the same start; each run writes ``<out>/<method>/trajectory.xdmf`` (+ .h5),
``energies.csv`` and ``summary.json`` through ``petsoft simulate``'s :class:`Simulation`.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

#: methods the demos know: integrator name and solver ("be-lg": backward Euler, local/global)
METHODS = {"be": ("be", "snes"), "si": ("si", "snes"), "midpoint": ("midpoint", "snes"),
           "ere": ("ere", "snes"), "alpha": ("alpha", "snes"), "be-lg": ("be", "local-global")}


def cloth_mesh(n: int, size: float, height: float):
    """Points (n*n, 3) and triangles of a square cloth centred above the origin at ``height``."""
    xs = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(xs, xs, indexing="xy")
    points = np.column_stack([X.ravel(), Y.ravel(), np.full(n * n, height)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    # alternate the diagonals so the cloth has no preferred shear direction
    flip = ((np.arange(n - 1)[:, None] + np.arange(n - 1)[None, :]) % 2).astype(bool)
    t1 = np.where(flip[..., None], np.stack([a, b, d], -1), np.stack([a, b, c], -1))
    t2 = np.where(flip[..., None], np.stack([a, d, c], -1), np.stack([b, d, c], -1))
    tris = np.concatenate([t1.reshape(-1, 3), t2.reshape(-1, 3)])
    return points, tris


def write_cloth(out: Path, n: int, size: float, height: float, comm) -> Path:
    """The cloth mesh as ``out/cloth.msh`` (written on rank 0; all ranks return its path)."""
    from petsoft.mesh.springs import write_spring_mesh

    path = out / "cloth.msh"
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        pts, tris = cloth_mesh(n, size, height)
        write_spring_mesh(path, pts, triangles=tris)
    comm.tompi4py().barrier()
    return path


def cloth_experiment(mesh: Path, *, stiffness: float, bending: float, mass: float,
                     radius: float, contact: float | None, step: float, end: float,
                     integrator: str, out: Path, damping: float = 0.0, every: int = 1):
    """The experiment (a dict through the public format): cloth, sphere, gravity, [time]."""
    from petsoft.experiment import experiment_from_dict

    collider = {"kind": "sphere", "center": [0.0, 0.0, 0.0], "radius": radius}
    if contact is not None:
        collider["stiffness"] = contact
    return experiment_from_dict({
        "mesh": {"file": str(mesh)},
        "springs": {"stiffness": stiffness, "bending": bending, "damping": 0.0,
                    "node_mass": mass},
        "collider": [collider],
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": damping},
        "time": {"end": end, "step": step, "integrator": integrator},
        "output": {"directory": str(out), "every": every},
    }, source="<cloth demo>")


def add_arguments(p, out: str) -> None:
    """The command-line arguments both cloth demos take."""
    p.add_argument("--out", default=out)
    p.add_argument("--methods", nargs="+", default=["be", "be-lg", "si", "midpoint", "ere"],
                   help=f"any of {', '.join(METHODS)}")
    p.add_argument("--nodes", type=int, default=15, help="nodes per side of the cloth")
    p.add_argument("--step", type=float, default=0.0025)
    p.add_argument("--end", type=float, default=1.0)
    p.add_argument("--stiffness", type=float, default=200.0, help="spring stiffness (N/m)")
    p.add_argument("--bending", type=float, default=2.0, help="bending springs (N/m)")
    p.add_argument("--contact-frequency", type=float, default=750.0,
                   help="sqrt(k_c / m) of a node on the sphere (rad/s): the penalty stiffness "
                        "k_c per node scales with the node mass, so the penetration does not "
                        "depend on --nodes")
    p.add_argument("--tolerance", type=float, default=2e-2,
                   help="largest penetration allowed (m)")
    p.add_argument("--spd", action="store_true",
                   help="clamped (PSD) spring and contact Hessians in Newton's Jacobians")
    p.add_argument("--quick", action="store_true", help="a small cloth, a few steps")


def run_method(method: str, exp, out: Path, stiffness_scale=None, spd: bool = False):
    """Run one method; returns (result, seconds spent in integrator steps, steps, model).

    ``stiffness_scale(model) -> (S,) factors`` multiplies the springs' stiffness before the
    system is built (mixed stiffness). ``spd``: clamped (PSD) spring and contact Hessians in
    the Newton Jacobians (``petsoft simulate --spd``).
    """
    from petsoft.dynamics.mass_spring import build_mass_spring_model
    from petsoft.dynamics.simulate import Simulation

    integrator, solver = METHODS[method]
    model = build_mass_spring_model(exp)
    if stiffness_scale is not None:
        model.stiffness = model.stiffness * stiffness_scale(model)
    sim = Simulation(model, exp, integrator=integrator, solver=solver, out=out, spd=spd)
    spent = [0.0, 0]
    step = sim.integrator.step

    def timed(*args, **kwargs):
        t = time.perf_counter()
        try:
            return step(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - t
            spent[1] += 1

    sim.integrator.step = timed   # cost per step, without output and bookkeeping
    try:
        result = sim.run()
    finally:
        sim.destroy()
    return result, spent[0], spent[1], model


def frames(out: Path):
    """Times and (N, 3) displacements of every frame of ``out/trajectory.xdmf`` (rank 0)."""
    from petsoft.io.xdmf import read_series

    series = read_series(out / "trajectory.xdmf")
    return series.times, [p["displacement"] for p in series.point_data]


def max_penetration(points, displacements, radius: float) -> float:
    """Largest depth of a node inside the sphere (at the origin) over all frames."""
    return max(float(np.maximum(0.0, radius - np.linalg.norm(points + u, axis=1)).max())
               for u in displacements)


def energy_growth(energies: np.ndarray) -> float:
    """Largest step-to-step rise of kinetic + elastic + gravitational energy, relative to the
    energy scale (the largest of |kinetic|, |elastic|, |gravitational| over the run)."""
    total = energies[:, 1] + energies[:, 2] + energies[:, 3]
    scale = np.abs(energies[:, 1:4]).max()
    return float(np.diff(total).max(initial=-np.inf) / scale)


def plot_energies(curves: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(curves)
    fig, axes = plt.subplots(1, len(methods), figsize=(3.2 * len(methods), 3.2), sharey=True,
                             squeeze=False)
    for ax, method in zip(axes[0], methods, strict=True):
        e = curves[method]
        t = e[:, 0]
        ax.plot(t, e[:, 1], label="kinetic")
        ax.plot(t, e[:, 2], label="elastic + contact")
        ax.plot(t, e[:, 3] - e[0, 3], label="gravitational")
        ax.plot(t, e[:, 1] + e[:, 2] + e[:, 3] - e[0, 3], "k", lw=2, label="total")
        ax.set_title(method)
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("energy (J, gravity from the start)")
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_frames(points, tris, times, displacements, radius: float, path: Path, title: str,
                count: int = 4, colour=None) -> None:
    """``count`` snapshots of the cloth (and the sphere) in one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    picks = np.unique(np.linspace(0, len(times) - 1, count).round().astype(int))
    fig = plt.figure(figsize=(3.2 * len(picks), 3.4))
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
    for k, i in enumerate(picks):
        ax = fig.add_subplot(1, len(picks), k + 1, projection="3d")
        x = points + displacements[i]
        ax.plot_wireframe(radius * np.cos(u) * np.sin(v), radius * np.sin(u) * np.sin(v),
                          radius * np.cos(v), color="0.6", lw=0.4)
        surf = ax.plot_trisurf(x[:, 0], x[:, 1], x[:, 2], triangles=tris, linewidth=0.1,
                               edgecolor="k", alpha=0.9,
                               cmap="coolwarm" if colour is not None else None)
        if colour is not None:
            surf.set_array(colour)
        lim = np.abs(points[:, :2]).max()
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_zlim(-lim, lim)
        ax.set_title(f"t = {times[i]:.2f} s", fontsize=9)
        ax.set_axis_off()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def compare(args, title: str, stiffness_scale=None, colour=None) -> int:
    """Run ``args.methods`` on the cloth of ``args``; print the table, write the figures.

    Returns the exit status: 1 if a penetration or energy check failed (rank 0).
    """
    import numpy as np
    from petsc4py import PETSc

    from petsoft.errors import PetsoftError
    from petsoft.solvers.options import set_default_option

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
                               mass=node_mass, radius=radius,
                               contact=args.contact_frequency**2 * node_mass,
                               step=args.step, end=args.end, integrator=METHODS[method][0],
                               out=out / method)
        try:
            result, spent, steps, _ = run_method(method, exp, out / method,
                                                 stiffness_scale=stiffness_scale, spd=args.spd)
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
    print(f"\n{title}: {args.nodes}x{args.nodes} nodes, step {args.step:g} s, "
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
                    f"{method}: {title}", colour=colour)
    if "be" in cost and "be-lg" in cost:
        diff = float(np.abs(finals["be"] - finals["be-lg"]).max())
        print(f"\nbackward Euler cost per step: Newton {cost['be']:.2f} ms, local/global "
              f"{cost['be-lg']:.2f} ms (Newton / local-global = "
              f"{cost['be'] / cost['be-lg']:.2f}); final states differ by {diff:.2e} m (rank "
              "0's nodes; step halvings on failure make the two step sequences differ)")
    plot_energies(curves, out / "energy.png",
                  f"{title}: energy profile per method (step {args.step:g} s)")
    print(f"wrote {out / 'energy.png'}, {out}/frames-<method>.png and "
          f"{out}/<method>/trajectory.xdmf")
    return 0 if ok else 1


