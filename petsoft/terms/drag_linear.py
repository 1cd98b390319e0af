"""``drag.linear``: surface drag linear in the normal velocity (Pa s/m)."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="drag.linear",
    meaning="velocity-dependent (linear) drag from the surrounding air/fluid",
    keys=(Key("drag", "linear", unit="Pa s/m", minimum=0.0),),
    # bounded by an equivalent mass-damping rate of 100/s
    proposal=Proposal(kind="value", parameters=(
        Parameter("drag.linear", "Pa s/m", lower="0", upper="100 * mass / area"),),
        settings=(("drag.linear", "0"),), note=" (on the body's surface)"),
    hints=(("viscous envelope", "exponential amplitude decay (linear drag on the body)"),),
    contributes="velocity",
    builds="petsoft.physics.drag:LinearDrag",
    surface=True,
)
