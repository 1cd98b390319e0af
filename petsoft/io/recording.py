"""The recording format (formats.md section 2): marker trajectories in HDF5, written and read.

Any simulation's probes become a recording, so a simulation can serve as data.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from petsoft.atomic import atomic_path
from petsoft.errors import ExperimentError, PetsoftError

FORMAT = "petsoft-recording"
#: The first bytes of an HDF5 file.
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
VERSION = 1


class RecordingError(PetsoftError):
    """A recording file (HDF5) is malformed: missing datasets, wrong shapes, bad values."""


class RecordingWarning(UserWarning):
    """Something in a recording is legal but suspicious (a marker that is never seen)."""


@dataclass
class Recording:
    """A measured (or synthetic) recording, formats.md section 2.

    Attributes
    ----------
    reference : ndarray (M, 3)
        Marker positions in the reference configuration (m).
    names : list of str
        One name per marker (``m0``, ``m1``, ... when the file has none).
    times : ndarray (K,)
        Strictly increasing frame times (s).
    positions : ndarray (K, M, 3) or None
        Measured positions; NaN where a marker was not seen in a frame.
    accelerations : ndarray (K, M, 3) or None
        Measured accelerations (accelerometers); NaN where missing.
    noise : dict of str to float
        ``position_std`` (m) and/or ``acceleration_std`` (m/s^2) when known.
    inputs : dict of str to (times (J,), values (J, 3))
        Measured inputs (a driven support, a load cell).
    attrs : dict
        Other root attributes (``source``, ...), kept as written.
    source : str
        The file it was read from (for messages); ``"<memory>"`` otherwise.
    """

    reference: np.ndarray
    names: list[str]
    times: np.ndarray
    positions: np.ndarray | None = None
    accelerations: np.ndarray | None = None
    noise: dict[str, float] = field(default_factory=dict)
    inputs: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)
    source: str = "<memory>"

    @property
    def num_markers(self) -> int:
        return int(len(self.reference))

    @property
    def num_frames(self) -> int:
        return int(len(self.times))

    def seen(self) -> np.ndarray:
        """(K, M) bool: whether each marker's position was measured in each frame."""
        if self.positions is None:
            return np.zeros((self.num_frames, self.num_markers), dtype=bool)
        return np.isfinite(self.positions).all(axis=2)

    def write(self, path: Path) -> Path:
        """Write this recording to ``path`` atomically (see :func:`write_recording`)."""
        return write_recording(path, self.reference, self.times, self.positions,
                               names=self.names, attrs=self.attrs,
                               accelerations=self.accelerations, noise=self.noise,
                               inputs=self.inputs)


def write_recording(path: Path, reference: np.ndarray, times: np.ndarray,
                    positions: np.ndarray | None, names: list[str] | None = None,
                    attrs: dict | None = None, *, accelerations: np.ndarray | None = None,
                    noise: dict | None = None,
                    inputs: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> Path:
    """Write a recording atomically (a temporary file renamed into place).

    A crash while writing leaves only a hidden ``.<name>.*.tmp`` file (:mod:`petsoft.atomic`),
    never a file under the final name that looks complete.

    Parameters
    ----------
    path : Path
        Destination (parent directories are created).
    reference : (M, 3)
        Marker positions in the reference configuration.
    times : (K,)
        Strictly increasing times (s).
    positions : (K, M, 3) or None
        Measured (or simulated) positions; NaN where not seen. None when only accelerations
        were measured.
    names : list of M str, optional
    attrs : dict, optional
        Extra root attributes (e.g. ``source``).
    accelerations : (K, M, 3), optional
    noise : dict, optional
        ``position_std`` / ``acceleration_std`` written as attributes of ``/noise``.
    inputs : dict of name to (times (J,), values (J, 3)), optional

    Raises
    ------
    ValueError
        For inconsistent shapes or times that do not increase strictly (a programming error of
        the caller: user files are checked by :func:`read_recording`).
    """
    import h5py

    path = Path(path)
    times = np.asarray(times, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    shape = (len(times), len(reference), 3)
    if positions is None and accelerations is None:
        raise ValueError("a recording needs positions or accelerations")
    frames = {}
    for key, arr in (("position", positions), ("acceleration", accelerations)):
        if arr is None:
            continue
        arr = np.asarray(arr, dtype=np.float64)
        if arr.shape != shape:
            raise ValueError(f"{key}s {arr.shape} do not match {len(times)} times and "
                             f"{len(reference)} markers")
        frames[key] = arr
    if len(times) > 1 and np.any(np.diff(times) <= 0):
        raise ValueError("recording times must be strictly increasing")
    if names is not None and len(names) != len(reference):
        raise ValueError(f"{len(names)} names for {len(reference)} markers")
    path.parent.mkdir(parents=True, exist_ok=True)
    # readable by everyone whatever the umask: a recording is shared data
    with atomic_path(path, mode=0o644) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["version"] = VERSION
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
        f["markers/reference"] = reference
        if names is not None:
            f.create_dataset("markers/name", data=np.array(list(names), dtype=object),
                             dtype=h5py.string_dtype("utf-8"))
        f["frames/time"] = times
        for key, arr in frames.items():
            f[f"frames/{key}"] = arr
        if noise:
            g = f.create_group("noise")
            for k, v in noise.items():
                g.attrs[k] = float(v)
        for name, (t_in, v_in) in (inputs or {}).items():
            f[f"inputs/{name}/time"] = np.asarray(t_in, dtype=np.float64)
            f[f"inputs/{name}/value"] = np.asarray(v_in, dtype=np.float64).reshape(-1, 3)
    return path


NOISE_KEYS = ("position_std", "acceleration_std")


def _increasing(times: np.ndarray, where: str) -> None:
    bad = np.flatnonzero(~(np.diff(times) > 0))
    if len(bad):
        i = int(bad[0])
        raise RecordingError(
            f"{where} must increase strictly; it does not at index {i + 1} "
            f"(t[{i}] = {times[i]:.17g} s, t[{i + 1}] = {times[i + 1]:.17g} s)")


def _frames(f, key: str, shape: tuple, where: str, names: list[str]) -> np.ndarray | None:
    if key not in f:
        return None
    arr = np.asarray(f[key][()], dtype=np.float64)
    if arr.shape != shape:
        raise RecordingError(f"{where}/{key} has shape {arr.shape}; expected {shape} "
                             "(frames, markers, 3) to match /frames/time and /markers/reference")
    inf = np.argwhere(np.isinf(arr))
    if len(inf):
        k, m, c = (int(i) for i in inf[0])
        raise RecordingError(f"{where}/{key}: infinite value at frame {k} (t index), marker "
                             f"{names[m]!r} (index {m}), component {'xyz'[c]}; only NaN is "
                             "allowed, meaning 'not seen'")
    partial = np.isnan(arr).any(axis=2) & ~np.isnan(arr).all(axis=2)
    if partial.any():
        k, m = (int(i) for i in np.argwhere(partial)[0])
        raise RecordingError(f"{where}/{key}: frame {k}, marker {names[m]!r} (index {m}) is "
                             f"NaN in some components only ({arr[k, m].tolist()}); a marker "
                             "is seen (3 finite values) or not seen (3 NaN)")
    return arr


def marker_file_kind(path: Path) -> str | None:
    """"CSV" or "C3D" when ``path`` is a marker file :mod:`petsoft.io.importers` converts
    (given where a recording is expected), else None. By content, with the extension for CSV:
    a C3D file's second byte is 0x50 (its parameter block key), and an HDF5 file starts with
    its signature (which no CSV or C3D file does)."""
    with open(path, "rb") as f:
        head = f.read(512)
    if head.startswith(HDF5_SIGNATURE):
        return None
    if len(head) >= 2 and head[1] == 0x50 and path.suffix.lower() == ".c3d":
        return "C3D"
    if path.suffix.lower() in (".csv", ".txt", ".tsv"):
        return "CSV"
    if len(head) >= 2 and head[1] == 0x50 and head[0] > 0:
        return "C3D"        # the header's first byte points to the parameter block (>= 1)
    try:
        lines = head.decode("utf-8").splitlines()
    except UnicodeDecodeError:
        return None
    return "CSV" if lines and "," in lines[0] else None


def read_recording(path: Path) -> Recording:
    """Read and validate a recording (formats.md section 2).

    NaN in ``/frames/position`` or ``/frames/acceleration`` means "not seen" and is kept (the
    misfit leaves those samples out); NaN anywhere else, and infinity anywhere, is an error. A
    marker that is never seen in any frame is legal (it may be seen in accelerations, or the
    recording may be cut from a longer one) but it gives no information, so it raises a
    :class:`RecordingWarning` naming it.

    Raises
    ------
    RecordingError
        Naming the file, the dataset and (where it applies) the frame, marker and value: missing
        file, wrong ``format``/``version`` attributes, missing datasets, wrong shapes, non-finite
        reference positions or times, times that do not increase strictly, infinite values,
        duplicate or empty marker names, negative or non-finite noise levels, bad inputs.
    """
    path = Path(path)
    where = str(path)
    with _open_recording(path, where) as f:
        _check_header(f, where)
        reference = _reference(f, where)
        names = _marker_names(f, where, len(reference))
        times = _frame_times(f, where)
        shape = (len(times), len(reference), 3)
        positions = _frames(f, "frames/position", shape, where, names)
        accelerations = _frames(f, "frames/acceleration", shape, where, names)
        noise = _noise_levels(f, where)
        inputs = _inputs(f, where)
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()
                 if k not in ("format", "version")}
    rec = Recording(reference, names, times, positions, accelerations, noise, inputs, attrs,
                    source=where)
    _warn_never_seen(where, names, positions, accelerations)
    return rec


def _open_recording(path: Path, where: str):
    """The recording's HDF5 file, open for reading; an error that says what the file is when
    it is missing, a marker file or not HDF5."""
    import h5py

    if not path.is_file():
        raise RecordingError(f"{where}: recording not found")
    kind = marker_file_kind(path)
    if kind is not None:
        raise RecordingError(
            f"{where}: this is a {kind} marker file, not a recording (HDF5): convert it first "
            f"with `petsoft import {where} --out recording.h5` (add --units mm if its lengths "
            "are in mm; formats.md section 2)")
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise RecordingError(f"{where}: not an HDF5 file ({exc}); a recording is the HDF5 file "
                             "of formats.md section 2 (`petsoft import` makes one from CSV or "
                             "C3D marker files)") from None


def _check_header(f, where: str) -> None:
    """The root attributes (format, version) and the datasets every recording has."""
    fmt = f.attrs.get("format")
    fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
    if fmt != FORMAT:
        raise RecordingError(f"{where}: root attribute format = {fmt!r}; a recording has "
                             f"format = {FORMAT!r}")
    version = f.attrs.get("version")
    if version is None or int(version) != VERSION:
        raise RecordingError(f"{where}: version = {version!r} is not supported; this "
                             f"petsoft reads version {VERSION}")
    for key in ("markers/reference", "frames/time"):
        if key not in f:
            raise RecordingError(f"{where}: /{key} is missing (formats.md section 2)")
    if "frames/position" not in f and "frames/acceleration" not in f:
        raise RecordingError(f"{where}: neither /frames/position nor /frames/acceleration "
                             "is present; a recording needs at least one")


def _reference(f, where: str) -> np.ndarray:
    """(M, 3) the markers' reference positions, finite, M >= 1."""
    reference = np.asarray(f["markers/reference"][()], dtype=np.float64)
    if reference.ndim != 2 or reference.shape[1] != 3 or len(reference) == 0:
        raise RecordingError(f"{where}: /markers/reference has shape {reference.shape}; "
                             "expected (M, 3) with M >= 1")
    bad = np.argwhere(~np.isfinite(reference))
    if len(bad):
        m = int(bad[0][0])
        raise RecordingError(f"{where}: /markers/reference of marker {m} is "
                             f"{reference[m].tolist()}; reference positions must be finite")
    return reference


def _marker_names(f, where: str, nmark: int) -> list[str]:
    """The markers' names (``/markers/name``: one each, not empty, unique; absent: m0, m1,
    ...)."""
    if "markers/name" not in f:
        return [f"m{i}" for i in range(nmark)]
    raw = f["markers/name"][()]
    names = [n.decode() if isinstance(n, bytes) else str(n) for n in np.ravel(raw)]
    if np.ndim(raw) != 1 or len(names) != nmark:
        raise RecordingError(f"{where}: /markers/name has shape {np.shape(raw)}; "
                             f"expected ({nmark},), one name per marker")
    empty = [i for i, n in enumerate(names) if not n.strip()]
    if empty:
        raise RecordingError(f"{where}: /markers/name[{empty[0]}] is empty; every "
                             "marker needs a name")
    seen: dict[str, int] = {}
    for i, n in enumerate(names):
        if n in seen:
            raise RecordingError(f"{where}: /markers/name: {n!r} names markers "
                                 f"{seen[n]} and {i}; names must be unique")
        seen[n] = i
    return names


def _frame_times(f, where: str) -> np.ndarray:
    """(K,) the frames' times, finite and strictly increasing, K >= 1."""
    times = np.asarray(f["frames/time"][()], dtype=np.float64)
    if times.ndim != 1 or len(times) == 0:
        raise RecordingError(f"{where}: /frames/time has shape {times.shape}; expected "
                             "(K,) with K >= 1")
    nonfinite = np.flatnonzero(~np.isfinite(times))
    if len(nonfinite):
        i = int(nonfinite[0])
        raise RecordingError(f"{where}: /frames/time[{i}] = {times[i]}; times must be "
                             "finite")
    _increasing(times, f"{where}: /frames/time")
    return times


def _noise_levels(f, where: str) -> dict[str, float]:
    """``/noise``'s attributes (:data:`NOISE_KEYS`, finite and >= 0)."""
    noise = {}
    if "noise" not in f:
        return noise
    unknown = sorted(set(f["noise"].attrs) - set(NOISE_KEYS))
    if unknown:
        raise RecordingError(f"{where}: /noise has unknown attribute(s) "
                             f"{', '.join(unknown)}; valid: {', '.join(NOISE_KEYS)}")
    for k in NOISE_KEYS:
        if k in f["noise"].attrs:
            v = float(f["noise"].attrs[k])
            if not (np.isfinite(v) and v >= 0):
                raise RecordingError(f"{where}: /noise {k} = {v}; must be finite and "
                                     ">= 0")
            noise[k] = v
    return noise


def _inputs(f, where: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (times, (J, 3) values) of each measured input series (``/inputs/<name>``),
    complete and in increasing time."""
    inputs = {}
    for name in sorted(f.get("inputs", {})):
        g = f["inputs"][name]
        w = f"{where}: /inputs/{name}"
        if "time" not in g or "value" not in g:
            raise RecordingError(f"{w} needs datasets time (J,) and value (J, 3)")
        t_in = np.asarray(g["time"][()], dtype=np.float64)
        v_in = np.asarray(g["value"][()], dtype=np.float64)
        if t_in.ndim != 1 or v_in.shape != (len(t_in), 3):
            raise RecordingError(f"{w}: time {t_in.shape} and value {v_in.shape}; "
                                 "expected (J,) and (J, 3)")
        if not (np.isfinite(t_in).all() and np.isfinite(v_in).all()):
            raise RecordingError(f"{w}: NaN or infinite entries (an input must be "
                                 "complete)")
        _increasing(t_in, f"{w}/time")
        inputs[name] = (t_in, v_in)
    return inputs


def _warn_never_seen(where: str, names: list[str], positions, accelerations) -> None:
    """A :class:`RecordingWarning` naming the markers seen in no frame (NaN throughout)."""
    seen_any = np.zeros(len(names), dtype=bool)
    for arr in (positions, accelerations):
        if arr is not None:
            seen_any |= np.isfinite(arr).all(axis=2).any(axis=0)
    never = np.flatnonzero(~seen_any)
    if len(never):
        listed = ", ".join(f"{names[m]!r} (index {m})" for m in never[:5])
        more = f" and {len(never) - 5} more" if len(never) > 5 else ""
        # (stack: this function, read_recording, its caller)
        warnings.warn(f"{where}: marker(s) {listed}{more} are never seen (NaN in every frame); "
                      "they add nothing to a fit", RecordingWarning, stacklevel=3)


class SeriesComponent:
    """One component of a measured input series, usable where an Expression of t is expected.

    Linear interpolation in time; asking for a time outside the recorded span is an error (no
    silent extrapolation of a measurement).
    """

    variables = frozenset({"t"})

    def __init__(self, times: np.ndarray, values: np.ndarray, source: str):
        self.times, self.values, self.source = times, values, source

    def evaluate_at(self, points, t: float | None = None) -> np.ndarray:
        t = 0.0 if t is None else float(t)
        span = self.times[-1] - self.times[0]
        if t < self.times[0] - 1e-12 * max(span, 1.0) or t > self.times[-1] + 1e-12 * max(
                span, 1.0):
            raise ExperimentError(
                f"{self.source}: t = {t:g} s is outside the recorded input "
                f"[{self.times[0]:g}, {self.times[-1]:g}] s; shorten [time] end or record longer")
        return np.full(len(points), np.interp(t, self.times, self.values))


def on_rank0_for_all(read, comm=None):
    """``read()`` called on rank 0 of ``comm`` (an mpi4py or PETSc communicator; default the
    world) and its result given to every rank. Collective. A user error
    (:class:`~petsoft.errors.PetsoftError`) raised by ``read`` is raised on every rank."""
    from mpi4py import MPI
    from petsc4py import PETSc

    mpi = MPI.COMM_WORLD if comm is None else (
        comm.tompi4py() if isinstance(comm, PETSc.Comm) else comm)
    result, error = None, None
    if mpi.rank == 0:
        try:
            result = read()
        except PetsoftError as exc:
            error = exc
    error = mpi.bcast(error, root=0)
    if error is not None:
        raise error
    return mpi.bcast(result, root=0)


def read_recording_on_all_ranks(path: str | os.PathLike, comm=None) -> Recording:
    """The recording at ``path``, read once on rank 0 and given to every rank of ``comm``
    (an mpi4py or PETSc communicator; default the world). Collective.

    A user error in the file (:class:`~petsoft.errors.PetsoftError`) is raised on every rank.
    """
    return on_rank0_for_all(lambda: read_recording(Path(path)), comm)


def read_input_series(recording: Recording | Path, name: str) -> tuple[SeriesComponent, ...]:
    """The measured input ``/inputs/<name>`` of a recording as three time series (x, y, z).

    ``recording`` is a :class:`Recording` already read (its ``inputs``) or the path of one;
    ``name`` may be given as ``"inputs/shaker"`` or ``"shaker"``.

    Raises
    ------
    ExperimentError
        Naming the file and dataset: missing file, unknown input (listing the available ones),
        wrong shapes, non-finite values or times that do not strictly increase.
    """
    key = name.split("/", 1)[1] if name.startswith("inputs/") else name
    if isinstance(recording, Recording):
        path, available = recording.source, sorted(recording.inputs)
        found = recording.inputs.get(key)
    else:
        import h5py

        path = Path(recording)
        if not path.is_file():
            raise ExperimentError(f"{path}: recording not found (needed for the input {name!r})")
        with h5py.File(path, "r") as f:
            inputs = f.get("inputs")
            available = sorted(inputs.keys()) if inputs is not None else []
            found = ((inputs[key]["time"][()], inputs[key]["value"][()])
                     if key in available else None)
    if found is None:
        raise ExperimentError(f"{path}: no measured input {name!r}; the recording has "
                              f"{', '.join('inputs/' + a for a in available) or 'none'}")
    times = np.asarray(found[0], dtype=float)
    values = np.asarray(found[1], dtype=float)
    where = f"{path}: /inputs/{key}"
    if times.ndim != 1 or len(times) < 2:
        raise ExperimentError(f"{where}/time must be a 1-D array of at least 2 times, "
                              f"got shape {times.shape}")
    if values.shape != (len(times), 3):
        raise ExperimentError(f"{where}/value must have shape ({len(times)}, 3), got "
                              f"{values.shape}")
    if not (np.isfinite(times).all() and np.isfinite(values).all()):
        raise ExperimentError(f"{where}: NaN or infinite entries (a support input must be "
                              "complete)")
    bad = np.flatnonzero(np.diff(times) <= 0)
    if len(bad):
        raise ExperimentError(f"{where}/time must increase strictly; it does not after index "
                              f"{bad[0]} (t = {times[bad[0]]:g} s)")
    return tuple(SeriesComponent(times, values[:, c], f"{where} ({'xyz'[c]})") for c in range(3))
