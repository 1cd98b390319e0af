"""``drag.quadratic``: surface drag quadratic in the normal velocity (kg/m^3)."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="drag.quadratic",
    meaning="velocity-squared drag from the surrounding air/fluid",
    keys=(Key("drag", "quadratic", unit="kg/m^3", minimum=0.0),),
    # bounded by an equivalent mass-damping rate of 100/s at the largest marker speed
    proposal=Proposal(kind="value", parameters=(
        Parameter("drag.quadratic", "kg/m^3", lower="0",
                  upper="100 * mass / (area * speed_max)"),),
        settings=(("drag.quadratic", "0"),), note=" (on the body's surface)"),
    hints=(("quadratic envelope", "the amplitude's decay rate grows with the amplitude squared "
                                  "(velocity-squared drag; {share:.0%} of it beyond the "
                                  "model's)"),),
    contributes="velocity",
    builds="petsoft.physics.drag:QuadraticDrag",
    surface=True,
)
