"""The safe expression language of experiment files.

This module owns the small arithmetic language users write in experiment files (regions, boundary
conditions, initial conditions, tractions; formats.md section 1)::

    where = "(x - 0.3)**2 + (z - 0.02)**2 < 0.01**2"
    displacement = ["0", "0", "0.01*sin(20*t)"]

An expression is parsed with Python's :mod:`ast` module (parsing only: nothing is ever compiled to
code, ``eval``-ed or ``exec``-ed) and translated into a tree of a few whitelisted node types, which
is evaluated with numpy ufuncs over whole arrays of points at once. Everything outside the
whitelist is rejected with an :class:`~petsoft.errors.ExpressionError` naming the source (file and
key), the expression, the offending token and what is allowed.

The language
------------
* numbers (``1``, ``2.5``, ``1e-6``), the constant ``pi``, the variables (by default x, y, z, t);
* ``+ - * / **``, unary ``-`` and ``+``, parentheses;
* comparisons ``< <= > >= == !=``, chained as in Python (``0 < x < 1``), giving conditions;
* ``and``, ``or``, ``not`` on conditions, elementwise;
* functions ``sin cos tan exp log sqrt abs`` (one argument) and ``min max`` (two or more,
  elementwise).

Conditions used in arithmetic count as 1 (true) and 0 (false), so ``0.01*(x > 0.2)`` is a step;
``and``/``or``/``not`` accept only conditions, which catches ``where = "x and y"`` mistakes.

Safety
------
* Input is limited to :data:`MAX_LENGTH` characters and the tree to :data:`MAX_DEPTH` levels, so
  neither parsing nor the (recursive) evaluation can exhaust the stack.
* All arithmetic is IEEE float64 in numpy, never Python integers, so ``9**9**9**9`` takes
  microseconds (it overflows to inf) instead of hanging the process computing a huge integer.
* Maximal constant sub-expressions are folded once at parse time and must be finite, so an
  overflowing constant such as ``9**9**9**9`` or ``log(0)`` is an error when the file is loaded.
* At evaluation a numeric result that is NaN or infinite where all inputs are finite, or a NaN
  compared in a condition, raises an :class:`~petsoft.errors.ExpressionError` that names the
  sub-expression that first went non-finite and the point where it did (``sqrt`` of a negative
  number, ``log(0)``, a division by zero, an overflow). Intermediate infinities that the expression
  itself resolves, as in ``exp(-1/x**2)`` at ``x = 0``, are allowed.
"""

from __future__ import annotations

import ast
import difflib
import functools
import math
from collections.abc import Iterable, Mapping

import numpy as np

from petsoft.errors import ExpressionError

__all__ = [
    "FUNCTIONS",
    "MAX_DEPTH",
    "MAX_LENGTH",
    "Expression",
    "parse_expression",
]

#: Longest accepted expression, in characters.
MAX_LENGTH = 1000
#: Deepest accepted syntax tree (a sum of n terms is n levels deep).
MAX_DEPTH = 100

#: The callable functions: name -> (numpy function, minimum and maximum number of arguments).
FUNCTIONS: dict[str, tuple[np.ufunc, int, int | None]] = {
    "sin": (np.sin, 1, 1),
    "cos": (np.cos, 1, 1),
    "tan": (np.tan, 1, 1),
    "exp": (np.exp, 1, 1),
    "log": (np.log, 1, 1),
    "sqrt": (np.sqrt, 1, 1),
    "abs": (np.absolute, 1, 1),
    "min": (np.minimum, 2, None),
    "max": (np.maximum, 2, None),
}
_CONSTANTS = {"pi": math.pi}

_BINARY = {
    ast.Add: np.add,
    ast.Sub: np.subtract,
    ast.Mult: np.multiply,
    ast.Div: np.true_divide,
    ast.Pow: np.power,
}
_COMPARE = {
    ast.Lt: np.less,
    ast.LtE: np.less_equal,
    ast.Gt: np.greater,
    ast.GtE: np.greater_equal,
    ast.Eq: np.equal,
    ast.NotEq: np.not_equal,
}
_OP_SYMBOL = {
    ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**",
    ast.Mod: "%", ast.FloorDiv: "//", ast.MatMult: "@", ast.BitAnd: "&", ast.BitOr: "|",
    ast.BitXor: "^", ast.LShift: "<<", ast.RShift: ">>", ast.Invert: "~",
    ast.In: "in", ast.NotIn: "not in", ast.Is: "is", ast.IsNot: "is not",
}  # fmt: skip
_OP_HINT = {
    ast.BitXor: "; write powers as x**2",
    ast.BitAnd: "; combine conditions with `and`",
    ast.BitOr: "; combine conditions with `or`",
    ast.Invert: "; negate a condition with `not`",
    ast.Is: "; compare with == or !=",
    ast.IsNot: "; compare with == or !=",
}
_NODE_NAME = {
    ast.Attribute: "attribute access",
    ast.Subscript: "indexing",
    ast.Slice: "slicing",
    ast.Lambda: "lambda",
    ast.List: "list",
    ast.Tuple: "tuple",
    ast.Dict: "dict",
    ast.Set: "set",
    ast.ListComp: "comprehension",
    ast.SetComp: "comprehension",
    ast.DictComp: "comprehension",
    ast.GeneratorExp: "generator",
    ast.IfExp: "conditional expression (a if c else b)",
    ast.NamedExpr: "assignment (:=)",
    ast.JoinedStr: "f-string",
    ast.FormattedValue: "f-string",
    ast.Starred: "unpacking (*)",
    ast.Await: "await",
    ast.Yield: "yield",
    ast.YieldFrom: "yield",
}


def _allowed_text(variables: Iterable[str]) -> str:
    names = ", ".join(variables) or "(none)"
    return (
        f"allowed: numbers, the variables {names}, the constant pi, + - * / ** and unary -, "
        "parentheses, comparisons < <= > >= == != (chainable), and/or/not, and the functions "
        + " ".join(FUNCTIONS)
        + " (min and max take two or more arguments)"
    )


# ------------------------------------------------------------------------------------------------
# The whitelisted tree. Each node knows its source text (for messages) and whether it yields a
# number or a condition; ``ev`` evaluates it on a dict of float64 arrays.


class _Node:
    __slots__ = ("text", "is_bool")

    def __init__(self, text: str, is_bool: bool):
        self.text = text
        self.is_bool = is_bool

    def children(self) -> tuple[_Node, ...]:
        return ()

    def ev(self, env: Mapping[str, np.ndarray]) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


class _Const(_Node):
    __slots__ = ("value",)

    def __init__(self, text: str, value: np.ndarray):
        super().__init__(text, value.dtype == np.bool_)
        self.value = value

    def ev(self, env):
        return self.value


class _Var(_Node):
    __slots__ = ("name",)

    def __init__(self, name: str):
        super().__init__(name, False)
        self.name = name

    def ev(self, env):
        return env[self.name]


class _Apply(_Node):
    """A numeric function of numeric arguments: unary/binary operators and calls."""

    __slots__ = ("func", "args")

    def __init__(self, text: str, func, args: tuple[_Node, ...]):
        super().__init__(text, False)
        self.func = func
        self.args = args

    def children(self):
        return self.args

    def ev(self, env):
        values = [_as_number(a.ev(env)) for a in self.args]
        if len(values) > 2:  # min/max of several arguments
            return functools.reduce(self.func, values)
        return self.func(*values)


class _Compare(_Node):
    """A (chained) comparison; a NaN operand is an error rather than a silent False."""

    __slots__ = ("funcs", "operands")

    def __init__(self, text: str, funcs: tuple, operands: tuple[_Node, ...]):
        super().__init__(text, True)
        self.funcs = funcs
        self.operands = operands

    def children(self):
        return self.operands

    def ev(self, env):
        values = [_as_number(o.ev(env)) for o in self.operands]
        for o, v in zip(self.operands, values, strict=True):
            nan = np.isnan(v)
            if nan.any():
                ok = env.get(_MASK)
                if ok is not None:  # ignore NaN that came from non-finite inputs
                    nan = nan & ok
                if nan.any():
                    raise _NotFinite(o, nan)
        result = self.funcs[0](values[0], values[1])
        for f, a, b in zip(self.funcs[1:], values[1:-1], values[2:], strict=True):
            result = np.logical_and(result, f(a, b))
        return result


class _Logic(_Node):
    """``and``/``or`` (func is logical_and/logical_or) or ``not`` (func is logical_not)."""

    __slots__ = ("func", "args")

    def __init__(self, text: str, func, args: tuple[_Node, ...]):
        super().__init__(text, True)
        self.func = func
        self.args = args

    def children(self):
        return self.args

    def ev(self, env):
        values = [a.ev(env) for a in self.args]
        if len(values) == 1:
            return self.func(values[0])
        return functools.reduce(self.func, values)


class _NotFinite(Exception):
    """Internal: a comparison met a NaN operand (``node``) at the points ``mask``."""

    def __init__(self, node: _Node, mask: np.ndarray):
        self.node = node
        self.mask = mask


#: Key of the evaluation environment holding the mask of points with finite inputs (or None when
#: all are finite); the empty string cannot clash with a variable name.
_MASK = ""


def _as_number(value: np.ndarray) -> np.ndarray:
    # Conditions in arithmetic count as 0/1; numpy refuses e.g. unary minus on booleans.
    return value.astype(np.float64) if value.dtype == np.bool_ else value


def _first_nonfinite(node: _Node, env: Mapping[str, np.ndarray], nan_only: bool) -> _Node | None:
    """The innermost sub-expression of ``node`` whose value at the single point ``env`` is NaN
    (``nan_only``) or non-finite while its operands are not: where things went wrong."""
    for child in node.children():
        bad = _first_nonfinite(child, env, nan_only)
        if bad is not None:
            return bad
    try:
        value = node.ev(env)
    except _NotFinite as exc:  # pragma: no cover - its operands were checked first
        return exc.node
    if value.dtype == np.bool_:
        return None
    if nan_only:
        return node if np.isnan(value).any() else None
    return None if np.isfinite(value).all() else node


# ------------------------------------------------------------------------------------------------


class Expression:
    """A parsed, whitelisted expression, evaluated elementwise with numpy.

    Create one with :func:`parse_expression`.

    Attributes
    ----------
    text : str
        The expression as written (numbers are kept as their ``str``).
    variables : frozenset of str
        The variables the expression uses (a subset of :attr:`allowed_variables`).
    allowed_variables : tuple of str
        The variables it was allowed to use.
    source : str
        Where it came from, e.g. ``"exp.toml: boundary[0].where"``, for messages.
    is_constant : bool
        True when it uses no variable; its value is then :attr:`constant_value`.
    is_boolean : bool
        True for a condition (a comparison or and/or/not of them); evaluates to bool arrays.
    literal : str, int or float
        The value given to :func:`parse_expression`, kept so files can be written back as they
        were (a number stays a number).
    """

    __slots__ = ("text", "variables", "allowed_variables", "source", "literal", "_tree")

    def __init__(self, text, variables, allowed_variables, source, literal, tree: _Node):
        self.text: str = text
        self.variables: frozenset[str] = variables
        self.allowed_variables: tuple[str, ...] = allowed_variables
        self.source: str = source
        self.literal: str | int | float = literal
        self._tree = tree

    @property
    def is_constant(self) -> bool:
        return not self.variables

    @property
    def is_boolean(self) -> bool:
        return self._tree.is_bool

    @property
    def constant_value(self) -> float | bool | None:
        """The value of a constant expression (a float, or a bool for a condition), else None."""
        if not isinstance(self._tree, _Const):
            return None
        return self._tree.value.item()

    def evaluate(self, **values) -> np.ndarray:
        """Evaluate elementwise at the given variable values.

        Parameters
        ----------
        **values : array_like
            Values of the variables (any of :attr:`allowed_variables`; those in
            :attr:`variables` are required). They broadcast against each other like numpy
            arrays; a scalar is fine (``t=0.5``).

        Returns
        -------
        numpy.ndarray
            A new float64 array (bool for a condition) of the broadcast shape of all given
            values, a 0-d array if none was given; a constant expression is broadcast too.

        Raises
        ------
        ExpressionError
            If the result is NaN or infinite at a point where all inputs are finite, or a
            condition compares a NaN there; the message names the sub-expression that first
            went wrong and the point.
        TypeError
            If a used variable is missing or an unknown variable is passed (a caller's bug).
        """
        unknown = set(values) - set(self.allowed_variables)
        if unknown:
            raise TypeError(
                f"{self.source}: evaluate() got unknown variable(s) {sorted(unknown)}; "
                f"this expression allows {list(self.allowed_variables)}"
            )
        missing = self.variables - set(values)
        if missing:
            raise TypeError(
                f"{self.source}: evaluate() is missing variable(s) {sorted(missing)} used by "
                f"{self.text!r}"
            )
        env: dict[str, np.ndarray | None] = {
            name: np.asarray(v, dtype=np.float64) for name, v in values.items()
        }
        shape = np.broadcast_shapes(*(v.shape for v in env.values()))
        # Points where an input is already non-finite are not the expression's fault: they are
        # excluded from the checks (the key "" cannot clash with a variable name).
        inputs_ok = None
        if not all(np.isfinite(v).all() for v in env.values()):
            inputs_ok = np.ones(shape, dtype=bool)
            for v in env.values():
                inputs_ok &= np.isfinite(v)
        env[_MASK] = inputs_ok
        try:
            with np.errstate(all="ignore"):  # non-finite values are reported below, not warned
                result = self._tree.ev(env)
        except _NotFinite as exc:
            self._raise_not_finite(env, shape, exc.node, np.broadcast_to(exc.mask, shape), True)
        if result.dtype != np.bool_:
            finite = np.isfinite(result)
            if not finite.all():
                bad = ~np.broadcast_to(finite, shape)
                if inputs_ok is not None:
                    bad = bad & inputs_ok
                if bad.any():
                    self._raise_not_finite(env, shape, self._tree, bad, False)
            result = result.astype(np.float64, copy=False)
        if (
            result.shape == shape
            and result.flags.owndata
            and result.flags.writeable
            and not any(result is v for v in env.values())
        ):
            return result
        return np.array(np.broadcast_to(result, shape))

    def evaluate_at(self, points, t: float | None = None) -> np.ndarray:
        """Evaluate at an ``(n, 3)`` array of points (x, y, z columns) and optionally time ``t``.

        Returns an array of shape ``(n,)``. Only the variables the expression allows are passed.
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must have shape (n, 3), got {p.shape}")
        values = {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2]}
        if t is not None:
            values["t"] = t
        values = {k: v for k, v in values.items() if k in self.allowed_variables}
        out = self.evaluate(**values)
        return np.array(np.broadcast_to(out, (p.shape[0],)))

    def _raise_not_finite(self, env, shape, node: _Node, bad: np.ndarray, nan_only: bool):
        """Report the first point of ``bad`` and the sub-expression of ``node`` that went
        non-finite there first (a vectorised search for the point, a scalar trace for the node).
        """
        index = int(np.flatnonzero(bad.ravel())[0])
        count = int(np.count_nonzero(bad))
        point = {
            k: float(np.broadcast_to(v, shape).ravel()[index]) for k, v in env.items() if k != _MASK
        }
        scalar_env = {k: np.asarray(v) for k, v in point.items()}
        with np.errstate(all="ignore"):
            value = node.ev(scalar_env)
            if not nan_only:
                nan_only = bool(np.isnan(value))
            culprit = _first_nonfinite(node, scalar_env, nan_only) or node
            value = culprit.ev(scalar_env)
        where = ", ".join(f"{k}={v:.6g}" for k, v in sorted(point.items())) or "(no variables)"
        more = f" (and at {count - 1} more of {bad.size} points)" if count > 1 else ""
        raise ExpressionError(
            f"{self.source}: expression {self.text!r} is not finite: `{culprit.text}` "
            f"evaluates to {_fmt_value(value)} at {where}{more}; check the domain of sqrt and "
            "log, divisions by zero and overflow in ** and exp"
        )

    def __eq__(self, other):
        if not isinstance(other, Expression):
            return NotImplemented
        return self.text == other.text and self.allowed_variables == other.allowed_variables

    def __hash__(self):
        return hash((self.text, self.allowed_variables))

    def __repr__(self):
        return f"Expression({self.text!r}, variables={sorted(self.variables)})"

    def __str__(self):
        return self.text

    def __reduce__(self):
        # Pickle by re-parsing (e.g. for mpi4py broadcasts): the tree holds no state of its own.
        return (_rebuild, (self.literal, self.source, self.allowed_variables))


def _rebuild(literal, source, variables):
    return parse_expression(literal, source=source, variables=variables)


def _fmt_value(value: np.ndarray) -> str:
    v = np.asarray(value).ravel()
    return str(v[0]) if v.size else "nothing"


# ------------------------------------------------------------------------------------------------


class _Translator:
    """Translates a Python ``ast`` expression into the whitelisted tree, or raises."""

    def __init__(self, text: str, source: str, variables: tuple[str, ...]):
        self.text = text
        self.source = source
        self.variables = variables
        self.used: set[str] = set()

    def fail(self, what: str, node: ast.AST | None = None, token: str | None = None) -> None:
        if token is None and node is not None:
            token = ast.get_source_segment(self.text, node)
        at = ""
        if node is not None and getattr(node, "col_offset", None) is not None:
            at = f" at column {node.col_offset + 1}"
        tok = f" `{token}`" if token else ""
        raise ExpressionError(
            f"{self.source}: {what}{tok}{at} in expression {self.text!r}; "
            f"{_allowed_text(self.variables)}"
        )

    def segment(self, node: ast.AST) -> str:
        return ast.get_source_segment(self.text, node) or ast.unparse(node)

    def node(self, node: ast.AST, depth: int) -> _Node:
        if depth > MAX_DEPTH:
            self.fail(f"expression is nested deeper than {MAX_DEPTH} levels", node, token="")
        d = depth + 1
        if isinstance(node, ast.Constant):
            return self.constant(node)
        if isinstance(node, ast.Name):
            return self.name(node)
        if isinstance(node, ast.UnaryOp):
            if isinstance(node.op, ast.Not):
                operand = self.condition(node.operand, d, "not")
                return _Logic(self.segment(node), np.logical_not, (operand,))
            if isinstance(node.op, (ast.USub, ast.UAdd)):
                operand = self.node(node.operand, d)
                if isinstance(node.op, ast.UAdd):
                    return operand if not operand.is_bool else self.to_number(operand)
                return _Apply(self.segment(node), np.negative, (operand,))
            self.operator(node.op, node)
        if isinstance(node, ast.BinOp):
            func = _BINARY.get(type(node.op))
            if func is None:
                self.operator(node.op, node)
            left = self.node(node.left, d)
            right = self.node(node.right, d)
            return _Apply(self.segment(node), func, (left, right))
        if isinstance(node, ast.Compare):
            funcs = []
            for op in node.ops:
                f = _COMPARE.get(type(op))
                if f is None:
                    self.operator(op, node)
                funcs.append(f)
            operands = tuple(self.node(o, d) for o in [node.left, *node.comparators])
            return _Compare(self.segment(node), tuple(funcs), operands)
        if isinstance(node, ast.BoolOp):
            word = "and" if isinstance(node.op, ast.And) else "or"
            func = np.logical_and if word == "and" else np.logical_or
            args = tuple(self.condition(v, d, word) for v in node.values)
            return _Logic(self.segment(node), func, args)
        if isinstance(node, ast.Call):
            return self.call(node, d)
        name = _NODE_NAME.get(type(node), type(node).__name__)
        self.fail(f"{name} is not allowed:", node)
        raise AssertionError  # unreachable, for type checkers

    def operator(self, op: ast.AST, node: ast.AST) -> None:
        symbol = _OP_SYMBOL.get(type(op), type(op).__name__)
        hint = _OP_HINT.get(type(op), "")
        self.fail(f"operator `{symbol}` is not allowed{hint}; found in", node)

    def to_number(self, n: _Node) -> _Node:
        return _Apply(n.text, np.positive, (n,)) if n.is_bool else n

    def condition(self, node: ast.AST, depth: int, word: str) -> _Node:
        n = self.node(node, depth)
        if not n.is_bool:
            self.fail(
                f"`{word}` combines conditions (comparisons such as x < 1), but got the number",
                node,
            )
        return n

    def constant(self, node: ast.Constant) -> _Node:
        value = node.value
        text = self.segment(node)
        if isinstance(value, bool) or value is None or value is Ellipsis:
            self.fail(
                f"the literal {value!r} is not allowed (use a comparison for conditions):", node
            )
        if isinstance(value, (str, bytes)):
            self.fail("strings are not allowed:", node)
        if isinstance(value, complex):
            self.fail("complex numbers are not allowed:", node)
        if not isinstance(value, (int, float)):  # pragma: no cover - no other literal kinds
            self.fail("this literal is not allowed:", node)
        try:
            number = float(value)
        except OverflowError:
            number = math.inf
        if not math.isfinite(number):
            self.fail("the number is too large (not a finite float64):", node)
        return _Const(text, np.asarray(number, dtype=np.float64))

    def name(self, node: ast.Name) -> _Node:
        name = node.id
        if name in self.variables:
            self.used.add(name)
            return _Var(name)
        if name in _CONSTANTS:
            return _Const(name, np.asarray(_CONSTANTS[name], dtype=np.float64))
        if name in FUNCTIONS:
            self.fail(f"`{name}` is a function: call it as {name}(...); found", node, token=name)
        if name in ("x", "y", "z", "t"):
            self.fail(
                f"the variable `{name}` is not available here (this expression may use "
                f"{', '.join(self.variables) or 'no variables'}); found",
                node,
                token=name,
            )
        known = [*self.variables, *_CONSTANTS]
        lower = [k for k in known if k.lower() == name.lower()]
        close = lower or difflib.get_close_matches(name, [*known, *FUNCTIONS], n=1, cutoff=0.6)
        hint = f" (did you mean `{close[0]}`?)" if close else ""
        self.fail(f"unknown name{hint}:", node, token=name)
        raise AssertionError  # unreachable

    def call(self, node: ast.Call, depth: int) -> _Node:
        if not isinstance(node.func, ast.Name):
            # Report what the callee is (a lambda, an attribute...) when it is itself forbidden.
            self.node(node.func, depth)
            self.fail("only the listed functions can be called; found the call of", node.func)
        name = node.func.id
        if name not in FUNCTIONS:
            what = (
                "is not a function"
                if name in self.variables or name in _CONSTANTS
                else ("is not an allowed function")
            )
            close = difflib.get_close_matches(name, list(FUNCTIONS), n=1, cutoff=0.6)
            hint = f" (did you mean `{close[0]}`?)" if close else ""
            self.fail(f"`{name}` {what}{hint}; found", node.func, token=name)
        if node.keywords:
            kw = node.keywords[0]
            self.fail(
                "keyword arguments are not allowed:", kw, token=f"{kw.arg}=" if kw.arg else "**"
            )
        func, lo, hi = FUNCTIONS[name]
        for a in node.args:
            if isinstance(a, ast.Starred):
                self.fail("unpacking (*) is not allowed:", a)
        n = len(node.args)
        if n < lo or (hi is not None and n > hi):
            want = f"exactly {lo}" if lo == hi else f"at least {lo}"
            self.fail(f"`{name}` takes {want} argument(s), got {n}:", node)
        args = tuple(self.node(a, depth) for a in node.args)
        return _Apply(self.segment(node), func, args)


def _fold(node: _Node) -> _Node:
    """Replace maximal variable-free sub-trees by their value, which must be finite."""
    if isinstance(node, (_Const, _Var)):
        return node
    if not _uses_variables(node):
        try:
            with np.errstate(all="ignore"):
                value = node.ev({})
        except _NotFinite as exc:
            raise _ConstantNotFinite(_first_nonfinite(exc.node, {}, True) or exc.node) from None
        if value.dtype != np.bool_ and not np.isfinite(value).all():
            with np.errstate(all="ignore"):
                bad = _first_nonfinite(node, {}, bool(np.isnan(value)))
            raise _ConstantNotFinite(bad or node)
        return _Const(node.text, np.asarray(value))
    if isinstance(node, _Apply):
        node.args = tuple(_fold(a) for a in node.args)
    elif isinstance(node, _Compare):
        node.operands = tuple(_fold(o) for o in node.operands)
    elif isinstance(node, _Logic):
        node.args = tuple(_fold(a) for a in node.args)
    return node


class _ConstantNotFinite(Exception):
    def __init__(self, node: _Node):
        self.node = node


def _uses_variables(node: _Node) -> bool:
    if isinstance(node, _Var):
        return True
    return any(_uses_variables(c) for c in node.children())


def parse_expression(
    text: str | int | float,
    *,
    source: str = "<expression>",
    variables: Iterable[str] = ("x", "y", "z", "t"),
    expect: str | None = None,
) -> Expression:
    """Parse an expression of the experiment-file language.

    Parameters
    ----------
    text : str, int or float
        The expression; a number is accepted as a constant expression.
    source : str
        Where the expression comes from, e.g. ``"exp.toml: boundary[0].where"``; every error
        message starts with it.
    variables : iterable of str
        The variable names the expression may use.
    expect : {"number", "condition"}, optional
        Require a numeric expression or a condition (comparison, and/or/not).

    Returns
    -------
    Expression

    Raises
    ------
    ExpressionError
        For anything outside the language, with the source, the expression, the offending token
        and the list of what is allowed; for a constant part that is not finite; for the wrong
        kind (number/condition) when ``expect`` is given.
    """
    variables = tuple(variables)
    for v in variables:
        if not v.isidentifier() or v in FUNCTIONS or v in _CONSTANTS:
            raise ValueError(f"invalid variable name {v!r}")
    literal = text
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        raise ExpressionError(
            f'{source}: expected an expression (a string such as "0.01*sin(20*t)") or a '
            f"number, got {text!r} of type {type(text).__name__}"
        )
    if not isinstance(text, str):
        if not math.isfinite(text):
            raise ExpressionError(f"{source}: {text!r} is not a finite number")
        text = str(text)
    if len(text) > MAX_LENGTH:
        raise ExpressionError(
            f"{source}: expression is {len(text)} characters long, the limit is {MAX_LENGTH}: "
            f"{text[:60]!r}..."
        )
    stripped = text.strip()
    if not stripped:
        raise ExpressionError(f"{source}: the expression is empty; {_allowed_text(variables)}")
    try:
        tree = ast.parse(stripped, mode="eval")
    except SyntaxError as exc:
        hint = ""
        if "=" in stripped and "==" not in stripped and not any(c + "=" in stripped for c in "<>!"):
            hint = " (compare with ==, not =)"
        col = f" at column {exc.offset}" if exc.offset else ""
        raise ExpressionError(
            f"{source}: syntax error{col} in expression {stripped!r}: {exc.msg}{hint}; "
            f"{_allowed_text(variables)}"
        ) from None
    except (ValueError, RecursionError, MemoryError) as exc:  # null bytes, pathological nesting
        raise ExpressionError(
            f"{source}: cannot parse expression {stripped[:60]!r}: {exc}; "
            f"{_allowed_text(variables)}"
        ) from None
    translator = _Translator(stripped, source, variables)
    root = translator.node(tree.body, 1)
    try:
        root = _fold(root)
    except _ConstantNotFinite as exc:
        with np.errstate(all="ignore"):
            value = exc.node.ev({})
        raise ExpressionError(
            f"{source}: in expression {stripped!r}, `{exc.node.text}` evaluates to "
            f"{_fmt_value(value)} (not finite): check for overflow in ** and exp, sqrt and log of "
            "negative numbers, and division by zero"
        ) from None
    expr = Expression(stripped, frozenset(translator.used), variables, source, literal, root)
    if expect == "condition" and not expr.is_boolean:
        raise ExpressionError(
            f'{source}: expected a condition (a comparison such as "x < 1e-6", combined with '
            f"and/or/not), got the number-valued expression {stripped!r}"
        )
    if expect == "number" and expr.is_boolean:
        raise ExpressionError(
            f"{source}: expected a number-valued expression, got the condition {stripped!r} "
            "(write e.g. 0.01*(x > 0.2) for a step)"
        )
    if expect not in (None, "number", "condition"):
        raise ValueError(f"expect must be None, 'number' or 'condition', not {expect!r}")
    return expr
