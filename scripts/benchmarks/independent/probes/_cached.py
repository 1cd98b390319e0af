"""The shared start of the probes that read a draw's cached runs: ``SEED N DIR CASE [CASE ...]``
on the command line, gmsh started quietly, and each named case of the realistic draw (SEED, N)
with its truth's element size."""

import os
import sys
from pathlib import Path

# imported first by the probes: one BLAS thread (as generate.py) and the generator's folder
os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import gmsh
import random_draw as rd
import random_shapes as rs


def cases_from_argv() -> tuple[Path, list[tuple[dict, float]]]:
    """(DIR/.runs, [(case, h), ...]) from ``sys.argv``; gmsh initialised."""
    seed, n, folder = int(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3])
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    drawn = {c["name"]: c for c in rd.draw(seed, n, "realistic")}
    missing = [name for name in sys.argv[4:] if name not in drawn]
    if missing:
        raise SystemExit(f"not among the first {n} cases of seed {seed}: {', '.join(missing)}")
    return folder / ".runs", [(drawn[name], rs.truth_h(drawn[name]["geometry"]))
                              for name in sys.argv[4:]]
