"""Terms from the user's own package (issue 38, item 2): the example package
scripts/examples/petsoft_foundation (a bilinear elastic foundation) and the registry's checks.

- The foundation's force against its energy, its Hessian against its force, its parameter
  derivatives against differences in the parameter (the energy is piecewise quadratic, so
  central differences inside one piece are exact up to round-off), on random states that press
  some nodes into the bed and lift others; a coefficient planted wrong must fail that check.
- The registry refuses malformed or clashing entry points with an ImportError naming them.
- End to end: the package installed with ``pip install -e`` (into a scratch prefix, so that this
  environment's registry, and every other test's vocabulary, stays petsoft's own) and its own
  tests (scripts/examples/petsoft_foundation/tests) run in a child process that finds it
  through its entry point: read, simulated on P1 and P2 with exact sensitivities checked against
  differences, calibrated back, named by ``petsoft diagnose``.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import types
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest
from child_process import child_env

from petsoft.errors import PetsoftError
from petsoft.physics.model import check_package_term
from petsoft.terms import (
    PLUGINS,
    TERMS,
    Key,
    Parameter,
    Plugin,
    Proposal,
    Term,
    load_plugin,
)

PACKAGE = Path(__file__).resolve().parents[1] / "scripts" / "examples" / "petsoft_foundation"


def _term_module():
    """The example's term module, loaded from its file (no registry involved)."""
    spec = importlib.util.spec_from_file_location(
        "_foundation_under_test", PACKAGE / "petsoft_foundation" / "term.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _errors(term, u, w, h=1e-6) -> dict[str, float]:
    """Relative errors of the term's gradient, Hessian and parameter derivatives against
    central differences (of the energy, the gradient, the gradient in the parameter)."""
    nv = len(u)
    flat = u.reshape(-1)

    def energy(x):
        return term.energy(x.reshape(nv, 3))

    def grad(x):
        g = np.zeros((nv, 3))
        g[term.nodes] = term.gradient(x.reshape(nv, 3))
        return g.reshape(-1)

    g = grad(flat)
    fd_g = np.array([(energy(flat + h * e) - energy(flat - h * e)) / (2 * h)
                     for e in np.eye(3 * nv)])
    H = _hessian(term, u)
    fd_H = np.stack([(grad(flat + h * e) - grad(flat - h * e)) / (2 * h)
                     for e in np.eye(3 * nv)], axis=1)
    out = {"gradient": np.abs(g - fd_g).max() / np.abs(g).max(),
           "hessian": np.abs(H - fd_H).max() / np.abs(H).max()}
    for name, k in term.parameters().items():
        d = np.zeros((nv, 3))
        term.add_parameter_derivative(name, u, d, w)
        step = 1e-3 * k

        sides = []
        for kk in (k + step, k - step):
            term.set_parameter(name, kk)
            sides.append(grad(flat) + _hessian(term, u) @ w.reshape(-1))
        fd = ((sides[0] - sides[1]) / (2 * step)).reshape(nv, 3)
        term.set_parameter(name, k)
        out[name] = np.abs(d - fd).max() / np.abs(fd).max()
    return out


def _hessian(term, u) -> np.ndarray:
    """The term's Hessian as a dense (3 nv, 3 nv) matrix."""
    nv = len(u)
    H = np.zeros((3 * nv, 3 * nv))
    for i, node in enumerate(term.nodes):
        H[3 * node:3 * node + 3, 3 * node:3 * node + 3] = term.hessian(u)[i]
    return H


def _foundation(module, cls=None):
    rng = np.random.default_rng(7)
    d = rng.standard_normal(3)
    nodes = np.array([0, 2, 3, 5, 6])
    cls = cls or module.BilinearFoundation
    term = cls(nodes, rng.uniform(0.5, 2.0, len(nodes)) * 1e-3, d / np.linalg.norm(d),
               compression=3e5, tension=4e4)
    # pushes s = d . u of both signs, bounded away from the kink at 0 (steps are 1e-6)
    u = rng.standard_normal((7, 3)) * 1e-3
    s = u[nodes] @ term.direction
    u[nodes] += np.where(s > 0, 2e-4, -2e-4)[:, None] * term.direction
    return term, u, rng.standard_normal((7, 3)) * 1e-3


def test_foundation_force_hessian_and_derivatives_against_differences():
    module = _term_module()
    term, u, w = _foundation(module)
    s = u[term.nodes] @ term.direction
    assert (s > 0).any() and (s < 0).any()      # both sides of the bed are tested
    err = _errors(term, u, w)
    assert all(e < 1e-7 for e in err.values()), err


def test_a_planted_wrong_coefficient_fails_the_check():
    """The force on the tension side 1 % too large: the gradient check must see it."""
    module = _term_module()

    class Wrong(module.BilinearFoundation):
        def gradient(self, u_local):
            g = super().gradient(u_local)
            s = u_local[self.nodes] @ self.direction
            return g * np.where(s > 0.0, 1.0, 1.01)[:, None]

    term, u, w = _foundation(module, Wrong)
    err = _errors(term, u, w)
    assert err["gradient"] > 1e-3, err


# -- the registry's checks ------------------------------------------------------------------------
def _plugin(**changes) -> types.ModuleType:
    """A well-formed package term module, with ``changes`` made to it."""
    module = types.ModuleType("_fake_petsoft_term")
    module.TERM = _term()
    module.build = lambda *args: None
    for k, v in changes.items():
        setattr(module, k, v)
    return module


def _load(module):
    sys.modules["_fake_petsoft_term"] = module
    try:
        ep = EntryPoint(name="fake", value="_fake_petsoft_term", group="petsoft.terms")
        return load_plugin(ep, dict(TERMS), {})
    finally:
        del sys.modules["_fake_petsoft_term"]


def _term(**kw) -> Term:
    base = dict(name="fake.term", meaning="a test term",
                keys=(Key("fake", "stiffness", unit="N/m", minimum=0.0),),
                proposal=Proposal(kind="value", parameters=(
                    Parameter("fake.stiffness", "N/m", lower="0", upper="1"),)))
    base.update(kw)
    return Term(**base)


def test_a_well_formed_plugin_loads():
    p = _load(_plugin())
    assert p.term.name == "fake.term" and p.tables == ("fake",)


@pytest.mark.parametrize("changes, words", [
    ({"TERM": None}, "has no TERM"),
    ({"build": None}, "has no build"),
    ({"TERM": _term(name="damping.mass")}, "clashes with petsoft's built-in term"),
    ({"TERM": _term(keys=(Key("damping", "stiffness"),), proposal=Proposal(
        kind="value", parameters=(Parameter("damping.stiffness", "", "0", "1"),)))},
     "table [damping] belongs to another term"),
    ({"TERM": _term(keys=(Key("fake", "stiffness", section="named"),))},
     'top-level table (section = "table")'),
    ({"TERM": _term(proposal=Proposal(kind="value", parameters=(
        Parameter("fake.other", "", "0", "1"),)))}, "is none of its number keys"),
    ({"TERM": _term(proposal=Proposal(kind="switch", ranking="switch", parameters=(
        Parameter("fake.stiffness", "", "0", "1"),)))}, 'proposed by its values'),
])
def test_a_malformed_plugin_is_refused_by_name(changes, words):
    with pytest.raises(ImportError, match="entry point 'fake' = '_fake_petsoft_term'") as info:
        _load(_plugin(**changes))
    assert words in str(info.value)


def test_two_packages_cannot_declare_one_term():
    first = _load(_plugin())
    sys.modules["_fake_petsoft_term"] = _plugin()
    try:
        ep = EntryPoint(name="fake", value="_fake_petsoft_term", group="petsoft.terms")
        with pytest.raises(ImportError, match="also declared by package"):
            load_plugin(ep, dict(TERMS), {first.term.name: first})
    finally:
        del sys.modules["_fake_petsoft_term"]


def test_what_build_returns_is_checked():
    """A package's build() must return a NodalTerm and ParametricTerm of the term's kind,
    outside K0, with the declaration's number keys as its parameters."""
    module = _term_module()
    plugin = Plugin(module.TERM, module.build, "petsoft-foundation", "petsoft_foundation.term")
    good, _, _ = _foundation(module)
    assert check_package_term(plugin, good) is good
    stiff, _, _ = _foundation(module)
    stiff.in_reference = True
    renamed, _, _ = _foundation(module)
    renamed.kind = "support"
    fewer, _, _ = _foundation(module)
    del fewer.k[module.TENSION]
    for t, words in [(object(), "is not a petsoft.physics.term.NodalTerm"),
                     (stiff, "in_reference = True is not supported"),
                     (renamed, "kind is 'support'"),
                     (fewer, "parameters() gives ['foundation.compression']")]:
        with pytest.raises(PetsoftError, match="package 'petsoft-foundation'") as info:
            check_package_term(plugin, t)
        assert words in str(info.value)


def test_this_environment_has_no_package_terms():
    """The suite runs on petsoft's own vocabulary (the example is installed elsewhere)."""
    assert PLUGINS == {}


# -- end to end -----------------------------------------------------------------------------------
@pytest.mark.serial_only
def test_the_installed_package_end_to_end(tmp_path):
    prefix = tmp_path / "prefix"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation",
         "--no-index", "--prefix", str(prefix), "-e", str(PACKAGE)],
        capture_output=True, text=True, timeout=300, env=child_env())
    if install.returncode != 0:
        pytest.skip("pip cannot install the example package offline here: "
                    + install.stderr.strip().splitlines()[-1])
    site = next(prefix.glob("lib/python*/site-packages"))
    # the prefix's site directory processed like the environment's own (its .pth finds the
    # editable package); the child's registry then holds the foundation
    code = ("import site, sys; site.addsitedir(sys.argv[1]); import pytest; "
            "sys.exit(pytest.main(['-q', '-s', '-p', 'no:cacheprovider', '--rootdir', "
            "sys.argv[2], sys.argv[3]]))")
    run = subprocess.run(
        [sys.executable, "-c", code, str(site), str(tmp_path), str(PACKAGE / "tests")],
        capture_output=True, text=True, timeout=600, cwd=tmp_path, env=child_env())
    print(run.stdout[-3000:])
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-3000:]
    assert "8 passed" in run.stdout   # (none skipped)
