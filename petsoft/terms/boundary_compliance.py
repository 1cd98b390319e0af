"""``boundary.compliance``: the fixed supports made elastic."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="boundary.compliance",
    meaning="the support is elastic, not rigid",
    keys=(Key("boundary", "compliance", unit="m/Pa", minimum=0.0, section="array",
              only="fixed", at_minimum="a rigid support, a Dirichlet condition"),),
    # from a support displacement a thousandth of a cell's strain (numerically rigid)
    proposal=Proposal(
        kind="value", start="1e-3 * cell / youngs_modulus",
        parameters=(Parameter("boundary.compliance", "m/Pa", lower="start",
                              upper="max(10 * length / youngs_modulus, 10 * start)",
                              scale="log"),),
        settings=(("boundary.compliance", "start"),),
        note=" (support springs, starting numerically rigid at {start:.3g} m/Pa)",
        continuum_only=True),
    hints=(("lower frequencies", "{shift}: a softer support lowers them"),),
    contributes="potential",
    builds="petsoft.physics.support:build_support",
)
