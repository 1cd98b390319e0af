"""``damping.mass``: Rayleigh damping proportional to mass (alpha, 1/s)."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="damping.mass",
    meaning="viscous damping proportional to mass (Rayleigh alpha; air, internal losses)",
    keys=(Key("damping", "mass", unit="1/s", minimum=0.0),),
    proposal=Proposal(kind="value", parameters=(
        Parameter("damping.mass", "1/s", lower="0", upper="100"),)),
    hints=(
        ("faster modes", "{count} mode(s) decay faster in the data than in the model (e.g. "
                         "{data:.3g} vs {sim:.3g} 1/s)"),
        ("partly", "the extra decay could also be partly mass-proportional"),
        ("viscous envelope", "exponential amplitude decay (viscous; {share:.0%} of the decay "
                             "rate beyond the model's)")),
    contributes="rayleigh",
    builds="petsoft.dynamics.rayleigh:MASS",
)
