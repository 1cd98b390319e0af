"""User-facing errors.

Every mistake a user can make (a bad experiment file, a broken mesh, an inverted element) raises a
subclass of :class:`PetsoftError` whose message says what is wrong, where (file, key, line,
element, node) and what would be valid. The command line prints the message without a traceback
and exits with status 2; anything else is a bug in petsoft and keeps its traceback.
"""


class PetsoftError(Exception):
    """Base class of errors caused by user input, reported without a traceback."""


class ExperimentError(PetsoftError, ValueError):
    """An experiment file (TOML) is malformed, has unknown keys or out-of-range values (also a
    ``ValueError``, as a bad argument value is in Python)."""


class ExpressionError(ExperimentError):
    """An expression in an experiment file cannot be parsed or uses something not allowed."""


class MeshError(PetsoftError):
    """A mesh cannot be used: no tetrahedra, degenerate/inverted cells, bad coordinates..."""


class InvertedElementError(PetsoftError):
    """A deformation inverted an element (J <= 0) where the material law is undefined.

    Parameters
    ----------
    element : int
        Index of the first inverted element (in the numbering of the caller's arrays; assembly
        translates it to the global element number before the message reaches a user).
    jacobian : float
        The determinant of the deformation gradient found there.
    """

    def __init__(self, element: int, jacobian: float, message: str | None = None):
        self.element = int(element)
        self.jacobian = float(jacobian)
        super().__init__(
            message
            or f"element {self.element} is inverted (det F = {self.jacobian:.3e} <= 0): the "
            "material law is undefined there; reduce the load step or time step"
        )


class SolverError(PetsoftError):
    """A PETSc solver (SNES, KSP, TAO, TS) diverged; the message says where and why."""


def without_frames(err: BaseException) -> BaseException:
    """``err`` (returned) with the tracebacks of it and of the exceptions chained to it dropped.

    An error a solver keeps to report later (an inverted trial element) must not keep the
    frames it was raised through: those of a PETSc callback hold the SNES or TS and its vectors,
    and on the rank that raised it only. Their destruction then waits for a garbage collection
    that comes at different moments on different ranks, while destroying a parallel direct
    solver (MUMPS) is collective: 2 ranks hung (tests/test_static_robustness.py).
    """
    stack, seen = [err], set()
    while stack:
        e = stack.pop()
        if e is None or id(e) in seen:
            continue
        seen.add(id(e))
        e.__traceback__ = None
        stack += [e.__context__, e.__cause__]
    return err
