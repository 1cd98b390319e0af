"""Cost of a trajectory frame: one file per frame against frames collected in batches.

What is measured
----------------
``XdmfWriter`` writing ``--frames`` frames (displacement and velocity, float64) of a box mesh
of about ``--dofs`` dofs, as ``petsoft simulate`` writes them every step, into a temporary
directory: ``flush_seconds = 0`` (every frame its own HDF5 file, the ``.xdmf`` extended per
frame) and ``flush_seconds = 1`` (the frames of each second in one file, what ``simulate``
uses). Each mode is timed ``--repeat`` times, alternating, in one process; the table gives the
best wall time per frame, the files written and the ratio from the same run. The series written
in batches is read back and compared with the frames given.

Run (seconds; never while another job runs)::

    .venv/bin/python scripts/benchmarks/bench_xdmf.py
    .venv/bin/python scripts/benchmarks/bench_xdmf.py --dofs 600 5000 50000 --frames 1000
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from petsoft.io.xdmf import XdmfWriter, read_series
from petsoft.mesh.serial import box_mesh


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dofs", type=float, nargs="+", default=[600, 5000, 50000])
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--repeat", type=int, default=3)
    return ap.parse_args(argv)


def bar_for(dofs: float):
    """A 10:1:1 box mesh with about ``dofs`` / 3 vertices."""
    m = max(1, round((dofs / 3 / 10) ** (1 / 3)) - 1)
    return box_mesh((1.0, 0.1, 0.1), (10 * m, m, m))


def write_series(directory: Path, mesh, frames: int, flush_seconds: float) -> float:
    """Seconds to write ``frames`` frames (the writer closed: every frame on disk)."""
    u = np.zeros_like(mesh.points)
    t0 = time.perf_counter()
    with XdmfWriter(directory / "t.xdmf", mesh.points, mesh.tets,
                    flush_seconds=flush_seconds) as out:
        for k in range(frames):
            u += 1e-4
            out.write(1e-3 * k, {"displacement": u, "velocity": u})
    return time.perf_counter() - t0


def main(argv=None) -> None:
    args = _args(argv)
    rows = []
    for target in args.dofs:
        mesh = bar_for(target)
        best = {0.0: np.inf, 1.0: np.inf}
        files = {}
        for _ in range(args.repeat):
            for mode in best:
                with tempfile.TemporaryDirectory() as d:
                    best[mode] = min(best[mode], write_series(Path(d), mesh, args.frames, mode))
                    files[mode] = len(list((Path(d) / "t_frames").iterdir()))
                    if mode:
                        series = read_series(Path(d) / "t.xdmf")
                        last = series.point_data[-1]["displacement"]
                        assert len(series.times) == args.frames
                        expected = np.full_like(mesh.points, 1e-4 * args.frames)
                        np.testing.assert_allclose(last, expected, rtol=1e-12)
        dofs = 3 * len(mesh.points)
        per = {m: 1e3 * t / args.frames for m, t in best.items()}
        rows.append((dofs, per[0.0], files[0.0], per[1.0], files[1.0], per[0.0] / per[1.0]))
        print(f"[progress] {dofs} dofs done", flush=True)
    print(f"\nms per frame (displacement + velocity), best of {args.repeat}, {args.frames} "
          "frames; ratios from this run")
    print(f"{'dofs':>7} {'file a frame':>13} {'files':>6} {'batches':>9} {'files':>6} "
          f"{'ratio':>6}")
    for dofs, a, fa, b, fb, r in rows:
        print(f"{dofs:>7} {a:>13.3f} {fa:>6} {b:>9.3f} {fb:>6} {r:>6.1f}")


if __name__ == "__main__":
    main()
