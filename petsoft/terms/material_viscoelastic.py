"""``material.viscoelastic``: a standard-linear-solid (Maxwell) branch."""

from __future__ import annotations

from petsoft.terms.declare import Key, Parameter, Proposal, Term

TERM = Term(
    name="material.viscoelastic",
    meaning="rate-dependent stress relaxation (Kelvin-Voigt / standard linear solid)",
    keys=(Key("viscoelastic", "ratio", unit="", text="E_M / E", minimum=0.0),
          Key("viscoelastic", "relaxation_time", default=0.1, unit="s", minimum=0.0, open=True)),
    # the branch's modulus ratio from 0; its relaxation time from 1/(2 pi f) of the data's
    # dominant frequency, fitted but not tested (undefined while the ratio is 0)
    proposal=Proposal(
        kind="value", ranking="score-fd", start="1 / (2 * pi * frequency)",
        parameters=(Parameter("viscoelastic.ratio", "", lower="0", upper="2", fd_step=1e-3),
                    Parameter("viscoelastic.relaxation_time", "s", lower="start / 30",
                              upper="30 * start", scale="log", tested=False)),
        settings=(("viscoelastic.ratio", "0"), ("viscoelastic.relaxation_time", "start")),
        note=" (standard linear solid, relaxation time from {start:.3g} s)",
        continuum_only=True),
    hints=(),   # no evidence points at it before its score test
)
