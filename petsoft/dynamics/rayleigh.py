"""Rayleigh damping from the terms that declare it (issue 38, item 1).

A term contributes ``"rayleigh"`` (:data:`petsoft.terms.CONTRIBUTIONS`: ``damping.mass``,
``damping.stiffness``) when its force is minus its coefficient times a matrix the system
already has, applied to the velocity. Its builder (``Term.builds``) is a :class:`RayleighLaw`
naming that matrix: ``"mass"`` (M) or ``"reference"`` (the reference stiffness K0 of a
continuum, the springs' stiffness at rest of a network). So

    D v = alpha M v + beta K0 v,   alpha, beta = the sums of the coefficients of each matrix,

and the integrators, whose Jacobians combine M and K0 anyway, see only alpha and beta. The
residual is linear in each coefficient: its derivative is the term's matrix times v, which a
system gives by ``rayleigh_unit(matrix, v, out)``. Adding a term of this kind is its module in
:mod:`petsoft.terms` with a law here; nothing in the systems or the parameters names it.
"""

from __future__ import annotations

from dataclasses import dataclass

from petsoft.terms import builders, coefficients

#: The system matrices a Rayleigh term may be proportional to.
MATRICES = ("mass", "reference")


@dataclass(frozen=True)
class RayleighLaw:
    """What a ``"rayleigh"`` term's declaration builds: the matrix its coefficient scales."""

    matrix: str

    def __post_init__(self):
        if self.matrix not in MATRICES:
            raise ValueError(f"a Rayleigh law scales one of {MATRICES}, not {self.matrix!r}")


#: ``damping.mass``'s law: alpha M.
MASS = RayleighLaw("mass")
#: ``damping.stiffness``'s law: beta K0.
REFERENCE = RayleighLaw("reference")

#: name -> law, from the declarations (petsoft.terms, contributes "rayleigh"), in the
#: registry's order.
LAWS = {t.name: law for t, law in builders("rayleigh")}
#: Parameter names of the Rayleigh terms (calibratable; their keys' ranges apply).
NAMES = tuple(LAWS)


class RayleighDamping:
    """The Rayleigh terms' coefficients of one system.

    Parameters
    ----------
    coefficients : mapping, optional
        name (:data:`NAMES`) -> coefficient; the terms not named are 0.
    """

    def __init__(self, coefficients: dict[str, float] | None = None):
        coefficients = dict(coefficients or {})
        unknown = sorted(set(coefficients) - set(NAMES))
        if unknown:
            raise ValueError(f"no Rayleigh term {unknown} (known: {', '.join(NAMES)})")
        #: name -> coefficient (set in place by the systems' set_parameters)
        self.coef = {name: float(coefficients.get(name, 0.0)) for name in NAMES}

    @classmethod
    def of(cls, experiment) -> RayleighDamping:
        """The coefficients ``experiment`` states (``[damping] mass``, ``stiffness``)."""
        return cls(coefficients(experiment, NAMES))

    @classmethod
    def of_matrices(cls, alpha: float = 0.0, beta: float = 0.0) -> RayleighDamping:
        """alpha on the first term of the mass matrix, beta on the first of the reference
        stiffness: a system built from the two numbers rather than an experiment."""
        out = cls()
        for matrix, value in zip(MATRICES, (alpha, beta), strict=True):
            first = [n for n, law in LAWS.items() if law.matrix == matrix][:1]
            if not first and value != 0.0:
                raise ValueError(f"no Rayleigh term scales the {matrix} matrix")
            out.coef.update(dict.fromkeys(first, float(value)))
        return out

    def matrix_of(self, name: str) -> str:
        """The matrix term ``name``'s coefficient scales (:data:`MATRICES`)."""
        return LAWS[name].matrix

    def coefficient(self, matrix: str) -> float:
        """The sum of the coefficients of ``matrix``'s terms."""
        return sum(c for n, c in self.coef.items() if LAWS[n].matrix == matrix)

    @property
    def alpha(self) -> float:
        """The coefficient of M in D (1/s)."""
        return self.coefficient("mass")

    @property
    def beta(self) -> float:
        """The coefficient of K0 in D (s)."""
        return self.coefficient("reference")
