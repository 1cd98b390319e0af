"""Neo-Hookean tangent + internal force assembly throughput (tets/s): petsoft vs DOLFINx.

What is measured
----------------
One "assembly" is what a Newton step needs from the elastic term at a given displacement:
the tangent matrix K = d2W/du2 and the internal force g = dW/du of the neo-Hookean energy

    psi(F) = mu/2 (tr C - 3) - mu ln J + lam/2 (ln J)^2,   C = F^T F, J = det F,
    E = 1e6, nu = 0.45,

on P1 (linear) tetrahedra, 3 dofs per vertex, assembled into a preallocated, reused PETSc
matrix and vector, including the off-rank communication (MatAssembly, ghost accumulation).

* petsoft: ``assembler.begin(); elastic.add_gradient(u, g_local, assembler);
  assembler.finish(A); dmesh.add_to_global(g_local, g)`` (force and tangent in one element pass).
* DOLFINx (only when ``import dolfinx`` works; otherwise skipped, saying so): the same energy in
  UFL, residual and Jacobian by ``ufl.derivative`` twice, ``fem.petsc.assemble_matrix`` into the
  matrix from ``fem.petsc.create_matrix`` (zeroed, reused) + ``assemble()``, and
  ``fem.petsc.assemble_vector`` + reverse ghost update. The DOLFINx mesh is built from the SAME
  points and tetrahedra as petsoft's (``dolfinx.mesh.create_mesh`` on petsoft's ``box_mesh``;
  DOLFINx repartitions and renumbers it itself). Quadrature: one point (``--dolfinx-qdeg 1``),
  exact here because every integrand is constant on a P1 tet; FFCx compiles with the same flags
  as petsoft's kernels (``-O3 -fno-math-errno``), see ``--dolfinx-cflags``.

Both are evaluated at the same smooth displacement u = 0.02 (sin, cos products) + a small
stretch (|grad u| ~ 0.1, F != I, J > 0) on the unit cube split into n^3 hexahedra x 6 tets.

Timing: every repeat is bracketed by an MPI barrier; the time of a repeat is the max over ranks;
rates are total tets / time. The table reports the BEST of ``--repeat`` repeats (the machine is
shared and noisy; the median is printed in the details below the table). One-time setup (mesh
distribution, sparsity pattern, matrix creation, FFCx JIT compilation, a warm-up assembly) is
excluded from the rates and printed separately: the fastest of ``--setup-repeat`` set-ups, made
alternately by the two codes (the first set-up in a process also pays for the first touch of its
memory, slow on this virtual machine; the details print every set-up's rate).

Correctness (smallest size): ||K||_F of both, the action K x on a random x and the force g are
compared after mapping DOLFINx's dofs to petsoft's vertices by coordinates; the relative
differences should be ~1e-13 (round-off).

Run
---
    .venv/bin/python scripts/benchmarks/bench_assembly.py  # 1 rank, ~1e4, 1e5, 1e6 tets
    export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \\
           OMPI_MCA_rmaps_base_oversubscribe=1
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_assembly.py          # 2 ranks
    .venv/bin/python scripts/benchmarks/bench_assembly.py --quick  # tiny smoke run (~ seconds)

Things to try
-------------
* sizes and repeats: ``--sizes 1e4 3e5 --repeat 10`` (a size is a tet count, rounded to the
  nearest 6 n^3).
* without the peer: ``--no-dolfinx``.
* DOLFINx's default quadrature degree estimate (several identical points here) or JIT flags:
  ``--dolfinx-qdeg -1``, ``--dolfinx-cflags "-O2 -g0"`` (DOLFINx's default) or
  ``"-O3 -march=native"``; the JIT cache is ~/.cache/fenics.
* PETSc options go after the script's own arguments, e.g. ``-log_view`` (where the time goes:
  MatAssemblyEnd, VecScatter), ``-petscpartitioner_type parmetis`` (petsoft's partition).
* ``taskset -c 0`` to pin a serial run; on this 2-core shared machine 2-rank runs are noisy.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

import numpy as np

# PETSc must see its options (everything argparse does not know) before it is initialised.
_parser = argparse.ArgumentParser(
    description=__doc__.splitlines()[0],
    epilog="Unknown arguments are passed to PETSc (e.g. -log_view).")
_parser.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e5, 1e6],
                     help="target numbers of tetrahedra (default 1e4 1e5 1e6)")
_parser.add_argument("--repeat", type=int, default=5, help="timed repeats per size (default 5)")
_parser.add_argument("--setup-repeat", type=int, default=3,
                     help="set-ups per size and code, alternating (default 3): the table shows "
                          "the fastest, the details the first too")
_parser.add_argument("--quick", action="store_true",
                     help="smoke run: ~750 and ~6000 tets, 2 repeats")
_parser.add_argument("--no-dolfinx", action="store_true", help="time petsoft only")
_parser.add_argument("--dolfinx-qdeg", type=int, default=1,
                     help="DOLFINx quadrature degree (1 = one point, exact here; -1 = UFL's "
                          "estimate)")
_parser.add_argument("--dolfinx-cflags", default="-O3 -fno-math-errno",
                     help="FFCx JIT compiler flags (default: petsoft's kernel flags)")
ARGS, _petsc_args = _parser.parse_known_args()

import petsc4py  # noqa: E402

import petsoft  # noqa: E402, F401  before petsc4py.init: one BLAS thread (petsoft/__init__.py)

petsc4py.init([sys.argv[0]] + _petsc_args)
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from petsoft.fem.assembly import MatrixAssembler  # noqa: E402
from petsoft.fem.kernels.materials import lame_parameters  # noqa: E402
from petsoft.mesh.distributed import DistributedMesh  # noqa: E402
from petsoft.mesh.serial import box_mesh  # noqa: E402
from petsoft.physics.elastic import ElasticTerm  # noqa: E402

COMM = MPI.COMM_WORLD
RANK, NRANKS = COMM.rank, COMM.size
E_MOD, NU = 1e6, 0.45
MU, LAM = (float(v) for v in lame_parameters(E_MOD, NU))


def say(*args, **kwargs) -> None:
    """Print on rank 0 only."""
    if RANK == 0:
        print(*args, **kwargs, flush=True)


def displacement(x: np.ndarray) -> np.ndarray:
    """The smooth displacement field at points ``x`` of shape (3, n); returns (3, n)."""
    X, Y, Z = x[0], x[1], x[2]
    pi = np.pi
    return np.stack([
        0.02 * np.sin(pi * Y) * np.cos(pi * Z) + 0.05 * X,
        0.02 * np.sin(pi * Z) * np.cos(pi * X) - 0.02 * Y,
        0.02 * np.sin(pi * X) * np.cos(pi * Y) + 0.01 * Z,
    ])


def timed(fn, repeat: int) -> np.ndarray:
    """Wall times of ``repeat`` calls of ``fn``: barrier before each, max over ranks."""
    times = np.empty(repeat)
    for i in range(repeat):
        COMM.Barrier()
        t0 = time.perf_counter()
        fn()
        times[i] = COMM.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    return times


def setup_clock():
    """A stopwatch for collective set-up phases (barrier, then max over ranks)."""
    COMM.Barrier()
    t0 = time.perf_counter()

    def stop() -> float:
        return COMM.allreduce(time.perf_counter() - t0, op=MPI.MAX)

    return stop


# -- petsoft --------------------------------------------------------------------------------------
class PetsoftCase:
    """petsoft's elastic term on the box: set-up once, then ``assemble()`` repeatedly."""

    def __init__(self, mesh):
        self.setup = {}
        stop = setup_clock()
        self.dmesh = dmesh = DistributedMesh(mesh if RANK == 0 else None, PETSc.COMM_WORLD)
        self.setup["distribute"] = stop()

        stop = setup_clock()
        ne = len(dmesh.cells)
        self.elastic = ElasticTerm(dmesh, np.full(ne, "neohookean"), np.full(ne, E_MOD),
                                   np.full(ne, NU))
        self.assembler = MatrixAssembler(dmesh, self.elastic.connectivities())
        self.A = self.assembler.create_matrix()
        self.g = dmesh.create_global_vec()
        self.g_local = np.zeros(3 * dmesh.nvertices)
        self.u_local = np.ascontiguousarray(displacement(dmesh.points.T).T)
        self.setup["geometry+pattern+matrix"] = stop()

        stop = setup_clock()
        self.assemble()
        self.setup["first assembly"] = stop()

    def assemble(self) -> None:
        self.assembler.begin()
        self.g_local[:] = 0.0
        self.elastic.add_gradient(self.u_local, self.g_local, self.assembler)
        self.assembler.finish(self.A)
        self.g.zeroEntries()
        self.dmesh.add_to_global(self.g_local.reshape(-1, 3), self.g)

    def apply(self, x_file: np.ndarray):
        """(K x, g) gathered on rank 0 as (N, 3) arrays in the mesh's vertex numbering."""
        x = self.dmesh.from_file_field(x_file)
        y = self.A.createVecLeft()
        self.A.mult(x, y)
        return self.dmesh.gather_global(y), self.dmesh.gather_global(self.g)

    def destroy(self) -> None:
        self.A.destroy()
        self.g.destroy()


# -- DOLFINx --------------------------------------------------------------------------------------
def import_dolfinx():
    """(dolfinx modules, None) when DOLFINx imports, else (None, the reason)."""
    try:
        import dolfinx
        import dolfinx.fem.petsc
        import ufl
    except Exception as exc:  # ImportError, or a PETSc/MPI mismatch at import time
        return None, f"{type(exc).__name__}: {exc}"
    # FFCx installs a root log handler and the JIT's setuptools build logs every compiler
    # command at INFO through it: keep warnings and errors only.
    for handler in logging.getLogger().handlers:
        handler.addFilter(lambda record: record.levelno >= logging.WARNING)
    return (dolfinx, ufl), None


class DolfinxCase:
    """The same neo-Hookean residual and Jacobian in DOLFINx, on the same points and tets."""

    def __init__(self, mods, mesh, qdeg: int, cflags: list[str]):
        dolfinx, ufl = mods
        fem = dolfinx.fem
        self.fem = fem
        self.setup = {}
        stop = setup_clock()
        domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.tetrahedron, 1))
        if RANK == 0:
            cells, x = mesh.tets.astype(np.int64), mesh.points
        else:
            cells, x = np.zeros((0, 4), np.int64), np.zeros((0, 3))
        # Cell integrals only: no ghost cells needed.
        self.msh = dolfinx.mesh.create_mesh(COMM, cells, x, domain,
                                            ghost_mode=dolfinx.mesh.GhostMode.none)
        self.V = V = fem.VectorFunctionSpace(self.msh, ("Lagrange", 1))
        self.u = u = fem.Function(V)
        u.interpolate(displacement)
        self.setup["mesh+space"] = stop()

        v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
        F = ufl.Identity(3) + ufl.grad(u)
        J = ufl.det(F)
        mu = fem.Constant(self.msh, PETSc.ScalarType(MU))
        lam = fem.Constant(self.msh, PETSc.ScalarType(LAM))
        psi = mu / 2 * (ufl.tr(F.T * F) - 3) - mu * ufl.ln(J) + lam / 2 * ufl.ln(J) ** 2
        md = {} if qdeg < 0 else {"quadrature_degree": qdeg}
        residual = ufl.derivative(psi * ufl.dx(metadata=md), u, v)
        jacobian = ufl.derivative(residual, u, du)
        stop = setup_clock()
        jit = {"cffi_extra_compile_args": list(cflags)}
        self.L = fem.form(residual, form_compiler_params={}, jit_params=dict(jit))
        self.a = fem.form(jacobian, form_compiler_params={}, jit_params=dict(jit))
        self.setup["FFCx JIT (cached after 1st run)"] = stop()

        stop = setup_clock()
        self.A = fem.petsc.create_matrix(self.a)
        self.b = fem.petsc.create_vector(self.L)
        self.setup["pattern+matrix"] = stop()
        stop = setup_clock()
        self.assemble()
        self.setup["first assembly"] = stop()

    def assemble(self) -> None:
        fem = self.fem
        self.A.zeroEntries()
        fem.petsc.assemble_matrix(self.A, self.a)
        self.A.assemble()
        with self.b.localForm() as b_local:
            b_local.set(0.0)
        fem.petsc.assemble_vector(self.b, self.L)
        self.b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def apply(self, x_file: np.ndarray, points: np.ndarray):
        """(K x, g) gathered on rank 0 as (N, 3) arrays in petsoft's vertex numbering."""
        fem = self.fem
        # The file vertex of every local dof block (owned first, then ghosts), by coordinates.
        vert = match_points(points, self.V.tabulate_dof_coordinates())
        nown = self.V.dofmap.index_map.size_local
        x = fem.Function(self.V)
        x.x.array[:] = x_file[vert].ravel()
        y = self.A.createVecLeft()
        self.A.mult(x.vector, y)
        n = len(points)
        return (gather_owned(vert[:nown], y.getArray(readonly=True).reshape(-1, 3), n),
                gather_owned(vert[:nown], self.b.getArray(readonly=True).reshape(-1, 3), n))

    def destroy(self) -> None:
        self.A.destroy()
        self.b.destroy()


def match_points(ref: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Index into ``ref`` of each row of ``query`` with the same coordinates (vectorised)."""
    tol = 1e-9 * float(np.ptp(ref, axis=0).max())
    keys = np.round(np.concatenate([ref, query[:, :3]]) / tol).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    ref_of_key = np.full(inverse.max() + 1, -1, np.int64)
    ref_of_key[inverse[: len(ref)]] = np.arange(len(ref))
    found = ref_of_key[inverse[len(ref):]]
    if (found < 0).any() or np.abs(ref[found] - query[:, :3]).max() > 10 * tol:
        raise RuntimeError("DOLFINx dof coordinates do not match the mesh vertices")
    return found


def gather_owned(ids: np.ndarray, values: np.ndarray, n: int) -> np.ndarray | None:
    """Owned rows of every rank gathered on rank 0 into an (n, 3) array indexed by ``ids``."""
    parts = COMM.gather((ids, values.copy()), root=0)
    if RANK != 0:
        return None
    out = np.full((n, 3), np.nan)
    for i, v in parts:
        out[i] = v
    return out


def check(pets: PetsoftCase, dolf: DolfinxCase, mesh) -> None:
    """Print the relative differences between the two operators and forces."""
    x_file = np.random.default_rng(1).standard_normal((len(mesh.points), 3))
    norm = PETSc.NormType.FROBENIUS
    fro_p, fro_d = pets.A.norm(norm), dolf.A.norm(norm)
    yp, gp = pets.apply(x_file)
    yd, gd = dolf.apply(x_file, mesh.points)
    if RANK != 0:
        return
    rel = lambda a, b: float(np.linalg.norm(a - b) / np.linalg.norm(a))  # noqa: E731
    say(f"correctness on {len(mesh.tets)} tets (petsoft vs DOLFINx, relative differences):")
    say(f"  ||K||_F    {fro_p:.6e} vs {fro_d:.6e}: {abs(fro_p - fro_d) / fro_p:.1e}")
    say(f"  K x        (random x, dofs matched by vertex coordinates): {rel(yp, yd):.1e}")
    say(f"  force g    {np.linalg.norm(gp):.6e} vs {np.linalg.norm(gd):.6e}: {rel(gp, gd):.1e}")


# -- driver ---------------------------------------------------------------------------------------
def cells_per_axis(tets: float) -> int:
    return max(1, round((tets / 6.0) ** (1.0 / 3.0)))


def rate_text(r: float | None) -> str:
    return "skipped" if r is None else f"{r / 1e6:.3f} M"


def main() -> None:
    sizes = [750, 6000] if ARGS.quick else ARGS.sizes
    repeat = 2 if ARGS.quick else max(1, ARGS.repeat)
    mods, why_not = (None, "--no-dolfinx") if ARGS.no_dolfinx else import_dolfinx()
    cflags = ARGS.dolfinx_cflags.split()

    say(f"petsoft neo-Hookean tangent + internal force assembly, {NRANKS} MPI rank(s), "
        f"PETSc {'.'.join(map(str, PETSc.Sys.getVersion()))}, E={E_MOD:g} nu={NU}")
    if mods is None:
        say(f"DOLFINx: skipped ({why_not})")
    else:
        qtxt = "UFL estimate" if ARGS.dolfinx_qdeg < 0 else str(ARGS.dolfinx_qdeg)
        say(f"DOLFINx {mods[0].__version__}: same mesh (create_mesh from petsoft's box points/"
            f"tets), quadrature degree {qtxt}, JIT flags {' '.join(cflags)}")
    say(f"rates: best of {repeat} repeats, time = max over ranks; set-up excluded\n")

    rows, details = [], []
    for k, target in enumerate(sizes):
        n = cells_per_axis(target)
        mesh = box_mesh((1.0, 1.0, 1.0), (n, n, n)) if RANK == 0 else None
        ntets = 6 * n**3
        # Set-ups alternate between the codes, each thrown away but the last: the first touch
        # of memory new to this process is slow on a virtual machine (a page fault in the guest
        # and one in the host), which the first set-up in a process pays and a long-lived
        # process does not; the details show the first beside the fastest.
        setups_p, setups_d = [], []
        for i in range(max(1, ARGS.setup_repeat)):
            last = i == max(1, ARGS.setup_repeat) - 1
            pets = PetsoftCase(mesh)
            setups_p.append(pets.setup)
            if not last:
                pets.destroy()
                del pets
            if mods is not None:
                dolf = DolfinxCase(mods, mesh, ARGS.dolfinx_qdeg, cflags)
                setups_d.append(dolf.setup)
                if not last:
                    dolf.destroy()
                    del dolf
        t_p = timed(pets.assemble, repeat)
        dolf, t_d = (dolf, timed(dolf.assemble, repeat)) if mods is not None else (None, None)
        if mods is not None:
            if k == 0:
                check(pets, dolf, pets.dmesh.mesh)
                say("")
        r_p = ntets / t_p.min()
        r_d = None if t_d is None else ntets / t_d.min()
        # set-up rate: distribution, geometry, pattern and matrix (DOLFINx: mesh and space,
        # pattern and matrix; its JIT compilation excluded)
        total_p = [s["distribute"] + s["geometry+pattern+matrix"] for s in setups_p]
        total_d = [s["mesh+space"] + s["pattern+matrix"] for s in setups_d]
        s_p = ntets / min(total_p)
        s_d = None if dolf is None else ntets / min(total_d)
        rows.append((ntets, r_p, r_d, s_p, s_d))
        setup = ", ".join(f"{k} {v:.2f}" for k, v in setups_p[int(np.argmin(total_p))].items())
        line = (f"{ntets:>9} tets: petsoft median {ntets / np.median(t_p) / 1e6:.3f} M tets/s "
                f"(best {t_p.min():.4f} s); fastest set-up s: {setup}; set-up rates (first .. "
                f"last): {' '.join(rate_text(ntets / t) for t in total_p)} tets/s")
        if dolf is not None:
            setup = ", ".join(f"{k} {v:.2f}" for k, v in setups_d[int(np.argmin(total_d))].items())
            line += (f"\n{'':>15}DOLFINx median {ntets / np.median(t_d) / 1e6:.3f} M tets/s "
                     f"(best {t_d.min():.4f} s); fastest set-up s: {setup}; set-up rates (first "
                     f".. last): {' '.join(rate_text(ntets / t) for t in total_d)} tets/s")
            dolf.destroy()
        details.append(line)
        pets.destroy()
        del pets, dolf

    say(f"{'tets':>9} {'ranks':>5} {'petsoft tets/s':>15} {'DOLFINx tets/s':>15} "
        f"{'ratio':>6} {'set-up: petsoft':>16} {'DOLFINx':>9} {'ratio':>6}")
    for ntets, r_p, r_d, s_p, s_d in rows:
        ratio = "-" if r_d is None else f"{r_p / r_d:.2f}"
        sratio = "-" if s_d is None else f"{s_p / s_d:.2f}"
        say(f"{ntets:>9} {NRANKS:>5} {rate_text(r_p):>15} {rate_text(r_d):>15} {ratio:>6} "
            f"{rate_text(s_p):>16} {rate_text(s_d):>9} {sratio:>6}")
    say(f"(set-up: tets per second of distribution + geometry + pattern + matrix, the fastest of "
        f"{max(1, ARGS.setup_repeat)} alternating set-ups; DOLFINx: mesh + function space + "
        f"pattern + matrix, its JIT compilation excluded)")
    say("\ndetails (median rates, best times, one-time set-up excluded from the rates):")
    for line in details:
        say(line)


if __name__ == "__main__":
    main()
