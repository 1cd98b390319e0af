"""``gravity.direction``: a stated gravity turned at its own size (a tilted mount)."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="gravity.direction",
    meaning="gravity in another direction at the stated size (a mount or camera frame that "
            "is not level)",
    keys=(Key("gravity", "tilt_a", unit="", text="tangent of the tilt"),
          Key("gravity", "tilt_b", unit="", text="tangent of the tilt")),
    # the tangents of the tilt towards the two directions across the stated one, from 0, up to
    # 45 degrees (petsoft.experiment.gravity_tilt); proposed only where gravity is stated
    proposal=Proposal(kind="value", parameters=tuple(
        Parameter(f"gravity.tilt_{c}", "", lower="-1", upper="1") for c in "ab"),
        continuum_only=True),
    hints=(("offset", "the residual has a common offset along {axis} ({offset:.3g} m)"),),
)
