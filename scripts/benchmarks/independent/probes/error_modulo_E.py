"""How much of a truth's discretisation error would the user's calibration of E absorb? From a
draw's cached runs (``DIR/.runs``: the truth at h, 1.4 h, 1.96 h and h at half the steps, 4
steps a frame) and one more run on the 1.96 h mesh at E (1 + 1e-3) (made and cached):
``python3 error_modulo_E.py SEED N DIR CASE [CASE ...]``. The differences the generator's
check measures (space D1 = u(1.4 h) - u(h), D2 = u(1.96 h) - u(1.4 h), time u(h, 2 dt) -
u(h, dt)) are printed in units of the case's noise, as they are and with their least-squares
component along the E sensitivity removed (what a refit of E takes up: diagnose's own
"refitted change"), with the bound random_cases.truth_error makes of each."""

import _cached  # first: one BLAS thread, the generator's folder on the path
import gmsh
import numpy as np
import random_cases as rc
import random_draw as rd

DELTA = 1e-3
cache, todo = _cached.cases_from_argv()
for case, h in todo:
    name = case["name"]
    runs = {key: np.load(cache / f"{name}-truth-h{h * k:.5g}-s{s}.npz")
            for key, k, s in (("truth", 1.0, 4), ("space", 1.4, 4), ("space2", 1.96, 4),
                              ("time", 1.0, 2))}
    markers = runs["truth"]["markers"]
    stiffer = dict(case, material=dict(case["material"], youngs_modulus=case["material"][
        "youngs_modulus"] * (1 + DELTA)))
    runs["E"] = rc.run(gmsh, stiffer, markers, f"truth-h{h * 1.96:.5g}-s4-E{1 + DELTA:g}",
                       cache, h=h * 1.96, substeps=4)
    ok = np.logical_and.reduce([r["found"] for r in runs.values()])
    u = {k: r["displacements"][:, ok] for k, r in runs.items()}
    noise = rd.noise_level(case["noise_fraction"],
                           float(np.linalg.norm(u["truth"], axis=-1).max()))
    g = ((u["E"] - u["space2"]) / DELTA).ravel()

    def without_E(d, g=g):
        d = d.ravel()
        return d - g * (g @ d) / (g @ g)

    diffs = {"space": u["space"], "space2": u["space2"], "time": u["time"]}
    plain = {k: v / noise for k, v in dict(truth=u["truth"], **diffs).items()}
    # the same runs with each difference from the truth taken along E out
    mod = {"truth": u["truth"] / noise}
    mod["space"] = mod["truth"] + without_E(u["space"] - u["truth"]).reshape(
        u["truth"].shape) / noise
    mod["space2"] = mod["space"] + without_E(u["space2"] - u["space"]).reshape(
        u["truth"].shape) / noise
    mod["time"] = mod["truth"] + without_E(u["time"] - u["truth"]).reshape(
        u["truth"].shape) / noise
    a, b = rc.truth_error(plain), rc.truth_error(mod)
    # (truth_error takes the time run against the 1.96 h mesh's: here both at h, so compare
    # the time differences directly)
    t_plain = rc.rms(plain["time"] - plain["truth"]) / 3
    t_mod = rc.rms(mod["time"] - mod["truth"]) / 3
    print(f"{name}: D1 {a['space_difference']:.3f} -> {b['space_difference']:.3f}, D2 "
          f"{a['space2_difference']:.3f} -> {b['space2_difference']:.3f} x noise (order "
          f"{a['space_observed_order']:.2f} -> {b['space_observed_order']:.2f}), space error "
          f"{a['space_error_estimate']} -> {b['space_error_estimate']}; time error "
          f"{t_plain:.3f} -> {t_mod:.3f}; E's share of the sensitivity: |g| "
          f"{np.sqrt(np.mean(g ** 2)) / noise:.3g} x noise per unit dE/E; {ok.sum()} markers",
          flush=True)
