"""``contact.plane``: a rigid plane (floor, wall) the body may touch."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="contact.plane",
    meaning="unmodelled contact with a plane (floor, wall)",
    keys=(Key("collider", "point", type="vector", default=None, unit="m", section="array",
              only="plane"),
          Key("collider", "normal", type="vector", default=None, section="array", only="plane"),
          Key("collider", "offset", unit="m", text="m, along the normal", section="array",
              only="plane"),
          Key("collider", "friction", minimum=0.0, section="array", only="plane"),
          Key("collider", "stiffness", default=None, unit="N/m", minimum=0.0, open=True,
              section="array", only="plane")),
    # placed where the simulation leaves the data's extent by ``depth``; its offset fitted
    proposal=Proposal(kind="switch", ranking="switch", parameters=(
        Parameter("collider.{index}.offset", "m", lower="-depth", upper="depth"),),
        note=": the simulation passes the data's extent by {depth:.3g} m along {normal}"),
    hints=(("intermittent", "the mismatch is intermittent ({count} window(s), {covered:.3g} s "
                            "of {duration:.3g} s)"),),
    contributes="potential",
    builds="petsoft.physics.contact:build_contact",
)
