"""How the package is put together, in numbers: the figures issue 18 ("One house") asks for.

Prints, for the ``petsoft`` package under ``--root`` (default: this checkout):

- the 15 longest functions and the 10 largest modules (lines, docstrings included);
- ``getattr``/``hasattr`` probes (where code asks an object what it is instead of knowing);
- imports inside functions (hidden dependencies, usually a sign of an import cycle);
- imports that go *up* or *sideways* in the declared layering below (a lower layer may not know
  a higher one; two packages of one layer may not know each other), and private names
  (``_name``) imported from another module.

Run::

    .venv/bin/python scripts/tools/architecture.py            # this checkout
    .venv/bin/python scripts/tools/architecture.py --root ../old-checkout
    .venv/bin/python scripts/tools/architecture.py --check    # exit 1 on a wrong import

A checkout from before the layout of issue 18 is measured with the same layering: its flat
modules are counted in the package each moved to (``OLD_HOMES``).
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

#: The declared architecture, lowest layer first. A module may import from its own package and
#: from any lower layer; packages on the same line are independent of each other.
LAYERS: list[set[str]] = [
    {"errors", "version", "blas_threads", "carrays", "results", "atomic"},
    {"dependencies"},
    {"terms"},
    {"mesh"},
    {"experiment"},
    {"io"},
    {"fem"},
    {"physics"},
    {"solvers"},
    {"dynamics"},
    {"reduced"},
    {"calibration"},
    {"diagnosis"},
    {"api", "cli"},
    {"__init__", "__main__"},
]

#: Where each module of the flat pre-issue-18 layout lives now (to measure an old checkout).
OLD_HOMES = {
    "assembly": "fem", "boundary": "fem", "kernels": "fem", "commands": "cli",
    "damping": "dynamics", "distributed": "mesh", "expressions": "experiment",
    "groups": "calibration", "linear": "solvers", "model": "physics", "modes": "solvers",
    "options": "solvers", "ordering": "mesh", "probes": "mesh", "recording": "io",
    "regions": "fem", "static": "solvers", "summary": "io", "synth": "calibration",
    "topology": "mesh", "xdmf": "io", "importers": "io",
}


def layer_of(unit: str) -> int:
    for i, names in enumerate(LAYERS):
        if unit in names:
            return i
    raise KeyError(f"package {unit!r} is in no layer of LAYERS: add it")


def unit_of(module: str) -> str:
    """The top-level package (or module) of a dotted ``petsoft.*`` name, mapped to its home."""
    parts = module.split(".")
    name = parts[1] if len(parts) > 1 else "__init__"
    return OLD_HOMES.get(name, name)


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def resolve(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


class Survey(ast.NodeVisitor):
    """Collects functions, probes and imports of one module."""

    def __init__(self, module: str, is_package: bool):
        self.module, self.is_package = module, is_package
        self.functions: list[tuple[int, str]] = []
        self.probes = 0
        self.local_imports = 0
        self.imports: list[tuple[int, str, list[str]]] = []
        self._stack: list[str] = []
        self._depth = 0  # functions enclosing the node being visited

    def _function(self, node):
        qual = ".".join([*self._stack, node.name])
        self.functions.append((node.end_lineno - node.lineno + 1, f"{self.module}:{qual}"))
        self._stack.append(node.name)
        self._depth += 1
        self.generic_visit(node)
        self._depth -= 1
        self._stack.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = _function

    def visit_ClassDef(self, node):
        self._stack.append(node.name)
        self.generic_visit(node)
        self._stack.pop()

    def visit_Call(self, node):
        if isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr"):
            self.probes += 1
        self.generic_visit(node)

    def _import(self, node, targets: list[tuple[str, list[str]]]):
        if self._depth:
            self.local_imports += 1
        for target, names in targets:
            if target == "petsoft" or target.startswith("petsoft."):
                self.imports.append((node.lineno, target, names))

    def visit_Import(self, node):
        self._import(node, [(a.name, []) for a in node.names])

    def visit_ImportFrom(self, node):
        self._import(node, [(resolve(node, self.module, self.is_package),
                             [a.name for a in node.names])])


def survey(root: Path) -> dict:
    package = root / "petsoft"
    functions, modules, probes, local, wrong, private = [], [], {}, {}, [], []
    known = {module_name(p, root) for p in package.rglob("*.py")}
    for path in sorted(package.rglob("*.py")):
        module = module_name(path, root)
        source = path.read_text()
        s = Survey(module, path.name == "__init__.py")
        s.visit(ast.parse(source))
        functions += s.functions
        modules.append((len(source.splitlines()), module))
        if s.probes:
            probes[module] = s.probes
        if s.local_imports:
            local[module] = s.local_imports
        src_unit = unit_of(module)
        for line, target, names in s.imports:
            # `from petsoft.diagnosis import locate` imports the module petsoft.diagnosis.locate
            submodules = [n for n in names if f"{target}.{n}" in known]
            if submodules:
                target = f"{target}.{submodules[0]}"
            dst_unit = unit_of(target)
            if target == "petsoft" and names and all(n == "__version__" for n in names):
                dst_unit = "__init__"
            if dst_unit != src_unit:
                a, b = layer_of(src_unit), layer_of(dst_unit)
                if b > a:
                    wrong.append(("up", f"{module}:{line}", target))
                elif b == a:
                    wrong.append(("sideways", f"{module}:{line}", target))
            if target != module and any(n.startswith("_") and not n.startswith("__")
                                        for n in names):
                private.append((f"{module}:{line}", target,
                                [n for n in names if n.startswith("_")]))
    return dict(functions=sorted(functions, reverse=True), modules=sorted(modules, reverse=True),
                probes=probes, local=local, wrong=wrong, private=private)


def report(r: dict) -> None:
    print("15 longest functions (lines):")
    for n, name in r["functions"][:15]:
        print(f"  {n:5d}  {name}")
    print("\n10 largest modules (lines):")
    for n, name in r["modules"][:10]:
        print(f"  {n:5d}  {name}")
    print(f"\ngetattr/hasattr calls: {sum(r['probes'].values())} in {len(r['probes'])} modules")
    for name, n in sorted(r["probes"].items(), key=lambda kv: -kv[1])[:10]:
        print(f"  {n:5d}  {name}")
    print(f"\nimports inside functions: {sum(r['local'].values())} in {len(r['local'])} modules")
    for name, n in sorted(r["local"].items(), key=lambda kv: -kv[1])[:10]:
        print(f"  {n:5d}  {name}")
    up = [w for w in r["wrong"] if w[0] == "up"]
    side = [w for w in r["wrong"] if w[0] == "sideways"]
    print(f"\nimports that go up: {len(up)}; sideways: {len(side)} (layers: "
          + " < ".join("/".join(sorted(s)) for s in LAYERS) + ")")
    for kind, where, target in r["wrong"]:
        print(f"  {kind:8s} {where} -> {target}")
    print(f"\nprivate names imported from another module: {len(r['private'])}")
    for where, target, names in r["private"]:
        print(f"  {where} -> {target}: {', '.join(names)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[2],
                    help="a petsoft checkout (default: this one)")
    ap.add_argument("--check", action="store_true",
                    help="exit with status 1 if an import goes up or sideways, or imports a "
                         "private name of another module")
    args = ap.parse_args(argv)
    r = survey(args.root)
    report(r)
    return 1 if args.check and (r["wrong"] or r["private"]) else 0


if __name__ == "__main__":
    sys.exit(main())
