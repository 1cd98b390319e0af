"""Anderson mixing of a fixed-point map q -> G(q) on distributed vectors [Peng et al. 2018].

This module owns the mixing and its history: given the map's value g = G(q) at the iterate q,
the next iterate is g minus the combination of the last ``window`` differences of G that best
cancels the last differences of the residuals f = G(q) - q (a regularised least-squares
problem, its Gram matrix summed over the ranks). Each rank holds the entries it owns; every rank
computes the same coefficients. The caller keeps the safeguard (:meth:`AndersonMixing.restart`
when it rejects a mixed iterate) and the map (:meth:`AndersonMixing.forget` when it changes):
:meth:`petsoft.dynamics.local_global.LocalGlobalSolver.solve`.
"""

from __future__ import annotations

import numpy as np


class AndersonMixing:
    """The mixing of the last ``window`` iterates of a fixed-point map (window 0: none).

    Parameters
    ----------
    window : int
        How many differences are kept (0: :meth:`mix` returns the map's value unchanged).
    mpi : mpi4py communicator
        The ranks the vectors are distributed over.

    Attributes
    ----------
    plain : ndarray or None
        The map's value G(q) at the last mixed iterate (the safeguard's fallback), None when
        there is none.
    """

    def __init__(self, window: int, mpi):
        self.window = int(window)
        self._mpi = mpi
        self._dG: list[np.ndarray] = []
        self._dF: list[np.ndarray] = []
        self._prev_g = self._prev_f = None
        self.plain = None

    def restart(self) -> None:
        """Drop the history (a mixed iterate was rejected); :attr:`plain` is kept."""
        self._dG.clear()
        self._dF.clear()
        self._prev_g = self._prev_f = None

    def forget(self) -> None:
        """Drop the history and :attr:`plain`: the map changed (a new matrix)."""
        self.restart()
        self.plain = None

    def mix(self, q: np.ndarray, g: np.ndarray) -> np.ndarray:
        """The next iterate from the iterate ``q`` and the map's value ``g`` = G(q) (owned
        entries, flattened; collective)."""
        if not self.window:
            return g
        f = g - q
        if self._prev_g is not None:
            self._dG.append(g - self._prev_g)
            self._dF.append(f - self._prev_f)
            if len(self._dG) > self.window:
                self._dG.pop(0)
                self._dF.pop(0)
        self._prev_g, self._prev_f = g, f
        self.plain = g
        if not self._dF:
            return g
        F = np.array(self._dF)
        gram = self._mpi.allreduce(F @ F.T)
        proj = self._mpi.allreduce(F @ f)
        # regularised least squares: the differences become nearly dependent close to
        # convergence (at round-off all differences may vanish: then no mixing)
        scale = float(np.trace(gram))
        if not (scale > 0.0 and np.isfinite(scale)):
            return g
        lam = 1e-10 * scale / len(self._dF)
        gamma = np.linalg.lstsq(gram + lam * np.eye(len(self._dF)), proj, rcond=None)[0]
        return g - gamma @ np.array(self._dG)
