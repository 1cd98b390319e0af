"""``gravity``: the body force per unit mass, freed at its current value."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="gravity",
    meaning="missing or wrong body force",
    keys=(Key("gravity", "acceleration", type="vector", default=(0.0, 0.0, 0.0),
              unit="m/s^2"),),
    # each component from its current value, +-20 m/s^2 (twice the Earth's)
    proposal=Proposal(kind="value", parameters=tuple(
        Parameter(f"gravity.acceleration.{c}", "m/s^2", lower="current - 20",
                  upper="current + 20") for c in "xyz")),
    hints=(("offset", "the residual has a common offset along {axis} ({offset:.3g} m)"),),
)
