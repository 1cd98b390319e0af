"""The work of diagnose's sphere searches on the sphere tests' cantilever (issue 40).

The case of ``tests/test_sphere_fit.py``: a 12 x 2 x 2-cell cantilever (288 tets) whose truth has
a sphere of 5x density near its tip; the user's model places it elsewhere and
:func:`~petsoft.diagnosis.geometry.refit_added_sphere` fits it by up to two searches. Counted:
full-model trial runs, polls, calibrations, and the result (sphere, chi2, held-out rms): what
does not depend on the machine's load (no wall time is measured).

Run: ``python scripts/benchmarks/sphere_search_work.py [--starts x,y,z ...]`` (1 or 2 ranks);
prints one JSON line per start.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))

from petsc4py import PETSc  # noqa: E402
from test_sphere_fit import _start, record_truth  # noqa: E402

from petsoft.diagnosis import geometry  # noqa: E402
from petsoft.diagnosis.records import AddedTerm  # noqa: E402


def work(d: Path, centre: tuple, name: str) -> dict:
    """Two searches from a sphere placed at ``centre``: their work and result."""
    diag, fit, cand = _start(d, centre, name)
    count = {"trials": 0, "polls": 0, "calibrations": 0, "searches": 0}
    trial, calibrate, fit_sphere = (geometry._Sphere.trial, diag.calibrate,
                                    geometry.fit_sphere)

    def counted_trial(self, region, comm):
        if comm.Get_rank() == 0:        # one count a trial (its group's first rank)
            count["trials"] += 1
        return trial(self, region, comm)

    def counted_calibrate(*args, comm=None, **kwargs):
        if comm is None:                # (it calls itself again with its ranks)
            count["calibrations"] += 1
        return calibrate(*args, comm=comm, **kwargs)

    def counted_fit_sphere(*args, **kwargs):
        count["searches"] += 1
        return fit_sphere(*args, **kwargs)

    lines = []
    diag.say = lines.append
    diag.calibrate = counted_calibrate
    geometry._Sphere.trial = counted_trial
    geometry.fit_sphere = counted_fit_sphere
    try:
        entry = AddedTerm(physics=cand.physics, parameters={}, std={}, score=1.0,
                          rms_after=fit.rms, evidence="score test", region=cand.region)
        entry, new, cand = geometry.refit_added_sphere(diag, entry, fit, cand)
    finally:
        geometry._Sphere.trial, geometry.fit_sphere = trial, fit_sphere
    count["trials"] = MPI.COMM_WORLD.allreduce(count["trials"])
    polls = [line.split(": poll ", 1)[1] for line in lines if ": poll " in line]
    count["polls"] = len(polls)
    # each poll's centre step and radius factor, a search's first poll starting a new list
    count["steps"] = []
    for words in polls:
        if words.startswith("1:"):
            count["steps"].append([])
        count["steps"][-1].append(words.split("centre step ", 1)[1].split(");", 1)[0])
    return {"start": list(centre), **count,
            "sphere": {"center": [round(c, 5) for c in cand.region["center"]],
                       "radius": round(cand.region["radius"], 5)},
            "chi2": round(new.chi2, 3), "heldout_rms": new.heldout_rms,
            "evidence": entry.evidence}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", nargs="*", default=["0.225,0.02,0.02", "0.2,0.02,0.02"],
                        help="placed sphere centres, x,y,z (m)")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(comm.bcast(tmp if comm.rank == 0 else None))
        record_truth(d)
        for i, text in enumerate(args.starts):
            centre = tuple(float(v) for v in text.split(","))
            out = work(d, centre, f"start{i}.toml")
            if comm.rank == 0:
                print(json.dumps(out), flush=True)
        comm.Barrier()
        PETSc.garbage_cleanup()


if __name__ == "__main__":
    main()
