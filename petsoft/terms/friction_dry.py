"""``friction.dry``: regularised Coulomb friction per unit mass (m/s^2)."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="friction.dry",
    meaning="Coulomb (rate-independent) friction in joints or contacts",
    keys=(Key("friction", "dry", unit="m/s^2", minimum=0.0),
          Key("friction", "speed", default=1e-3, unit="m/s", minimum=0.0, open=True),
          Key("friction", "where", type="where", default=None)),
    # regularised at 1 % of the data's rms speed; bounded by a 100/s rate at that speed
    proposal=Proposal(
        kind="value", start="0.01 * speed",
        parameters=(Parameter("friction.dry", "m/s^2", lower="0", upper="100 * speed"),),
        settings=(("friction.dry", "0"), ("friction.speed", "start")),
        note=" (per unit mass, regularised below {start:.3g} m/s)"),
    hints=(("constant envelope", "the oscillation amplitude decays at a rate that stays finite "
                                 "as it shrinks (a constant term, {share:.0%} of its decay "
                                 "rate, beyond the model's; envelope law: {law})"),),
    contributes="velocity",
    builds="petsoft.physics.friction:DryFriction",
)
