"""Cross-check of petsoft.reduced.basis.pod_basis against pyMOR's ``pod`` (issue 40).

The same 100 snapshots (q_n - q_0 of 0.2 s of the realistic control case, P2, 4641 dofs) and
the same mass product: the square roots of petsoft's correlation eigenvalues against pyMOR's
singular values, both bases' M-orthonormality, and the principal cosines between the two
subspaces. pyMOR is not a petsoft dependency: install it into a scratch environment and put it
on the path, e.g.::

    python3 -m venv --system-site-packages /tmp/pymor_venv
    echo numpy==1.24.2 > /tmp/c.txt && /tmp/pymor_venv/bin/pip install -c /tmp/c.txt pymor
    PYTHONPATH=/tmp/pymor_venv/lib/python3.11/site-packages .venv/bin/python \
        scripts/tools/pymor_pod_check.py
"""
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from pymor.algorithms.pod import pod
from pymor.operators.numpy import NumpyMatrixOperator
from pymor.vectorarrays.numpy import NumpyVectorSpace

from petsoft.api import load_experiment, read_recording
from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.experiment import experiment_from_dict
from petsoft.reduced.basis import pod_basis

CASE = Path(__file__).resolve().parents[1] / "benchmarks" / "realistic" / "cases" / "control"


def main() -> None:
    exp = load_experiment(CASE / "user.toml")
    d = exp.to_dict()
    d["mesh"]["order"] = 2
    d["time"]["end"] = 0.2
    exp = experiment_from_dict(d, source=exp.source, base_dir=exp.base_dir, path=exp.path)
    rec = read_recording(CASE / "recording.h5")
    times = rec.times[rec.times <= 0.2 + 1e-12]
    fm = ForwardModel(exp, ["material.youngs_modulus"],
                      lambda s: MarkerObserver.from_recording(s, rec), times)
    s = fm.system
    states, _ = fm._run(fm.p0, store=True)
    snaps = []
    for q, _v, _a in states[1:]:
        x = q.copy()
        x.axpy(-1.0, states[0][0])
        s.zero_prescribed(x)
        snaps.append(x)
    t0 = time.perf_counter()
    B = pod_basis(s, snaps, energy=1 - 1e-8)
    t_mine = time.perf_counter() - t0
    ai, aj, av = s.M.getValuesCSR()
    M = sp.csr_matrix((av, aj, ai), shape=s.M.getSize())
    S = np.array([x.getArray() for x in snaps])
    U = NumpyVectorSpace(S.shape[1]).from_numpy(S.T)
    t0 = time.perf_counter()
    P, svals = pod(U, product=NumpyMatrixOperator(M), modes=B.size, rtol=0.0, atol=0.0,
                   method="method_of_snapshots")
    t_pymor = time.perf_counter() - t0
    r = B.size
    rel = np.abs(np.sqrt(B.eigenvalues[:r]) - svals[:r]) / svals[:r]
    Vm, Vp = B.owned, P.to_numpy()
    print(f"r = {r} (pyMOR: {len(P)} modes)")
    print(f"sqrt(eigenvalues) vs pyMOR's singular values: max relative difference "
          f"{rel.max():.2e}")
    print(f"M-orthonormality: petsoft {np.abs(Vm.T @ (M @ Vm) - np.eye(r)).max():.1e}, "
          f"pyMOR {np.abs(Vp.T @ (M @ Vp) - np.eye(r)).max():.1e}")
    cosines = np.linalg.svd(Vm.T @ (M @ Vp), compute_uv=False)
    print(f"subspaces: smallest principal cosine {cosines.min():.16f}")
    print(f"time: petsoft {t_mine:.3f} s, pyMOR {t_pymor:.3f} s ({len(snaps)} snapshots, "
          f"{S.shape[1]} dofs; under load)")


if __name__ == "__main__":
    main()
