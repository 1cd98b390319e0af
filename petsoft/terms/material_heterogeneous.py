"""``material.heterogeneous``: a sphere of its own Young's modulus."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="material.heterogeneous",
    meaning="stiffness varies in space; mismatch.region says where",
    keys=(Key("region", "where", type="where", default=None, section="named"),
          Key("material", "youngs_modulus", default=None, unit="Pa", minimum=0.0, open=True,
              section="named")),
    # from the surrounding modulus (current), within a factor 5 either way
    proposal=Proposal(kind="region", region="diag_stiffness", parameters=(
        Parameter("material.{region}.youngs_modulus", "Pa", lower="current / 5",
                  upper="5 * current", scale="log"),),
        note="; sphere from {origin}", continuum_only=True),
    hints=(("localised shift", "{shift}, with a localised residual"),),
)
