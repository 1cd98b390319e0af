"""The `petsoft` console command: parses petsoft's own arguments, hands the rest to PETSc.

PETSc options (single dash, e.g. ``-ksp_type cg -pc_type gamg``) go after the experiment file;
petsoft's own options use two dashes and may stand anywhere. PETSc is initialised with those
options before any module that imports it, so the command line always wins over defaults.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

from petsoft.calibration.methods import METHOD_ALIASES, METHODS
from petsoft.dependencies import require
from petsoft.errors import PetsoftError
from petsoft.version import __version__

#: ``diagnose --one-rank-dofs``'s default, said in its help without importing PETSc here
#: (tests/test_api.py ties it to :data:`petsoft.diagnosis.placement.ONE_RANK_DOFS`).
ONE_RANK_DOFS_DEFAULT = 100_000
#: ``diagnose --budget``'s default (s), said without importing PETSc here (tests/test_diagnose.py
#: ties it to :data:`petsoft.diagnosis.budget.DEFAULT_BUDGET`).
BUDGET_DEFAULT = 900.0
#: The user's reference of the experiment, recording and report formats (installed with petsoft).
FORMATS = Path(__file__).resolve().parents[1] / "formats.md"

_PETSC_OPTION = re.compile(r"^-[A-Za-z][A-Za-z0-9_]+")
_FLAGS_WITHOUT_VALUE = {"--restart", "--spd", "--quiet", "--help", "--version",
                        "--spelled-out"}
# `modes -n K` (also -n=K, -nK): the one single-dash option of petsoft's own. The PETSc pattern
# above needs two characters after the dash, so "-n" alone would otherwise pass as the value of a
# preceding PETSc option.
_OUR_SHORT_OPTION = re.compile(r"^-n(=?\d+)?$")


def split_arguments(argv: list[str]) -> tuple[list[str], list[str]]:
    """Split argv into petsoft's arguments and PETSc options (in their order)."""
    ours, petsc, i = [], [], 0
    in_petsc = False
    while i < len(argv):
        tok = argv[i]
        if tok.startswith("--") or _OUR_SHORT_OPTION.match(tok):
            ours.append(tok)
            takes_value = tok == "-n" or (tok.startswith("--") and "=" not in tok
                                          and tok not in _FLAGS_WITHOUT_VALUE)
            if (takes_value and in_petsc
                    and i + 1 < len(argv) and not argv[i + 1].startswith("-")):
                ours.append(argv[i + 1])
                i += 1
        elif _PETSC_OPTION.match(tok):
            in_petsc = True
            petsc.append(tok)
        elif in_petsc:
            petsc.append(tok)           # the value of the preceding PETSc option
        else:
            ours.append(tok)
        i += 1
    return ours, petsc


class _VersionAction(argparse.Action):
    """``petsoft --version``: petsoft's version and the PETSc it runs on."""

    def __call__(self, parser, namespace, values, option_string=None):
        try:
            require(("petsc4py",), "petsoft --version")
        except PetsoftError as exc:
            parser.exit(2, f"petsoft: error: {exc}\n")
        import petsc4py

        petsc4py.init([])
        from petsc4py import PETSc  # after init: the version query must not read argv

        petsc = ".".join(str(v) for v in PETSc.Sys.getVersion())
        print(f"petsoft {__version__} (PETSc {petsc}, petsc4py {petsc4py.__version__})")
        parser.exit()


def _spelled_out_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--spelled-out", action="store_true",
                        help="write the calibrated experiment with every value spelled out "
                             "(default: your own file with only the calibrated values and added "
                             "sections changed, comments kept)")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="petsoft",
        description="Simulate soft deformable objects with PETSc. PETSc options (e.g. "
                    "-ksp_type cg -pc_type gamg) go after the experiment file.")
    p.add_argument("--version", action=_VersionAction, nargs=0,
                   help="print the versions of petsoft, PETSc and petsc4py and exit")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    s = sub.add_parser("static", help="quasistatic equilibrium of an experiment",
                       description="Solve the quasistatic problem of EXPERIMENT.toml; writes "
                                   "displacement.xdmf/.h5 and summary.json.")
    s.add_argument("experiment", help=f"experiment file (TOML; the keys: {FORMATS})")
    _static_options(s)
    _add_simulate_parser(sub)
    _add_modes_parser(sub)
    _add_damping_parser(sub)
    _add_calibrate_parser(sub)
    _add_diagnose_parser(sub)
    _add_recording_parsers(sub)
    d = sub.add_parser("demo", help="run the embedded example (no input needed)",
                       description="The embedded example: (static) solve a neo-Hookean "
                                   "cantilever under gravity and an end load; (diagnose) "
                                   "synthesise a recording of a bar with an effect its model "
                                   "lacks, and let `petsoft diagnose` find it. Writes results, "
                                   "plots and the diagnosis report to --out.")
    d.add_argument("--out", default="petsoft-demo", help="output directory (default %(default)s)")
    d.add_argument("--part", choices=("all", "static", "diagnose"), default="all",
                   help="which part to run (default %(default)s)")
    d.add_argument("--method", choices=("snes", "tao"), default="snes")
    d.add_argument("--load-steps", type=int, default=4)
    return p


def _add_simulate_parser(sub) -> None:
    s = sub.add_parser(
        "simulate", help="elastodynamics of an experiment over [time]",
        description="Integrate M q'' = f_el(q) + f_d(v) + f_ext(t) over [time]; writes "
                    "trajectory.xdmf/.h5, probes.h5 (a recording), energies.csv, summary.json.")
    s.add_argument("experiment", help="experiment file (TOML) with a [time] section")
    s.add_argument("--out", help="output directory (default: [output] directory)")
    s.add_argument("--integrator", help="override [time] integrator "
                   "(be, si, midpoint, trapezoidal, explicit, ...)")
    s.add_argument("--solver", choices=("snes", "tao", "local-global"), default="snes",
                   help="Newton on the step equations, or (be) minimise the incremental "
                        "potential with TAO, or (be, mass-spring models) the local/global "
                        "iteration of Liu et al. 2013 (options -lg_rtol, -lg_max_it, "
                        "-lg_anderson, -lg_ksp_type...)")
    s.add_argument("--explicit-scheme", choices=("verlet", "euler"), default="verlet",
                   help="explicit integrator: velocity Verlet or symplectic Euler")
    s.add_argument("--recording", help="recording (HDF5) whose /inputs drive `series` supports")
    s.add_argument("--restart", action="store_true",
                   help="continue from the latest checkpoint in the output directory")
    s.add_argument("--alpha-backend", choices=("petsoft", "ts"), default="petsoft",
                   help="generalized-alpha: petsoft's step (second order) or PETSc TS alpha2 "
                        "(first order for r < 1 in PETSc 3.18, see petsoft/dynamics/README.md)")
    s.add_argument("--spd", action="store_true",
                   help="mass-spring models: clamped (positive semi-definite) spring and contact "
                        "Hessians in the Jacobians")


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, not {value}")
    return value


def _budget(text: str) -> float | None:
    """``diagnose --budget``: seconds > 0, or 0 for none (None)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not (value >= 0.0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a number of seconds >= 0 (0: no budget), "
                                         f"not {text}")
    return None if value == 0.0 else value


def _count(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, not {value}")
    return value


def _add_modes_parser(sub) -> None:
    m = sub.add_parser(
        "modes", help="natural frequencies and mode shapes of an experiment",
        description="Solve K x = omega^2 M x (stiffness at the unloaded reference state, "
                    "consistent mass, the experiment's supports; loads are ignored) with SLEPc "
                    "for the lowest modes; writes summary.json (frequencies_hz) and modes.xdmf/.h5 "
                    "(one frame per mode, time = mode number, M-normalised shapes). Eigensolver "
                    "options: -eps_type, -eps_tol, -eps_ncv, -eps_target (in (rad/s)^2), "
                    "-st_pc_factor_mat_solver_type ...")
    m.add_argument("experiment", help=f"experiment file (TOML; the keys: {FORMATS})")
    m.add_argument("-n", "--num-modes", type=_positive_int, default=6, dest="num_modes",
                   metavar="K", help="number of modes (default %(default)s)")
    m.add_argument("--out", help="output directory (default: [output] directory)")


def _radii(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"not a comma-separated list of numbers: {text!r}") from None
    if not values or any(not 0.0 <= r <= 1.0 for r in values):
        raise argparse.ArgumentTypeError(f"radii must lie in [0, 1], not {text!r}")
    return values


def _add_damping_parser(sub) -> None:
    d = sub.add_parser(
        "damping", help="artificial damping of the integrators (analytic and measured)",
        description="Artificial damping ratio d/w = -2 ln(rho)/(tau w) of BE/SI, generalized "
                    "alpha, midpoint/trapezoidal and the explicit schemes against tau*w: analytic "
                    "(amplification matrices) and measured (petsoft's integrators on undamped "
                    "oscillators). With an experiment, also per mode of its body at its [time] "
                    "step. Writes damping.png, damping.md, CSV tables and summary.json.")
    d.add_argument("experiment", nargs="?", help="experiment file (TOML) with a [time] step")
    d.add_argument("--out", help="output directory (default: [output] directory, or "
                                 "petsoft-damping without an experiment)")
    d.add_argument("--modes", type=_positive_int, default=6, metavar="K",
                   help="lowest modes of the body (default %(default)s)")
    d.add_argument("--radii", type=_radii, default=(0.0, 0.25, 0.5, 0.75, 1.0),
                   help="generalized-alpha spectral radii (default 0,0.25,0.5,0.75,1)")
    d.add_argument("--steps", type=_positive_int, default=16, metavar="N",
                   help="steps per integrator run on each mode (default %(default)s)")
    d.add_argument("--amplitude", type=float, default=1e-3, metavar="A",
                   help="initial max displacement / body size of each mode run (default "
                        "%(default)s; smaller for nonlinear materials approaches the linear "
                        "values, but stalls the midpoint rule's Newton on round-off)")


def _add_recording_parsers(sub) -> None:
    i = sub.add_parser(
        "import", help="convert a CSV or C3D marker file into a recording (HDF5)",
        description="Read marker trajectories from CSV (time, <name>_x, <name>_y, <name>_z, ...; "
                    "empty or NaN cells = not seen) or C3D (POINT data; residual < 0 = not seen) "
                    "and write a petsoft recording. Reference positions: the first frame in "
                    "which every marker is seen, or --rest-frame.")
    i.add_argument("file", help="the file to import (.csv or .c3d)")
    i.add_argument("--out", required=True, help="recording to write (HDF5)")
    i.add_argument("--format", choices=("csv", "c3d"), help="default: from the extension")
    i.add_argument("--units", choices=("m", "cm", "mm"),
                   help="length unit of the file (CSV default m; C3D default POINT:UNITS)")
    i.add_argument("--scale", type=float, help="factor to metres instead of --units")
    i.add_argument("--rest-frame", type=int, help="frame giving the reference positions")
    i.add_argument("--position-std", type=float,
                   help="measurement noise (m) to write into /noise, when known")
    y = sub.add_parser(
        "synth", help="a synthetic recording from a simulation (with truth.json beside it)",
        description="Simulate EXPERIMENT.toml on a K-times refined mesh with step/K (no inverse "
                    "crime), observe N markers on surface nodes of the original mesh at the "
                    "original step's times, add Gaussian noise and drop a fraction of samples; "
                    "writes the recording, truth.json beside it and summary.json.")
    y.add_argument("experiment", help="experiment file (TOML) with a [time] section")
    y.add_argument("--out", required=True, help="recording to write (HDF5)")
    y.add_argument("--noise", type=float, default=0.0, metavar="STD",
                   help="Gaussian position noise, m (default 0)")
    y.add_argument("--markers", type=_positive_int, default=8, metavar="N",
                   help="number of random surface-node markers (default %(default)s)")
    y.add_argument("--markers-file", help="marker reference positions instead: CSV or text "
                                          "with x y z per line (m)")
    y.add_argument("--dropout", type=float, default=0.0, metavar="P",
                   help="fraction of samples dropped (NaN), 0 <= P < 1")
    y.add_argument("--refine", type=_positive_int, default=1, metavar="K",
                   help="simulate on a K-times refined mesh with step/K (default 1)")
    y.add_argument("--integrator", help="override [time] integrator for the simulation")
    y.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def _add_calibrate_parser(sub) -> None:
    c = sub.add_parser(
        "calibrate", help="fit the [calibrate] parameters of an experiment to a recording",
        description="Minimise the misfit between simulated and recorded marker positions over "
                    "the parameters of the experiment's [calibrate] table (bounds there, start "
                    "values from the experiment). Prints progress per iteration and a result "
                    "table with Gauss-Newton standard deviations; writes calibrated.toml, "
                    "summary.json, trajectories.png and residuals.png. TAO options take the "
                    "prefix cal_ (e.g. -cal_tao_gatol 1e-10), the forward Newton fm_ and the "
                    "gradient solves fm_grad_.")
    c.add_argument("experiment", help="experiment file (TOML) with [time] and [calibrate]")
    c.add_argument("recording", nargs="?",
                   help=f"recording (HDF5; the layout: {FORMATS}, section 2); not with --modes")
    c.add_argument("--modes", metavar="FILE",
                   help="fit the [calibrate] material parameters to natural frequencies "
                        "instead of trajectories: a text/CSV file of frequency_hz [, std_hz] "
                        "per line (ascending), JSON {\"frequencies_hz\": [...], \"std_hz\": "
                        "[...], \"markers\": {name: [x, y, z]}, \"mode_shapes\": [[[ux, uy, "
                        "uz] per marker] per mode]} (with shapes, modes are paired by MAC), or a "
                        "recording (HDF5): its frequencies, std and shapes at the markers are "
                        "estimated from the trajectories")
    c.add_argument("--method", default="gauss-newton",
                   choices=(*METHODS, *METHOD_ALIASES),
                   help="optimizer (default %(default)s; gd is also spelled gradient-descent)")
    c.add_argument("--gradient", default="adjoint", choices=("adjoint", "sensitivity", "fd"),
                   help="gradients by discrete adjoint, forward sensitivities or finite "
                        "differences (Jacobians always by sensitivities unless fd)")
    c.add_argument("--integrator", choices=("be", "si", "alpha"),
                   help="override [time] integrator for the forward model")
    c.add_argument("--multistart", type=int, default=0, metavar="K",
                   help="also K random starts in the bounds, run on groups of ranks")
    c.add_argument("--seed", type=int, default=0, help="seed of the random starts")
    c.add_argument("--noise", type=float, help="position noise std (m) when the recording "
                                                "has no /noise")
    c.add_argument("--regularization", type=float, default=0.0, metavar="LAMBDA",
                   help="Tikhonov weight on the scaled parameters' distance from the start")
    c.add_argument("--out", help="output directory (default: [output] directory)")
    c.add_argument("--check-mesh", action="store_true",
                   help="after the fit, calibrate again on the mesh refined once (box cells "
                        "doubled, a mesh file split 1->8) and warn when a parameter moves by "
                        "more than its standard deviation")
    c.add_argument("--misfit", choices=("l2", "spectral"), default="l2",
                   help="spectral: fit the markers' power spectra first (a phase-robust misfit "
                        "with a wider basin, for starts off by a period), then polish with l2")
    c.add_argument("--rest-shape", action="store_true",
                   help="the mesh is the captured equilibrium, not the rest shape: fit the "
                        "parameters with the rest shape solved for each trial (writes rest.vtu)")
    _spelled_out_option(c)
    r = sub.add_parser(
        "rest-shape", help="the rest mesh whose equilibrium is the experiment's (captured) mesh",
        description="Inverse statics: find rest positions X such that the experiment's mesh is "
                    "the static equilibrium under its gravity, materials and fixed supports; "
                    "writes the rest mesh. SNES options take the prefix rest_shape_.")
    r.add_argument("experiment", help="experiment file (TOML) whose mesh is the captured shape")
    r.add_argument("--out", default="rest.vtu", help="rest mesh file (default %(default)s)")
    r.add_argument("--load-steps", type=int, default=1,
                   help="gravity increments of the continuation (default %(default)s)")


def _add_diagnose_parser(sub) -> None:
    c = sub.add_parser(
        "diagnose", help="calibrate, test the residual against the noise, add missing physics",
        description="Calibrate the experiment's [calibrate] parameters on the first --fraction "
                    "of the recording, test whether the residual is noise (chi-square + "
                    "whiteness), and if not rank the candidate physics by a score test, add the "
                    "best, re-calibrate and keep it when the likelihood ratio is significant and "
                    "the held-out rms improves (repeat). Before blaming physics (and first, on a "
                    "mesh file) the step is halved and the mesh refined (a box's cells doubled, "
                    "a mesh file split 1->8); the report says which refinement matters and "
                    "recommends a mesh. Writes report.json, report.md, figures, "
                    "diagnosed.toml (the calibrated extended experiment) and summary.json.")
    c.add_argument("experiment", help="experiment file (TOML) with [time] and [calibrate]")
    c.add_argument("recording", help=f"recording (HDF5; the layout: {FORMATS}, section 2)")
    c.add_argument("--out", help="output directory (default: [output] directory)")
    _spelled_out_option(c)
    c.add_argument("--fraction", type=float, default=0.7,
                   help="share of the record's span used to identify parameters; the rest is "
                        "held out for prediction (default %(default)s)")
    c.add_argument("--alpha", type=float, default=0.01,
                   help="significance level of all tests (default %(default)s)")
    c.add_argument("--max-additions", type=_positive_int, default=3,
                   help="at most this many physics terms are added (default %(default)s)")
    c.add_argument("--method", default="gauss-newton",
                   choices=(*METHODS, *METHOD_ALIASES),
                   help="optimizer of every calibration (default %(default)s; gd is also spelled "
                        "gradient-descent)")
    c.add_argument("--integrator", choices=("be", "si", "alpha"),
                   help="override [time] integrator for the forward model")
    c.add_argument("--noise", type=float, help="position noise std (m) when the recording "
                                                "has no /noise (default: estimated from it)")
    c.add_argument("--no-numerics", action="store_true",
                   help="skip the step/mesh refinement check")
    c.add_argument("--budget", type=_budget, metavar="SECONDS", default=BUDGET_DEFAULT,
                   help="wall seconds after which no new piece of work starts (a round of "
                        "candidates, a candidate's fit, a sphere search, a numerics check) and "
                        "a candidate fit under way stops at its next iteration; the report is "
                        "then written from the model reached and says what was left out; 0: "
                        f"no budget (default {BUDGET_DEFAULT:g})")
    c.add_argument("--one-rank-dofs", type=_count, metavar="N",
                   help="under mpiexec, a model of at most N unknowns runs on one rank (the "
                        "others wait, or run independent fits side by side): faster, since one "
                        f"rank solves up to {ONE_RANK_DOFS_DEFAULT} directly where several "
                        "solve iteratively; 0 spreads every model over all the ranks (default "
                        f"{ONE_RANK_DOFS_DEFAULT})")
    c.add_argument("--reduced-trials", action="store_true",
                   help="score the trials of an added mass's sphere search (centre and "
                        "radius) by a reduced-order model of the fitted model instead of a full "
                        "run each; each poll's best that would move the sphere is run on the "
                        "full model, which decides, and the reduced model's error there is "
                        "reported (full trials once it exceeds 0.2x the noise). Off by default")


def _static_options(s) -> None:
    s.add_argument("--out", help="output directory (default: [output] directory)")
    s.add_argument("--method", choices=("snes", "tao"), default="snes",
                   help="Newton on the residual (snes) or energy minimisation (tao)")
    s.add_argument("--load-steps", type=int, default=1, help="equal load increments (>= 1)")
    s.add_argument("--spd", action="store_true",
                   help="project element tangents to positive semi-definite")


#: Integrators that need SLEPc (the explicit step limit, ERE's matrix functions, IMEX's modes).
_SLEPC_INTEGRATORS = ("explicit", "ere", "imex")


def needed_modules(args: argparse.Namespace) -> tuple[str, ...]:
    """The Debian-packaged modules a parsed command needs (:mod:`petsoft.dependencies`)."""
    needs = ["petsc4py", "mpi4py"]
    if args.command not in ("damping", "rest-shape"):
        needs.append("h5py")          # recordings, XDMF output, checkpoints
    if (args.command in ("modes", "damping")
            or (args.command == "calibrate" and args.modes is not None)
            or getattr(args, "integrator", None) in _SLEPC_INTEGRATORS):
        needs.append("slepc4py")
    return tuple(needs)


def _rank0() -> bool:
    """Rank 0 of an MPI launch, told by the launcher's environment (before MPI is loaded)."""
    for key in ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK"):
        if key in os.environ:
            return os.environ[key] == "0"
    return True


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``petsoft`` command."""
    argv = sys.argv[1:] if argv is None else argv
    ours, petsc_args = split_arguments(argv)
    args = _parser().parse_args(ours)
    if getattr(args, "load_steps", 1) < 1:
        _parser().error("--load-steps must be >= 1")
    try:
        # before any work: a missing h5py used to fail only when the solved results were written
        require(needed_modules(args), f"petsoft {args.command}")
    except PetsoftError as exc:
        if _rank0():
            print(f"petsoft: error: {exc}", file=sys.stderr, flush=True)
        return 2
    import petsc4py

    petsc4py.init(["petsoft", *petsc_args])
    from petsc4py import PETSc


    try:
        from petsoft.cli import commands

        status = commands.run(args)
        _warn_unused_options(PETSc.COMM_WORLD)
        return status
    except PetsoftError as exc:
        if PETSc.COMM_WORLD.rank == 0:
            print(f"petsoft: error: {exc}", file=sys.stderr, flush=True)
        return 2
    except KeyboardInterrupt:
        return 130


def _warn_unused_options(comm) -> None:
    """PETSc's ``-options_left`` at the end of a run, as a warning (collective)."""
    from petsoft.solvers.options import unused_options

    unused = unused_options(comm)
    if unused and comm.rank == 0:
        print(f"petsoft: warning: PETSc option{'s' if len(unused) > 1 else ''} never used "
              f"(misspelled, or for a solver this command does not run): {', '.join(unused)}",
              file=sys.stderr, flush=True)


if __name__ == "__main__":  # python -m petsoft.cli.main
    raise SystemExit(main())
