"""Experiment files as Python values (formats.md section 1).

The package is split by idea; this module re-exports the public names so that
``from petsoft.experiment import X`` works for all of them:

- :mod:`petsoft.experiment.spec`: the typed, frozen value (:class:`Experiment` and one dataclass
  per section) and its dict form;
- :mod:`petsoft.experiment.reader`: :func:`load_experiment`, :func:`experiment_from_dict` and the
  strict validation with its messages (the decisions the format leaves open are listed there);
- :mod:`petsoft.experiment.parameters`: the named numeric parameters of ``[calibrate]``
  (:func:`parameter_names`, :func:`get_parameter`, :func:`key_part`);
- :mod:`petsoft.experiment.changes`: validated copies with changes (:func:`with_parameters`,
  :func:`with_compliance`, :func:`with_plane_collider`);
- :mod:`petsoft.experiment.writer`: TOML text (:func:`dumps_toml`, :func:`write_toml`);
- :mod:`petsoft.experiment.ranges` and :mod:`petsoft.experiment.messages`: valid ranges of
  numbers and the pieces of error messages;
- :mod:`petsoft.experiment.expressions`: the expressions of x, y, z, t inside an experiment.
"""

from petsoft.experiment.changes import with_compliance, with_parameters, with_plane_collider
from petsoft.experiment.parameters import get_parameter, key_part, parameter_names
from petsoft.experiment.reader import experiment_from_dict, load_experiment
from petsoft.experiment.spec import (
    BOUNDARY_KINDS,
    COLLIDER_KINDS,
    COMPONENTS,
    FORMAT_VERSION,
    INTEGRATORS,
    MATERIAL_MODELS,
    BoundarySpec,
    BoxSpec,
    ColliderSpec,
    DampingSpec,
    DragSpec,
    Experiment,
    FrictionSpec,
    GravitySpec,
    InitialSpec,
    MassSpec,
    MaterialSpec,
    MeshSpec,
    OutputSpec,
    RegionSpec,
    SpringsSpec,
    TimeSpec,
    ViscoelasticSpec,
)
from petsoft.experiment.writer import dumps_toml, write_toml

__all__ = [
    "BOUNDARY_KINDS",
    "COLLIDER_KINDS",
    "COMPONENTS",
    "FORMAT_VERSION",
    "INTEGRATORS",
    "MATERIAL_MODELS",
    "BoundarySpec",
    "BoxSpec",
    "ColliderSpec",
    "DampingSpec",
    "DragSpec",
    "FrictionSpec",
    "Experiment",
    "GravitySpec",
    "InitialSpec",
    "MassSpec",
    "MaterialSpec",
    "MeshSpec",
    "OutputSpec",
    "RegionSpec",
    "SpringsSpec",
    "TimeSpec",
    "ViscoelasticSpec",
    "dumps_toml",
    "experiment_from_dict",
    "get_parameter",
    "key_part",
    "load_experiment",
    "parameter_names",
    "with_compliance",
    "with_parameters",
    "with_plane_collider",
    "write_toml",
]
