"""Tests of the safe expression language (petsoft.experiment.expressions)."""

import inspect
import pickle
import time

import numpy as np
import pytest

from petsoft.errors import ExperimentError, ExpressionError, PetsoftError
from petsoft.experiment import expressions
from petsoft.experiment.expressions import MAX_DEPTH, MAX_LENGTH, parse_expression

SOURCE = "exp.toml: boundary[0].where"

rng = np.random.default_rng(0)
X = rng.uniform(0.1, 2.0, 50)
Y = rng.uniform(-1.0, 1.0, 50)
Z = rng.uniform(-2.0, 2.0, 50)
T = 0.37

NUMERIC = [
    ("x", lambda x, y, z, t: x),
    ("1", lambda x, y, z, t: np.ones_like(x)),
    ("-x + 2*y - z/3", lambda x, y, z, t: -x + 2 * y - z / 3),
    ("x**2 + y**3", lambda x, y, z, t: x**2 + y**3),
    ("2**-x", lambda x, y, z, t: 2.0**-x),
    ("-x**2", lambda x, y, z, t: -(x**2)),
    ("2**3**2", lambda x, y, z, t: np.full_like(x, 512.0)),
    ("(x - 0.3)**2 + (z - 0.02)**2", lambda x, y, z, t: (x - 0.3) ** 2 + (z - 0.02) ** 2),
    ("0.01*sin(20*t)", lambda x, y, z, t: np.full_like(x, 0.01 * np.sin(20 * t))),
    ("sin(x)*cos(y) + tan(z/4)", lambda x, y, z, t: np.sin(x) * np.cos(y) + np.tan(z / 4)),
    ("exp(-x) * log(x) + sqrt(x)", lambda x, y, z, t: np.exp(-x) * np.log(x) + np.sqrt(x)),
    ("abs(y) - abs(-z)", lambda x, y, z, t: np.abs(y) - np.abs(z)),
    ("min(x, y)", lambda x, y, z, t: np.minimum(x, y)),
    ("max(x, y, z, 0.5)", lambda x, y, z, t: np.maximum(np.maximum(x, y), np.maximum(z, 0.5))),
    ("min(x, y, z) + max(t, 1)", lambda x, y, z, t: np.minimum(np.minimum(x, y), z) + 1),
    ("pi*x/180", lambda x, y, z, t: np.pi * x / 180),
    ("1e-3 * x * t", lambda x, y, z, t: 1e-3 * x * t),
    ("+x - -y", lambda x, y, z, t: x + y),
    ("0.01*(x > 1)", lambda x, y, z, t: 0.01 * (x > 1)),
    ("-(y < 0) + 2*(z >= 0)", lambda x, y, z, t: -1.0 * (y < 0) + 2.0 * (z >= 0)),
    ("x / (1 + y**2)", lambda x, y, z, t: x / (1 + y**2)),
]

CONDITIONS = [
    ("x < 1", lambda x, y, z, t: x < 1),
    ("x <= 1 and y > 0", lambda x, y, z, t: (x <= 1) & (y > 0)),
    ("x < 0.5 or y >= 0.5 or z == 0", lambda x, y, z, t: (x < 0.5) | (y >= 0.5) | (z == 0)),
    ("not x > 1", lambda x, y, z, t: ~(x > 1)),
    ("0.5 < x < 1.5", lambda x, y, z, t: (0.5 < x) & (x < 1.5)),
    ("-1 < y <= z < 1", lambda x, y, z, t: (-1 < y) & (y <= z) & (z < 1)),
    ("x != 1 and not (y < 0 or z < 0)", lambda x, y, z, t: (x != 1) & ~((y < 0) | (z < 0))),
    (
        "(x - 0.3)**2 + (z - 0.02)**2 < 0.5**2",
        lambda x, y, z, t: (x - 0.3) ** 2 + (z - 0.02) ** 2 < 0.25,
    ),
    ("t > 0.1", lambda x, y, z, t: np.full(x.shape, t > 0.1)),
]


@pytest.mark.parametrize("text, reference", NUMERIC, ids=[c[0] for c in NUMERIC])
def test_numeric_matches_numpy(text, reference):
    expr = parse_expression(text, source=SOURCE)
    result = expr.evaluate(x=X, y=Y, z=Z, t=T)
    assert result.dtype == np.float64
    assert result.shape == X.shape
    np.testing.assert_allclose(result, reference(X, Y, Z, T), rtol=1e-14, atol=1e-300)
    assert not expr.is_boolean


@pytest.mark.parametrize("text, reference", CONDITIONS, ids=[c[0] for c in CONDITIONS])
def test_conditions_match_numpy(text, reference):
    expr = parse_expression(text, source=SOURCE, expect="condition")
    result = expr.evaluate(x=X, y=Y, z=Z, t=T)
    assert result.dtype == np.bool_
    np.testing.assert_array_equal(result, reference(X, Y, Z, T))
    assert expr.is_boolean


def test_variables_and_constants():
    e = parse_expression("x*sin(t) + pi", source=SOURCE)
    assert e.variables == frozenset({"x", "t"})
    assert e.text == "x*sin(t) + pi"
    assert not e.is_constant
    c = parse_expression("2*pi + sqrt(4)", source=SOURCE)
    assert c.is_constant and c.variables == frozenset()
    assert c.constant_value == pytest.approx(2 * np.pi + 2)
    assert parse_expression(3).constant_value == 3.0
    assert parse_expression(-2.5).text == "-2.5"
    assert parse_expression("  x + 1  ").text == "x + 1"
    assert parse_expression("1 < 2").constant_value is True


def test_broadcasting_shapes():
    x = np.linspace(0, 1, 4)[:, None]
    y = np.linspace(0, 1, 3)[None, :]
    assert parse_expression("x + y").evaluate(x=x, y=y).shape == (4, 3)
    # A constant (or a partially used set of variables) takes the shape of all given values.
    assert parse_expression("0").evaluate(x=x, y=y, t=0.0).shape == (4, 3)
    assert parse_expression("x").evaluate(x=x, y=y).shape == (4, 3)
    assert parse_expression("t < 1").evaluate(x=x, t=0.5).shape == (4, 1)
    zero_d = parse_expression("1.5").evaluate()
    assert zero_d.shape == () and zero_d == 1.5
    assert parse_expression("t").evaluate(t=2).shape == ()


def test_result_is_a_fresh_array():
    x = np.arange(5.0)
    out = parse_expression("x").evaluate(x=x)
    assert out is not x and not np.shares_memory(out, x)
    out[:] = -1
    assert x[1] == 1.0
    c = parse_expression("2").evaluate(x=x)
    c[0] = 7  # writable, not a read-only broadcast view
    assert c.tolist() == [7, 2, 2, 2, 2]


def test_integer_inputs_and_lists():
    e = parse_expression("x / 2")
    np.testing.assert_allclose(e.evaluate(x=[1, 2, 3]), [0.5, 1.0, 1.5])  # true division


def test_evaluate_at_points():
    p = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]])
    np.testing.assert_allclose(parse_expression("x + 10*y + 100*z").evaluate_at(p), [210, 543])
    np.testing.assert_allclose(parse_expression("t*z").evaluate_at(p, t=2.0), [4.0, 10.0])
    np.testing.assert_allclose(parse_expression("1").evaluate_at(p), [1, 1])
    region = parse_expression("x < 1", variables=("x", "y", "z"))
    np.testing.assert_array_equal(region.evaluate_at(p, t=3.0), [True, False])
    with pytest.raises(ValueError):
        region.evaluate_at(np.zeros((3, 2)))


def test_call_errors_are_type_errors():
    e = parse_expression("x + t", variables=("x", "y", "z", "t"))
    with pytest.raises(TypeError, match="missing"):
        e.evaluate(x=1.0)
    with pytest.raises(TypeError, match="unknown"):
        e.evaluate(x=1.0, t=0.0, w=1.0)


def test_error_hierarchy():
    assert issubclass(ExpressionError, ExperimentError)
    assert issubclass(ExpressionError, PetsoftError)


FORBIDDEN = [
    ("__import__('os')", "__import__"),
    ("__import__('os').system('true')", "__import__"),
    ("x.__class__", "x.__class__"),
    ("().__class__.__bases__[0]", "__bases__"),
    ("(lambda: 1)()", "lambda"),
    ("[1][0]", "[1][0]"),
    ("[x, y]", "[x, y]"),
    ("(x, y)", "(x, y)"),
    ("{1: 2}", "{1: 2}"),
    ("open('f')", "open"),
    ("eval('1')", "eval"),
    ("exec('1')", "exec"),
    ("getattr(x, 'real')", "getattr"),
    ("x.real", "x.real"),
    ("x if y else z", "x if y else z"),
    ("[i for i in x]", "[i for i in x]"),
    ("(y := 2)", "y := 2"),
    ("'text'", "'text'"),
    ("b'bytes'", "b'bytes'"),
    ("f'{x}'", "f'{x}'"),
    ("1j", "1j"),
    ("True", "True"),
    ("None", "None"),
    ("...", "..."),
    ("sin(x=1)", "x="),
    ("max(*x)", "*x"),
    ("foo", "foo"),
    ("X + 1", "X"),
    ("Pi", "Pi"),
    ("sine(x)", "sine"),
    ("sin", "sin"),
    ("x(1)", "x"),
    ("pi(1)", "pi"),
    ("x % 2", "%"),
    ("x // 2", "//"),
    ("x ^ 2", "^"),
    ("x & y", "&"),
    ("x | y", "|"),
    ("~x", "~"),
    ("x << 1", "<<"),
    ("x @ y", "@"),
    ("x in y", "in"),
    ("x is y", "is"),
    ("x and 1", "1"),
    ("not x", "x"),
    ("sqrt(x, y)", "sqrt(x, y)"),
    ("sqrt()", "sqrt()"),
    ("min(x)", "min(x)"),
    ("1e999", "1e999"),
    ("9**9**9**9", "9**9**9"),
    ("x + 9**9**9**9", "9**9**9"),
    ("log(0)", "log(0)"),
    ("x * sqrt(-1)", "sqrt(-1)"),
    ("1/0 + x", "1/0"),
    ("10**400", "10**400"),
    ("exp(1000)", "exp(1000)"),
]


@pytest.mark.parametrize("text, token", FORBIDDEN, ids=[c[0] for c in FORBIDDEN])
def test_forbidden_constructs_are_rejected(text, token):
    with pytest.raises(ExpressionError) as info:
        parse_expression(text, source=SOURCE)
    message = str(info.value)
    assert message.startswith(SOURCE + ":")
    assert repr(text) in message or text in message  # the expression itself
    assert token in message  # the offending token/node


@pytest.mark.parametrize(
    "text",
    ["__import__('os')", "x.__class__", "[1][0]", "open('f')", "foo", "x % 2", "sqrt(x, y)"],
)
def test_rejection_lists_what_is_allowed(text):
    with pytest.raises(ExpressionError, match="allowed: numbers, the variables x, y, z, t"):
        parse_expression(text, source=SOURCE)


SYNTAX = ["", "   ", "x +", "(x", "x = 1", "import os", "x; y", "1 +* 2", "x\x00", "\n"]


@pytest.mark.parametrize("text", SYNTAX)
def test_syntax_errors(text):
    with pytest.raises(ExpressionError) as info:
        parse_expression(text, source=SOURCE)
    assert str(info.value).startswith(SOURCE + ":")


def test_assignment_hint():
    with pytest.raises(ExpressionError, match="compare with =="):
        parse_expression("x = 1", source=SOURCE)


def test_suggestions():
    with pytest.raises(ExpressionError, match="did you mean `x`"):
        parse_expression("X < 1", source=SOURCE)
    with pytest.raises(ExpressionError, match="did you mean `sin`"):
        parse_expression("sine(x)", source=SOURCE)
    with pytest.raises(ExpressionError, match="did you mean `pi`"):
        parse_expression("Pi", source=SOURCE)


def test_variables_restriction():
    with pytest.raises(ExpressionError) as info:
        parse_expression("x < t", source=SOURCE, variables=("x", "y", "z"))
    message = str(info.value)
    assert "`t`" in message and "not available here" in message and "x, y, z" in message
    assert parse_expression("w + 1", variables=("w",)).variables == frozenset({"w"})
    with pytest.raises(ValueError):
        parse_expression("1", variables=("sin",))


def test_expect_kind():
    with pytest.raises(ExpressionError, match="expected a condition"):
        parse_expression("x", source=SOURCE, expect="condition")
    with pytest.raises(ExpressionError, match="expected a number-valued"):
        parse_expression("x < 1", source=SOURCE, expect="number")
    assert parse_expression("x < 1", expect="condition").is_boolean


def test_non_string_input():
    for bad in (True, None, [1, 2], {"a": 1}, float("nan"), float("inf")):
        with pytest.raises(ExpressionError) as info:
            parse_expression(bad, source=SOURCE)
        assert str(info.value).startswith(SOURCE + ":")


def test_length_limit():
    text = "x + " * (MAX_LENGTH // 4) + "1"
    assert len(text) > MAX_LENGTH
    with pytest.raises(ExpressionError, match=f"limit is {MAX_LENGTH}") as info:
        parse_expression(text, source=SOURCE)
    assert SOURCE in str(info.value)
    with pytest.raises(ExpressionError):
        parse_expression("1" * 5000, source=SOURCE)


@pytest.mark.parametrize(
    "text",
    [
        "-" * 500 + "x",
        "x" + "+x" * 300,
        "(" * 300 + "x" + ")" * 300,
        "sin(" * 120 + "x" + ")" * 120,
        "not " * 150 + "x < 1",
    ],
    ids=["unary", "sum", "parens", "calls", "not"],
)
def test_depth_limit(text):
    with pytest.raises(ExpressionError) as info:
        parse_expression(text, source=SOURCE)
    assert str(info.value).startswith(SOURCE + ":")


def test_depth_within_limit_works():
    n = MAX_DEPTH // 2
    e = parse_expression("x" + "+x" * (n - 1))
    np.testing.assert_allclose(e.evaluate(x=np.array([1.0, 2.0])), [n, 2 * n])
    # Redundant parentheses add no depth (Python's parser allows up to 200 levels).
    assert parse_expression("(" * 150 + "x" + ")" * 150).evaluate(x=3.0) == 3.0


def test_huge_powers_do_not_hang():
    start = time.perf_counter()
    for text in ["9**9**9**9", "x**9**9**9", "(x+1)**(10**300)"]:
        try:
            e = parse_expression(text, source=SOURCE)
            e.evaluate(x=np.array([2.0]))
        except ExpressionError:
            pass
    assert time.perf_counter() - start < 1.0
    # Overflow at evaluation is reported, naming the part that overflowed.
    with pytest.raises(ExpressionError, match=r"`x\*\*9\*\*9` evaluates to inf at x=2"):
        parse_expression("x**9**9", source=SOURCE).evaluate(x=np.array([1.0, 2.0]))


@pytest.mark.parametrize(
    "text, values, culprit, value",
    [
        ("sqrt(x - 1)", {"x": np.array([2.0, 0.5, 3.0])}, "sqrt(x - 1)", "nan"),
        ("log(x)", {"x": np.array([1.0, 0.0])}, "log(x)", "-inf"),
        ("1 + 1/x", {"x": np.array([1.0, 0.0])}, "1/x", "inf"),
        ("exp(x)", {"x": np.array([1.0, 1000.0])}, "exp(x)", "inf"),
        ("sqrt(x - 1) < 2", {"x": np.array([2.0, 0.0])}, "sqrt(x - 1)", "nan"),
        ("exp(-1/x**2) + sqrt(x - 0.6)", {"x": np.array([0.0, 1.0])}, "sqrt(x - 0.6)", "nan"),
        ("(x - 1)**0.5 * t", {"x": np.array([2.0, 0.0]), "t": 1.0}, "(x - 1)**0.5", "nan"),
    ],
)
def test_non_finite_evaluation_is_an_error(text, values, culprit, value):
    e = parse_expression(text, source=SOURCE)
    with pytest.raises(ExpressionError) as info:
        e.evaluate(**values)
    message = str(info.value)
    assert message.startswith(SOURCE + ":")
    assert f"`{culprit}` evaluates to {value}" in message
    assert "x=" in message  # the point


def test_resolved_intermediate_infinity_is_fine():
    out = parse_expression("exp(-1/x**2)").evaluate(x=np.array([0.0, 1.0]))
    np.testing.assert_allclose(out, [0.0, np.exp(-1.0)])


def test_non_finite_inputs_are_not_the_expressions_fault():
    out = parse_expression("2*x").evaluate(x=np.array([np.nan, 1.0, np.inf]))
    assert np.isnan(out[0]) and out[1] == 2.0 and out[2] == np.inf
    cond = parse_expression("x < 1").evaluate(x=np.array([np.nan, 0.0]))
    assert cond.tolist() == [False, True]
    # ... but a new NaN at a finite point still is.
    with pytest.raises(ExpressionError, match="x=-1"):
        parse_expression("sqrt(x)").evaluate(x=np.array([np.nan, -1.0]))


def test_pickle_and_equality():
    e = parse_expression("x < 0.5 and y > 0", source=SOURCE, variables=("x", "y", "z"))
    e2 = pickle.loads(pickle.dumps(e))
    assert e2 == e and hash(e2) == hash(e)
    assert e2.source == SOURCE and e2.allowed_variables == ("x", "y", "z")
    np.testing.assert_array_equal(e2.evaluate(x=X, y=Y), e.evaluate(x=X, y=Y))
    assert parse_expression("x") != parse_expression("x", variables=("x",))
    n = pickle.loads(pickle.dumps(parse_expression(0.25)))
    assert n.literal == 0.25


def test_module_never_evaluates_code():
    source = inspect.getsource(expressions)
    for word in ("eval(", "exec(", "compile("):
        assert word not in source.replace("ast.parse", "")


def test_vectorised_evaluation_is_fast():
    n = 200_000
    x = np.linspace(0, 1, n)
    e = parse_expression("(x - 0.3)**2 + (z - 0.02)**2 < 0.01**2 and not x > 0.9")
    start = time.perf_counter()
    out = e.evaluate(x=x, y=x, z=x)
    assert out.shape == (n,)
    assert time.perf_counter() - start < 0.5
