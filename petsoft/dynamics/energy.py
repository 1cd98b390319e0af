"""Energy bookkeeping of a simulation: what is stored, what was dissipated, what was done.

Per step: kinetic, elastic (including a viscoelastic branch's stored energy) and gravitational
energy of the state; cumulative physical dissipation (Rayleigh damping, the viscoelastic branch)
and external work (tractions and moving supports) as paired with the displacement increment by
the integrator itself. Their balance

    numerical = E(0) + external work - (kinetic + elastic + gravitational + dissipated)

is the energy the time discretisation itself removed (backward Euler's artificial damping) or
added; it is zero (to the Newton tolerance) for the discrete-gradient midpoint rule.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FIELDS = ("time", "kinetic", "elastic", "gravitational", "dissipated", "external_work",
          "numerical")


@dataclass
class EnergyLedger:
    """Rows of energies, one per step, starting with the initial state."""

    rows: list = field(default_factory=list)
    dissipated: float = 0.0
    external_work: float = 0.0
    initial: float = 0.0       # the total energy of the first row

    def record(self, system, t: float, q, v) -> dict:
        kin = system.kinetic_energy(v)
        el = system.elastic_energy(q)
        # a Maxwell branch's stored energy is elastic energy too (its dissipation is booked by
        # the steps); systems without one do not have the method
        branch = system.viscoelastic_energy
        if branch is not None:
            el += branch(q)
        grav = system.gravitational_energy(q)
        total = kin + el + grav
        if not self.rows:
            self.initial = total
        numerical = self.initial + self.external_work - (total + self.dissipated)
        row = dict(time=t, kinetic=kin, elastic=el, gravitational=grav,
                   dissipated=self.dissipated, external_work=self.external_work,
                   numerical=numerical)
        self.rows.append(row)
        return row

    def add_step(self, report) -> None:
        self.dissipated += report.dissipated
        self.external_work += report.external_work + report.boundary_work

    def array(self) -> np.ndarray:
        return np.array([[r[k] for k in FIELDS] for r in self.rows])
