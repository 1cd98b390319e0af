"""``mass.added``: a sphere of higher density (a sensor, a fixture)."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="mass.added",
    meaning="extra mass attached (sensor, fixture); mismatch.region says where",
    keys=(Key("region", "where", type="where", default=None, section="named"),
          Key("material", "density", default=None, unit="kg/m^3", minimum=0.0, open=True,
              section="named")),
    # extra mass is a denser region: from the surrounding density (current) up only
    proposal=Proposal(kind="region", region="diag_mass", parameters=(
        Parameter("material.{region}.density", "kg/m^3", lower="current",
                  upper="10 * current", scale="log"),),
        note="; sphere from {origin}", continuum_only=True),
    hints=(("localised shift", "{shift}, localised"),
           ("lower frequencies", "{shift}: extra mass lowers them")),
)
