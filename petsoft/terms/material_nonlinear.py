"""``material.nonlinear``: the linear material law switched to a nonlinear one."""

from __future__ import annotations

from petsoft.terms.declare import Key, Proposal, Term

#: The material laws of ``[material] model`` (formats.md section 1).
MODELS = ("linear", "stvk", "corotated", "neohookean")

TERM = Term(
    name="material.nonlinear",
    meaning="the material law is nonlinear at the observed strains",
    keys=(Key("material", "model", type="choice", default="linear", choices=MODELS),),
    # the switch is applied to every linear material of the model (the default and regions)
    proposal=Proposal(kind="switch", ranking="switch",
                      settings=(("material.model", "corotated"),),
                      note=" (linear -> corotated)", continuum_only=True),
    hints=(("higher frequencies", "{shift}: stiffening at the observed strains"),),
)
