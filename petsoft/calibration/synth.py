"""`petsoft synth`: a synthetic recording from a simulation, with its ground truth beside it.

To avoid the "inverse crime" (fitting data made by the very discretisation that fits it), the
data are simulated on a refined mesh with a smaller step: ``--refine K`` divides the mesh size
and the time step by K. Box meshes get K times the cells along each axis; file meshes are refined
by uniform 1 -> 8 tetrahedron subdivision, which halves the mesh size, so for them K must be a
power of two (log2 K subdivisions), regions and boundary facet groups carried over. The markers
are nodes of the *original* mesh's surface (or given), hence also nodes of the refined mesh, and
are sampled at the original step's times. Noise and dropout come from a seeded generator.

The ground truth (the experiment's parameter values, noise, seed, refinement, integrator and step
actually used) goes to ``truth.json`` beside the recording, which no calibration reads.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.atomic import write_text
from petsoft.dynamics.simulate import Simulation
from petsoft.errors import PetsoftError
from petsoft.experiment import experiment_from_dict, get_parameter, load_experiment, parameter_names
from petsoft.io.recording import write_recording
from petsoft.io.summary import write_summary
from petsoft.mesh.refine import refine_mesh
from petsoft.mesh.serial import Mesh
from petsoft.mesh.topology import exterior_faces
from petsoft.physics.model import build_model, load_mesh


class SynthError(PetsoftError):
    """Bad options of `petsoft synth` (noise, dropout, markers, refinement)."""


def surface_nodes(mesh: Mesh) -> np.ndarray:
    """Sorted node numbers on the exterior surface of a tet mesh."""
    faces, _ = exterior_faces(mesh.tets)
    return np.unique(faces)


def _read_markers_file(path: Path) -> np.ndarray:
    if not path.is_file():
        raise SynthError(f"{path}: markers file not found")
    text = path.read_text().replace(",", " ")
    try:
        rows = [[float(v) for v in line.split()] for line in text.splitlines()
                if line.strip() and not line.lstrip().startswith("#")]
    except ValueError as exc:
        raise SynthError(f"{path}: not numbers ({exc}); expected x y z (m) per line") from None
    bad = [i for i, r in enumerate(rows) if len(r) != 3]
    if not rows or bad:
        raise SynthError(f"{path}: line {bad[0] + 1 if bad else 1}: expected 3 numbers x y z "
                         "(m) per line")
    return np.array(rows)


@dataclass(frozen=True)
class SynthOptions:
    """How :func:`synth` turns a simulation into a recording (the ``petsoft synth`` options).

    Parameters
    ----------
    out : Path
        The recording to write (HDF5); ``truth.json`` and ``summary.json`` go beside it.
    noise : float
        Standard deviation (m) of the Gaussian position noise, >= 0.
    markers : int
        Number of random surface-node markers (ignored when ``markers_file`` is given).
    markers_file : Path, optional
        Marker reference positions instead: a CSV or text file of x y z (m) per line.
    dropout : float
        Fraction of marker samples dropped (NaN, "not seen"), in [0, 1).
    refine : int
        Divide the mesh size and the time step by this (box meshes: cells x K; file meshes:
        1 -> 8 subdivision, K a power of two).
    integrator : str, optional
        Override ``[time] integrator`` for the simulation.
    seed : int
        Seed of the marker choice, the noise and the dropout.
    """

    out: Path
    noise: float = 0.0
    markers: int = 8
    markers_file: Path | None = None
    dropout: float = 0.0
    refine: int = 1
    integrator: str | None = None
    seed: int = 0

    def __post_init__(self):
        object.__setattr__(self, "out", Path(self.out))
        if self.markers_file is not None:
            object.__setattr__(self, "markers_file", Path(self.markers_file))
        if not (math.isfinite(self.noise) and self.noise >= 0):
            raise SynthError(f"--noise = {self.noise}: the noise standard deviation (m) must "
                             "be >= 0")
        if not (0.0 <= self.dropout < 1.0):
            raise SynthError(f"--dropout = {self.dropout}: the fraction of dropped samples must "
                             "be in [0, 1)")


@dataclass(frozen=True)
class SynthResult:
    """What :func:`synth` wrote: the recording, its ground truth and the marker count."""

    recording: Path
    truth: Path
    markers: int
    frames: int


def run_synth(args) -> int:
    """`petsoft synth EXPERIMENT.toml --out RECORDING.h5 ...` (all ranks call)."""
    options = SynthOptions(out=args.out, noise=args.noise, markers=args.markers,
                           markers_file=args.markers_file, dropout=args.dropout,
                           refine=args.refine, integrator=args.integrator, seed=args.seed)
    synth(load_experiment(args.experiment), options)
    return 0


def synth(experiment, options: SynthOptions, *, say=None) -> SynthResult:
    """Simulate ``experiment`` refined and record its markers with noise (all ranks call).

    Parameters
    ----------
    experiment : Experiment
        The truth, with ``[time]``.
    options : SynthOptions
    say : callable(str), optional
        Progress lines (rank 0); default: print.

    Returns
    -------
    SynthResult
    """
    from petsoft.calibration.observation import time_interpolation

    t0 = time.perf_counter()
    comm = PETSc.COMM_WORLD
    rank0 = comm.rank == 0

    def tell(line):
        if rank0:
            (say or _print)(line)

    exp = experiment
    if exp.time is None:
        raise SynthError(f"{exp.source}: [time] is missing: synth needs end and step")
    K = int(options.refine)
    mesh0 = load_mesh(exp)                     # every rank: marker choice must agree
    if options.markers_file:
        markers = _read_markers_file(options.markers_file)
        node_ids = None
    else:
        nodes = surface_nodes(mesh0)
        if options.markers > len(nodes):
            raise SynthError(f"--markers {options.markers}: the mesh has only {len(nodes)} surface "
                             "nodes")
        rng_pick = np.random.default_rng([options.seed, 1])
        node_ids = np.sort(rng_pick.choice(nodes, size=options.markers, replace=False))
        markers = mesh0.points[node_ids]
    names = [f"m{i:02d}" for i in range(len(markers))]
    data = exp.to_dict()
    step = exp.time.step / K
    data["time"]["step"] = step
    if options.integrator:
        data["time"]["integrator"] = options.integrator
    data["output"]["probes"] = markers.tolist()
    data["output"]["every"] = 1
    data["output"]["checkpoint_every"] = 0
    mesh = None
    if exp.mesh.box is not None:
        data["mesh"]["box"]["cells"] = [K * c for c in exp.mesh.box.cells]
    elif K > 1:
        levels = int(round(math.log2(K)))
        if 2 ** levels != K:
            raise SynthError(f"--refine {K}: a file mesh is refined by 1->8 subdivision, which "
                             "halves its size; use a power of two (2, 4, 8)")
        mesh = refine_mesh(mesh0, levels)
    sim_exp = experiment_from_dict(data, source=exp.source, base_dir=exp.base_dir, path=exp.path)
    model = build_model(sim_exp, comm, mesh=mesh)
    tell(f"petsoft synth: {len(markers)} markers; simulating on "
         f"{len(model.dmesh.mesh.tets)} tets (refine {K}, original {len(mesh0.tets)}) with "
         f"step {step:g} s")
    sim = Simulation(model, sim_exp, monitor=tell)
    result = sim.run()
    integrator = sim.name
    sim.destroy()
    summary = {}
    if rank0:
        t_sim = np.array(result.probe_times)
        u_sim = np.array(result.probe_displacements)              # (S, M, 3)
        n_frames = exp.time.num_steps
        frame_times = np.arange(n_frames + 1) * exp.time.step
        frame_times = frame_times[frame_times <= t_sim[-1] * (1 + 1e-12)]
        idx, w = time_interpolation(frame_times, t_sim, source="synth")
        clean = markers[None] + np.einsum("kj,kjmc->kmc", w, u_sim[idx])
        rng = np.random.default_rng([options.seed, 2])
        noisy = clean + (rng.normal(0.0, options.noise, clean.shape) if options.noise > 0 else 0.0)
        dropped = rng.random(clean.shape[:2]) < options.dropout
        noisy[dropped] = np.nan
        out = options.out
        cmd = (f"petsoft synth {exp.path or exp.source} --noise {options.noise:g} --dropout "
               f"{options.dropout:g} --refine {K} --seed {options.seed}")
        write_recording(out, markers, frame_times, noisy, names=names,
                        attrs={"source": cmd}, noise={"position_std": float(options.noise)})
        truth = {
            "experiment": str(exp.path or exp.source),
            "parameters": {p: get_parameter(exp, p) for p in parameter_names(exp)},
            "noise": {"position_std": float(options.noise), "dropout": float(options.dropout),
                      "dropped_samples": int(dropped.sum())},
            "seed": int(options.seed), "refine": K, "integrator": integrator,
            "step": step, "recording_step": exp.time.step,
            "tets": {"simulated": int(len(model.dmesh.mesh.tets)),
                     "original": int(len(mesh0.tets))},
            "markers": {"names": names, "reference": markers.tolist(),
                        "nodes": None if node_ids is None else node_ids.tolist()},
        }
        truth_path = out.parent / "truth.json"
        write_text(truth_path, json.dumps(truth, indent=2) + "\n")
        summary = {"recording": str(out), "truth": str(truth_path), "markers": len(markers),
                   "frames": int(len(frame_times)), "dropped_samples": int(dropped.sum()),
                   "max_displacement_markers": float(np.abs(clean - markers).max())}
        tell(f"wrote {out} ({len(frame_times)} frames, {len(markers)} markers, noise "
            f"{options.noise:g} m, {int(dropped.sum())} samples dropped) and {truth_path}")
    stats = {"newton_iterations": result.newton_iterations,
             "linear_iterations": result.linear_iterations, "retries": result.retries}
    write_summary(options.out.parent, "synth", summary, stats, time.perf_counter() - t0, comm)
    return SynthResult(recording=options.out, truth=options.out.parent / "truth.json",
                       markers=len(markers), frames=int(comm.tompi4py().bcast(
                           len(frame_times) if rank0 else None, root=0)))


def _print(line: str) -> None:
    print(line, flush=True)
