"""``damping.stiffness``: Rayleigh damping proportional to stiffness (beta, s)."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="damping.stiffness",
    meaning="viscous damping proportional to stiffness (Rayleigh beta; material losses)",
    keys=(Key("damping", "stiffness", unit="s", minimum=0.0),),
    proposal=Proposal(kind="value", parameters=(
        Parameter("damping.stiffness", "s", lower="0", upper="0.05"),)),
    hints=(
        ("faster modes", "{count} mode(s) decay faster in the data than in the model (e.g. "
                         "{data:.3g} vs {sim:.3g} 1/s)"),
        ("partly", "the extra decay could also be partly stiffness-proportional")),
    contributes="rayleigh",
    builds="petsoft.dynamics.rayleigh:REFERENCE",
)
