"""The material of every cell: the experiment's default and its regions' overrides."""

from __future__ import annotations

import numpy as np

from petsoft.errors import ExperimentError
from petsoft.fem.regions import RegionResolver


def cell_materials(experiment, resolver: RegionResolver):
    """Per-cell (file numbering) model, E, nu, density: the default, then region overrides."""
    ncell = len(resolver.mesh.tets)
    default = experiment.material_for(None)
    model = np.full(ncell, default.model, dtype=object)
    E = np.full(ncell, default.youngs_modulus)
    nu = np.full(ncell, default.poisson_ratio)
    rho = np.full(ncell, default.density)
    for name, spec in experiment.material.items():
        if name == "default":
            continue
        cells = resolver.cell_mask(name, key=f"material.{name}")
        if not cells.any():
            raise ExperimentError(f"{experiment.source}: material.{name}: region {name!r} "
                                  "contains no cell of the mesh")
        model[cells], E[cells], nu[cells], rho[cells] = (
            spec.model, spec.youngs_modulus, spec.poisson_ratio, spec.density)
    return model, E, nu, rho
