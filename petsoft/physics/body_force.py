"""The body force per unit mass and its parameters: the gravity terms' one home in physics.

Two terms set it (:mod:`petsoft.terms`): ``gravity``, the stated acceleration
(``[gravity] acceleration``, parameters ``gravity.acceleration.x|y|z``), and
``gravity.direction``, that acceleration turned at its size (``[gravity] tilt_a``, ``tilt_b``,
:mod:`petsoft.experiment.gravity_tilt`; parameters only where gravity is stated, since a zero
acceleration has no direction to turn). :class:`BodyForce` holds their values and answers what
the systems and the parameter derivatives ask of any parametric contribution: its
``parameters()``, ``set_parameter(name, value)``, the acceleration it makes and that
acceleration's derivative with respect to each parameter (the load is rho times it, linear in
it). The names come from the two terms' declared keys, so no other module spells them.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import ExperimentError
from petsoft.experiment.gravity_tilt import tilt_derivatives, tilted
from petsoft.terms import term

_STATED = term("gravity").keys[0]
#: The stated acceleration's components, as parameters.
COMPONENTS = tuple(f"{_STATED.dotted}.{c}" for c in "xyz")
#: The tilt's tangents, as parameters.
TILTS = tuple(k.dotted for k in term("gravity.direction").keys)


class BodyForce:
    """The acceleration of the body force, from its parameters' values.

    Parameters
    ----------
    stated : array_like (3,)
        The stated acceleration (m/s^2).
    tilt : (float, float) or None
        The tilt's tangents; None: no tilt parameters (a body whose gravity is not turned,
        a mass-spring network). Ignored (no tilt) when ``stated`` is zero.
    """

    def __init__(self, stated, tilt=None):
        self.values = dict(zip(COMPONENTS, np.asarray(stated, dtype=float).tolist(),
                               strict=True))
        if tilt is not None and any(self.values.values()):
            self.values.update(zip(TILTS, map(float, tilt), strict=True))

    @classmethod
    def of(cls, experiment) -> BodyForce:
        """The body force ``experiment`` states, with its tilt."""
        g = experiment.gravity
        return cls(g.as_stated, (g.tilt_a, g.tilt_b))

    def parameters(self) -> dict[str, float]:
        """name -> value of every parameter it has (the components, then the tilt's)."""
        return dict(self.values)

    def set_parameter(self, name: str, value: float) -> None:
        """Set one of :meth:`parameters` (KeyError for another name)."""
        if name not in self.values:
            raise KeyError(f"{name!r} is no parameter of the body force "
                           f"({', '.join(self.values)})")
        self.values[name] = float(value)

    def _stated(self) -> np.ndarray:
        return np.asarray([self.values[n] for n in COMPONENTS])

    def _tilt(self) -> tuple[float, float]:
        return tuple(self.values.get(n, 0.0) for n in TILTS)

    def acceleration(self) -> np.ndarray:
        """The acceleration the body feels: the stated one turned by the tilt (m/s^2)."""
        return tilted(self._stated(), *self._tilt())

    def derivative(self, name: str) -> np.ndarray:
        """d :meth:`acceleration` / d ``name``.

        Raises
        ------
        ExperimentError
            For a stated component under a tilt (calibrate the one or the other)."""
        a, b = self._tilt()
        if name in TILTS:
            return tilt_derivatives(self._stated(), a, b)[TILTS.index(name)]
        if a != 0.0 or b != 0.0:
            raise ExperimentError(
                f'"{name}" is not differentiable while gravity is tilted (tilt_a = {a:g}, '
                f"tilt_b = {b:g}): calibrate the tilt or the stated components, not both")
        unit = np.zeros(3)
        unit[COMPONENTS.index(name)] = 1.0
        return unit
