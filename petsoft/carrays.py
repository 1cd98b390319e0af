"""Arrays handed to compiled code (ctypes) as plain addresses.

In the lowest layer so that the mesh layer's compiled functions (:mod:`petsoft.mesh.ordering`)
and the element kernels (:mod:`petsoft.fem.kernels`) share it.
"""

from __future__ import annotations

import numpy as np


def addr(a: np.ndarray) -> int:
    """The address of ``a``'s data.

    Not ``a.ctypes.data``: numpy builds that from a ``ctypes.cast`` result, which references
    itself, so every call leaves a reference cycle that keeps the array alive until Python's
    cyclic collector runs -- gigabytes over a calibration run with the collector paused (as
    ``petsoft diagnose`` does on several ranks).
    """
    return a.__array_interface__["data"][0]
