"""The small cantilever of the diagnose tests (tests/test_diagnose.py, test_diagnose_numerics.py).

A 0.3 x 0.04 x 0.04 m bar of 6 x 1 x 1 box cells (36 tets), clamped at x = 0, as experiment TOML
text: fast enough to run the whole diagnosis loop in seconds.
"""

from __future__ import annotations

#: Calibrate Young's modulus only (the user's model as given).
CALIBRATE = '[calibrate]\n"material.youngs_modulus" = [1e6, 1e8]\n'


def cantilever(E: float, *, extra: str = "", gravity: float = -9.81, end: float = 0.2,
               step: float = 0.004, integrator: str = "alpha", alpha_radius: float | None = 0.9,
               calibrate: str = "") -> str:
    """The bar's experiment text.

    Parameters
    ----------
    E : float
        Young's modulus (Pa).
    extra : str
        Further tables (``[damping]``, ``[initial]``, ...), placed after ``[material]``.
    gravity : float
        z component of the gravity (m/s^2).
    end, step, integrator, alpha_radius
        ``[time]``; ``alpha_radius`` None leaves it out (the integrator's default).
    calibrate : str
        A ``[calibrate]`` table, e.g. :data:`CALIBRATE`.
    """
    radius = "" if alpha_radius is None else f"alpha_radius = {alpha_radius}\n"
    return f"""
[mesh]
box = {{ size = [0.3, 0.04, 0.04], cells = [6, 1, 1] }}

[material]
model = "linear"
youngs_modulus = {E}
poisson_ratio = 0.3
density = 1000.0
{extra}
[gravity]
acceleration = [0.0, 0.0, {gravity}]

[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[time]
end = {end}
step = {step}
integrator = "{integrator}"
{radius}
[output]
directory = "out"
{calibrate}
"""
