"""The random draw of independent diagnose cases (issue 37, item 1): parameters only.

Pure numpy (no gmsh, no DOLFINx, no petsoft), so the draw can be tested anywhere
(tests/test_random_draw.py); random_cases.py meshes and simulates what it draws.

:func:`draw_case` gives case ``index`` of a draw with seed ``seed`` from a generator seeded by
the pair ``(seed, index)`` alone, so a case does not change when N changes or other cases are
dropped. What it draws (the ranges are the tables below):

* the concealed category by the case's position in blocks of eight (:data:`PATTERN`): two
  controls, three single vocabulary terms, one pair, two off-vocabulary effects per block, so
  at least a quarter of any draw (any N) are controls;
* a shape family and its gmsh dimensions (:data:`FAMILIES`), the user's mesh size (a target tet
  count), the number of markers, noise, dropouts, occluded stretches, the record length;
* the excitation (:data:`EXCITATIONS`): an initial velocity field, a release from a deflected
  shape, or a base motion (the clamp translated by A sin(omega t)^3; boundary.compliance is
  then not drawn: a compliant moving support is not made);
* the material (E, nu, rho; the truth is neo-Hookean) and the user's starting E (off by up to
  50 %); the user's law is linear exactly when ``material.nonlinear`` is concealed;
* the concealed terms' magnitudes, log-uniform over :data:`MAGNITUDE` (from far below to above
  the sizes the fixed suite detects, cases/ and generate.py's CASES).
"""

from __future__ import annotations

import math

import numpy as np

#: the user's step (s): the user's frames and the truth's output
STEP = 0.002
GRAVITY = [0.0, 0.0, -9.81]

#: the category of the case at position ``index % 8``
PATTERN = ("control", "one", "one", "off", "control", "one", "two", "off")

FAMILIES = ("bar", "bracket", "plate", "shell", "fillet")

#: the vocabulary terms the DOLFINx truth makes (petsoft/diagnosis/candidates.py's names)
VOCABULARY = ("damping.mass", "damping.stiffness", "gravity", "boundary.compliance",
              "drag.linear", "drag.quadratic", "friction.dry", "material.viscoelastic",
              "material.heterogeneous", "mass.added", "material.nonlinear")
#: effects outside the vocabulary: a slab-shaped stiff band across the body, and a standard
#: linear solid with two Maxwell branches of well separated relaxation times
OFF_VOCABULARY = ("inclusion.slab", "viscoelastic.two_branch")

#: term -> (low, high) of its magnitude, drawn log-uniformly. The fixed suite's values
#: (generate.py CASES), all detected there, sit near the top: damping.mass 4 /s, stiffness
#: 2e-4 s, compliance 2e-9 m/Pa, drag 80 Pa s/m and 300 Pa s^2/m^2, dry friction 1 m/s^2,
#: viscoelastic ratio 0.3, inclusion E x2 (excess 1), added density x4 (excess 3).
#: material.nonlinear: the factor on the excitation's amplitude (the nonlinearity's size).
#: gravity has no magnitude (9.81 m/s^2 along -z); its effect size is measured like the rest.
MAGNITUDE = {
    "damping.mass": (0.01, 8.0),                 # 1/s
    "damping.stiffness": (5e-7, 4e-4),           # s
    "boundary.compliance": (1e-11, 4e-9),        # m/Pa
    "drag.linear": (0.3, 160.0),                 # Pa s/m
    "drag.quadratic": (1.0, 600.0),              # Pa s^2/m^2
    "friction.dry": (0.003, 2.0),                # m/s^2
    "material.viscoelastic": (0.002, 0.5),       # branch ratio g
    "material.heterogeneous": (0.01, 3.0),       # E_inclusion / E - 1
    "mass.added": (0.02, 5.0),                   # rho_region / rho - 1
    "material.nonlinear": (1.0, 8.0),            # amplitude factor
    "inclusion.slab": (0.01, 3.0),               # E_slab / E - 1
    "viscoelastic.two_branch": (0.002, 0.5),     # each branch's ratio
}
#: the user's mesh (target tets) and the record length (s) by size
SIZES = {"small": {"tets": (100, 400), "end": (0.2, 0.4)},
         "realistic": {"tets": (600, 1000), "end": (0.5, 1.0)}}
E_RANGE, NU_RANGE, RHO_RANGE = (8e6, 4e7), (0.25, 0.42), (900.0, 1400.0)
#: the noise: a fraction of the motion (the truth's largest marker displacement), log-uniform
#: (a marker system's 0.1-0.5 mm on a 3-20 mm motion), then held within NOISE_BOUNDS (m).
#: Drawn relative to the motion, since the truth's discretisation error is: seed 1 drew the
#: noise alone (0.03-0.3 mm) and its 0.04-0.06 mm cases on mm motions asked the truth for an
#: error of a few micrometres. 0.5-3 % was tried first: seed 2's r000 (1.07 %, 3.8 mm) then
#: needed its truth's error below 0.2 % of its motion, a P2 refinement costing 5.5 truths
NOISE_FRACTION = (0.01, 0.05)
NOISE_BOUNDS = (2e-5, 5e-4)
MARKER_RANGE = (6, 32)
DROPOUT_RANGE = (0.0, 0.15)         # fraction of the samples dropped at random
OCCLUDED_RANGE = (0.0, 0.3)         # fraction of the markers hidden for a stretch
STRETCH_RANGE = (0.05, 0.3)         # a stretch's length, fraction of the record
E_START_OFF = 0.5                   # the user's E starts within +-50 % of the truth's
VELOCITY_TIP = (0.15, 0.5)          # m/s, the initial velocity's largest value (tip)
RELEASE_TIP = (0.003, 0.012)        # m, the released shape's tip deflection
BASE_AMPLITUDE = (0.0005, 0.003)    # m, the base motion's amplitude
#: the base motion's frequency over the body's estimated first bending frequency
#: (:func:`first_frequency`, uniform): below it, where one mode's steady response is at most
#: 1 / (1 - 0.6^2) ~ 1.6 x the quasi-static one if the estimate holds (seed 2's r004, an L at
#: 0.55, moved 5x its clamp amplitude: the L's estimate is likely high). Seed 1 drew 4-30 Hz
#: regardless of the body: r007's 24 Hz drove a thin shell to 76 mm at its tip, and its truth
#: meshes disagreed by mm
BASE_RATIO = (0.2, 0.6)
#: excitation kind -> probability
EXCITATIONS = {"velocity": 0.45, "release": 0.3, "base": 0.25}
SPEED_DRY = 0.003                   # m/s, dry friction's regularisation speed (as the suite)


def loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A draw log-uniform on [lo, hi]."""
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw_geometry(rng: np.random.Generator, family: str) -> dict:
    """A family's gmsh dimensions (m) and its axis: ``axis`` the clamp's normal (the body runs
    from the clamp at 0 along it to ``length``), ``section`` its smallest thickness."""
    u = rng.uniform
    if family == "bar":             # a tapered, twisted bar (the suite's finger, drawn)
        g = dict(length=u(0.2, 0.32), width=u(0.03, 0.045), height=u(0.03, 0.045),
                 taper_w=u(0.55, 0.85), taper_h=u(0.55, 0.85), twist_deg=u(0.0, 60.0))
        g["section"] = min(g["width"] * g["taper_w"], g["height"] * g["taper_h"])
    elif family in ("bracket", "fillet"):   # an L: a post on the floor and an arm along x
        g = dict(thickness=u(0.03, 0.045), post=u(0.14, 0.22), arm=u(0.1, 0.17))
        g["length"] = g["post"]
        g["section"] = g["thickness"]
        if family == "fillet":
            g["fillet_radius"] = g["thickness"] * u(0.3, 0.8)
            # the fillet's curved face is resolved with the truth's h at most 2/3 of its
            # radius (h = section / 3): seed 5's r003-fillet (radius 9.6 mm, thickness 31 mm)
            # converged at order 0.6 with h = 10.2 mm and at order 3.0 with 6.1 mm
            g["section"] = min(g["thickness"], 2 * g["fillet_radius"])
    elif family == "plate":         # a plate with a hole through its thickness
        g = dict(length=u(0.14, 0.2), width=u(0.05, 0.075), thickness=u(0.02, 0.03))
        g["hole_radius"] = g["width"] * u(0.15, 0.25)
        g["hole_x"] = g["length"] * u(0.45, 0.7)
        # the thinnest section is the thickness or a ligament beside the hole, whichever is
        # less (the truth puts three P2 cells across it). With the thickness alone the test
        # draw 604960342's r000-plate (ligaments 16 mm, thickness 26 mm) converged at order
        # 0.5 over 0.25 s (grading the clamp to h/10 did not help: order -0.1), at the
        # ligament's h at order 2.5, its error 0.03x the noise. The hole is kept to 15-25 %
        # of the width (was 20-35 %: ligaments of 7.5 mm would need 4x the cells across)
        g["section"] = min(g["thickness"], (g["width"] - 2 * g["hole_radius"]) / 2)
    elif family == "shell":         # a thin curved strip (a cylindrical tile)
        g = dict(length=u(0.1, 0.15), width=u(0.035, 0.055), thickness=u(0.011, 0.015),
                 radius=u(0.05, 0.2))
        g["section"] = g["thickness"]
    else:
        raise ValueError(f"unknown family {family!r}; valid: {', '.join(FAMILIES)}")
    g["axis"] = "z" if family in ("bracket", "fillet") else "x"
    return g


def first_frequency(family: str, geom: dict, material: dict) -> float:
    """An estimate (Hz) of the body's first bending frequency about its weakest axis: Rayleigh's
    quotient of a cantilever of length L, bending stiffness EI and mass per length rho A, with
    a tip mass M, in its static shape, f = sqrt(3 E I / (L^3 (33/140 rho A L + M))) / (2 pi)
    (1.5 % above the exact 1.8751^2 / (2 pi L^2) sqrt(EI / rho A) without a tip mass; exact
    as M dominates). The section is the smallest (a bar's tip: a lower estimate than its
    taper's); a plate's hole is ignored; a shell is taken flat (its curvature stiffens it:
    again lower); an L is its post carrying the arm's mass at its top."""
    E, rho = material["youngs_modulus"], material["density"]
    tip = 0.0
    if family == "bar":
        b, d = geom["width"] * geom["taper_w"], geom["height"] * geom["taper_h"]
        I, A, L = min(b * d ** 3, d * b ** 3) / 12, b * d, geom["length"]
    elif family in ("bracket", "fillet"):
        a = geom["thickness"]
        I, A, L = a ** 4 / 12, a * a, geom["post"]
        tip = rho * a * a * (geom["arm"] - a)
    elif family in ("plate", "shell"):
        w, t = geom["width"], geom["thickness"]
        I, A, L = w * t ** 3 / 12, w * t, geom["length"]
    else:
        raise ValueError(f"unknown family {family!r}; valid: {', '.join(FAMILIES)}")
    return math.sqrt(3 * E * I / (L ** 3 * (33 / 140 * rho * A * L + tip))) / (2 * math.pi)


def noise_level(fraction: float, motion: float) -> float:
    """The noise std (m): ``fraction`` of the ``motion`` (the truth's largest marker
    displacement, m), held within :data:`NOISE_BOUNDS`."""
    if not (fraction > 0 and motion > 0):
        raise ValueError(f"noise fraction and motion must be > 0, got {fraction}, {motion}")
    return float(np.clip(fraction * motion, *NOISE_BOUNDS))


def axis_point(geom: dict, s: float) -> list[float]:
    """A point inside the body at fraction ``s`` of its length from the clamp (on the post of
    an L for s <= 1, along its arm for ``s`` > 1: s - 1 of the arm's length)."""
    if geom["axis"] == "z":
        a = geom["thickness"]
        if s <= 1.0:
            return [a / 2, a / 2, s * geom["post"]]
        return [a + (s - 1.0) * (geom["arm"] - a), a / 2, geom["post"] - a / 2]
    x = s * geom["length"]
    if "hole_x" in geom:            # beside the hole's axis (y = W/2), mid-thickness
        return [x, geom["width"] / 2, geom["thickness"] / 2]
    return [x, 0.0, 0.0]


def neutral_axis(geom: dict) -> list[float]:
    """A point of the sections' centroid line (the coordinate along the axis is unused)."""
    if geom["axis"] == "z":
        return [geom["thickness"] / 2, geom["thickness"] / 2, 0.0]
    if "hole_x" in geom:
        return [0.0, geom["width"] / 2, geom["thickness"] / 2]
    if "radius" in geom:            # the shell's arc: its centroid below the crown
        half = geom["width"] / geom["radius"] / 2
        return [0.0, 0.0, geom["radius"] * (math.sin(half) / half - 1.0)]
    return [0.0, 0.0, 0.0]


def _cross_size(geom: dict) -> float:
    """The body's largest cross-section dimension (m): a region's radius scale."""
    if geom["axis"] == "z":
        return geom["thickness"]
    return max(geom.get("width", 0.0), geom.get("height", 0.0), geom.get("thickness", 0.0))


def effect(rng: np.random.Generator, term: str, geom: dict, material: dict) -> tuple[dict, dict]:
    """The truth settings of one concealed ``term`` (generate.py's truth keys) and the record
    of its drawn magnitude."""
    if term == "gravity":           # left out of the user's model; 9.81 m/s^2 along -z
        return {}, {"term": term, "magnitude": 9.81, "range": None}
    lo, hi = MAGNITUDE[term]
    m = loguniform(rng, lo, hi)
    E, rho = material["youngs_modulus"], material["density"]
    along = geom["axis"]
    if term == "damping.mass":
        t = {"damping": {"mass": m}}
    elif term == "damping.stiffness":
        t = {"damping": {"stiffness": m}}
    elif term == "boundary.compliance":
        t = {"compliance": m}
    elif term == "drag.linear":
        t = {"drag": {"linear": m}}
    elif term == "drag.quadratic":
        t = {"drag": {"quadratic": m}}
    elif term == "friction.dry":
        t = {"friction": {"dry": m, "speed": SPEED_DRY}}
    elif term == "material.viscoelastic":
        t = {"viscoelastic": {"ratio": m, "relaxation_time": loguniform(rng, 0.005, 0.05)}}
    elif term in ("material.heterogeneous", "mass.added"):
        # a stiff sphere near the clamp (large strain), a heavy one towards the free end
        s = rng.uniform(0.1, 0.45) if term == "material.heterogeneous" else rng.uniform(0.7, 0.95)
        if along == "z" and term == "mass.added":
            s = 1.0 + s                     # the L's arm
        key, value = (("youngs_modulus", E * (1 + m)) if term == "material.heterogeneous"
                      else ("density", rho * (1 + m)))
        t = {"regions": [{"kind": "sphere", "center": axis_point(geom, s),
                          "radius": _cross_size(geom) * rng.uniform(0.5, 0.9), key: value}]}
    elif term == "inclusion.slab":
        # a band across the body, its normal tilted up to 30 degrees from the body's axis
        tilt, turn = math.radians(rng.uniform(0.0, 30.0)), rng.uniform(0.0, 2 * math.pi)
        axial, side1, side2 = math.cos(tilt), math.sin(tilt) * math.cos(turn), \
            math.sin(tilt) * math.sin(turn)
        normal = [axial, side1, side2] if along == "x" else [side1, side2, axial]
        s = rng.uniform(0.15, 0.6)
        t = {"regions": [{"kind": "slab", "center": axis_point(geom, s), "normal": normal,
                          "thickness": geom["length"] * rng.uniform(0.08, 0.25),
                          "youngs_modulus": E * (1 + m)}]}
    elif term == "viscoelastic.two_branch":
        tau1 = loguniform(rng, 0.003, 0.01)
        t = {"viscoelastic": {"ratio": m, "relaxation_time": tau1},
             "viscoelastic2": {"ratio": loguniform(rng, lo, hi),
                               "relaxation_time": tau1 * rng.uniform(8.0, 30.0)}}
    elif term == "material.nonlinear":
        t = {}                              # the user's model linearises the law
    else:
        raise ValueError(f"unknown term {term!r}")
    return t, {"term": term, "magnitude": m, "range": [lo, hi]}


def _merge(a: dict, b: dict) -> dict:
    """Truth settings of two terms together (regions appended, sub-tables merged)."""
    out = dict(a)
    for k, v in b.items():
        if k == "regions":
            out[k] = out.get(k, []) + v
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = {**out[k], **v}
        else:
            out[k] = v
    return out


def excitation(rng: np.random.Generator, geom: dict, kind: str, scale: float = 1.0,
               first: float | None = None) -> dict:
    """The excitation ``kind``, transverse to the body's axis in a drawn direction (expressions
    of x, y, z and t): an initial velocity growing as s^2, a released deflection shaped as the
    cantilever's static one, s^2 (3 - s) / 2 (s the fraction of the length from the clamp), or
    the clamp translated by A sin(omega t)^3 (at rest, zero acceleration at t = 0) at
    :data:`BASE_RATIO` of ``first``, the body's first frequency (Hz, :func:`first_frequency`);
    ``scale`` multiplies the amplitude (material.nonlinear's magnitude)."""
    if "thickness" in geom and geom["axis"] == "x":
        # plate and shell: across the thickness (z) within 30 degrees; in their plane they are
        # 3-10 times stiffer, and a release there strained the strip by ~3 % (the truth's
        # Newton failed at 1 ms steps)
        angle = math.pi / 2 + rng.choice([0.0, math.pi]) + math.radians(rng.uniform(-30, 30))
    else:
        angle = rng.uniform(0.0, 2 * math.pi)
    c, sn = math.cos(angle), math.sin(angle)
    coord, length = geom["axis"], geom["length"]
    comps = [0.0, c, sn] if coord == "x" else [c, sn, 0.0]
    s = f"({coord}/{length:.6g})"
    out = {"kind": kind, "direction_deg": math.degrees(angle), "base": None}
    if kind == "velocity":
        amp, shape = loguniform(rng, *VELOCITY_TIP) * scale, f"{s}**2"
    elif kind == "release":
        # Euler-Bernoulli kinematics: the transverse deflection w = A s^2 (3 - s) / 2 and the
        # sections turned by w' about the neutral axis (a transverse field alone would shear
        # the body by w' ~ 3 A / L: a release with most of its energy in shear)
        amp = loguniform(rng, *RELEASE_TIP) * scale
        c0 = neutral_axis(geom)
        arm = "+".join(f"({k:.6g})*({x}-({x0:.6g}))" for k, x, x0 in zip(
            comps, "xyz", c0, strict=True) if abs(k) > 1e-12)
        slope = f"{3 * amp / (2 * length):.6g}*{s}*(2-{s})"
        axial = f"-{slope}*({arm})"
        shape = f"{s}**2*(3-{s})/2"
    elif kind == "base":
        amp = loguniform(rng, *BASE_AMPLITUDE) * scale
        if first is None or not first > 0:
            raise ValueError("a base motion needs the body's first frequency (> 0)")
        omega = 2 * math.pi * first * rng.uniform(*BASE_RATIO)
        shape = f"sin({omega:.6g}*t)**3"
        out["base"] = {"direction": comps, "amplitude": amp, "omega": float(f"{omega:.6g}"),
                       "first_frequency_estimate": first}
    else:
        raise ValueError(f"excitation {kind!r}; valid: {', '.join(EXCITATIONS)}")
    exprs = ["0" if abs(k) < 1e-12 else f"{amp * k:.6g}*{shape}" for k in comps]
    if kind == "release":
        exprs["xyz".index(coord)] = axial
    zero = ["0", "0", "0"]
    return out | {"amplitude": amp,
                  "velocity": exprs if kind == "velocity" else zero,
                  "displacement": exprs if kind == "release" else zero,
                  "clamp_displacement": exprs if kind == "base" else None}


def draw_case(seed: int, index: int, size: str = "small") -> dict:
    """Case ``index`` of the draw ``seed`` (JSON-serialisable): everything random_cases.py
    needs to mesh, simulate and write it."""
    if size not in SIZES:
        raise ValueError(f"size {size!r}; valid: {', '.join(SIZES)}")
    if seed < 0 or index < 0:
        raise ValueError("seed and index must be >= 0")
    rng = np.random.default_rng([seed, index])
    category = PATTERN[index % len(PATTERN)]
    family = FAMILIES[rng.integers(len(FAMILIES))]
    geom = draw_geometry(rng, family)
    sz = SIZES[size]
    material = {"youngs_modulus": loguniform(rng, *E_RANGE),
                "poisson_ratio": rng.uniform(*NU_RANGE), "density": rng.uniform(*RHO_RANGE)}
    # the shell is not released: from its released shape the truth's Newton inverted cells at
    # the 1 ms steps of its error check (r002 of draw 1, before this rule)
    kinds = {k: p for k, p in EXCITATIONS.items() if not (family == "shell" and k == "release")}
    kind = str(rng.choice(list(kinds), p=np.array(list(kinds.values())) / sum(kinds.values())))
    # a moving clamp is rigid here (generate.py's Winkler clamp does not move)
    vocab = [t for t in VOCABULARY if not (kind == "base" and t == "boundary.compliance")]
    if category == "control":
        terms = []
    elif category == "one":
        terms = [vocab[rng.integers(len(vocab))]]
    elif category == "two":
        terms = [vocab[i] for i in sorted(rng.choice(len(vocab), 2, replace=False))]
    else:
        terms = [OFF_VOCABULARY[rng.integers(len(OFF_VOCABULARY))]]
    truth, magnitudes = {}, []
    for term in terms:
        t, mag = effect(rng, term, geom, material)
        truth = _merge(truth, t)
        magnitudes.append(mag)
    scale = next((m["magnitude"] for m in magnitudes if m["term"] == "material.nonlinear"), 1.0)
    exc = excitation(rng, geom, kind, scale, first_frequency(family, geom, material))
    frames = int(round(rng.uniform(*sz["end"]) / STEP))
    return {
        "name": f"r{index:03d}-{family}", "seed": [seed, index], "index": index, "size": size,
        "category": category, "family": family, "geometry": geom, "material": material,
        "concealed": terms, "magnitudes": magnitudes, "truth": truth, "excitation": exc,
        "gravity": GRAVITY,
        "user": {"model": "linear" if "material.nonlinear" in terms else "neohookean",
                 "gravity": [0.0, 0.0, 0.0] if "gravity" in terms else GRAVITY,
                 "youngs_modulus": material["youngs_modulus"]
                 * (1 + rng.uniform(-E_START_OFF, E_START_OFF))},
        "user_tets": int(rng.integers(sz["tets"][0], sz["tets"][1] + 1)),
        "markers": int(rng.integers(MARKER_RANGE[0], MARKER_RANGE[1] + 1)),
        # the noise's std is this fraction of the truth's motion (noise_level, once the truth
        # is simulated)
        "noise_fraction": loguniform(rng, *NOISE_FRACTION),
        "dropout": rng.uniform(*DROPOUT_RANGE),
        "occluded": rng.uniform(*OCCLUDED_RANGE),
        "end": round(frames * STEP, 6),
    }


def draw(seed: int, n: int, size: str = "small") -> list[dict]:
    """The N cases of draw ``seed``."""
    if n < 1:
        raise ValueError(f"N must be >= 1, got {n}")
    return [draw_case(seed, i, size) for i in range(n)]


def corrupt(clean: np.ndarray, case: dict) -> tuple[np.ndarray, dict]:
    """Noise, dropped samples and occluded stretches on clean marker positions (frames, K, 3),
    from the generator seeded by ``(seed, index, 2)``; returns the recording's positions and
    what was hidden."""
    rng = np.random.default_rng([*case["seed"], 2])
    frames, k = clean.shape[:2]
    noisy = clean + rng.normal(0.0, case["noise"], clean.shape)
    hidden = rng.random((frames, k)) < case["dropout"]
    dropped = int(hidden.sum())
    occluded = rng.choice(k, size=int(round(case["occluded"] * k)), replace=False)
    stretches = []
    for m in np.sort(occluded):
        length = max(1, int(round(rng.uniform(*STRETCH_RANGE) * frames)))
        start = int(rng.integers(0, frames - length + 1))
        hidden[start:start + length, m] = True
        stretches.append([int(m), start, length])
    noisy[hidden] = np.nan
    return noisy, {"position_std": case["noise"], "dropout": case["dropout"],
                   "dropped_samples": dropped, "occluded_stretches": stretches,
                   "hidden_samples": int(hidden.sum())}
