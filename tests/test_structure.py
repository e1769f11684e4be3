"""The package's shape: its subpackages form layers whose imports point down only; no import
cycle; at most 6 modules at the top of ``bayescal/`` and 12 per subpackage; no module over 500
lines, no function body over 60 lines (docs/architecture.md, docs/conventions.md)."""

import ast
import pathlib

import pytest

PKG = pathlib.Path(__file__).resolve().parents[1] / "bayescal"
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 60
MAX_TOP_MODULES = 6
MAX_SUBPACKAGE_MODULES = 12
#: the subpackages, bottom first: each may import only those before it (and the top-level
#: ``errors``, ``constants``, ``_validation``); ``bayescal/__init__`` and ``__main__`` sit above all
LAYERS = ("sensor", "image", "stats", "scene", "likelihood", "results", "io", "checks", "fit",
          "mcmc", "validation", "plotting", "report", "cli")
TOP_LOW = ("errors", "constants", "_validation")
#: the only imports allowed to point up: inside a method of a result, a convenience that
#: reaches a higher layer when called (``r.save()``, ``r.corner()``), never at import time.
#: (importing module, imported module)
LAZY_METHOD_IMPORTS = {
    ("bayescal.results.calibration", "bayescal.io.jsonfile"),
    ("bayescal.results.posterior", "bayescal.io.jsonfile"),
    ("bayescal.results.posterior", "bayescal.plotting"),
    ("bayescal.results.calibration", "bayescal.checks.model"),
    ("bayescal.results.posterior", "bayescal.checks.model"),
    ("bayescal.results.reconstruction", "bayescal.io.pointcloud"),
}
#: the command line is a client of the public API: it may import the package itself
#: (``import bayescal as bc``, so that it calls exactly what a user calls)
PUBLIC_API_CLIENTS = ("cli",)
#: known offenders in modules being reworked elsewhere; anything new fails. Remove an entry
#: when it is fixed (the tests below then fail if it is still listed).
KNOWN_CYCLES = set()
KNOWN_LARGE_MODULES = set()
KNOWN_LONG_FUNCTIONS = set()


def _modules(pkg=PKG):
    out = {}
    for path in sorted(pkg.rglob("*.py")):
        rel = path.relative_to(pkg.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imports(name, path, modules, *, with_lazy=False):
    """bayescal modules imported by ``name`` anywhere in its body (function level too).

    With ``with_lazy``, a set of ``(module, lazy)`` where ``lazy`` says the import
    is inside a function.
    """
    tree = ast.parse(path.read_text())
    in_function = {id(sub) for node in ast.walk(tree)
                   if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                   for sub in ast.walk(node) if sub is not node}
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                mod = ".".join(base[: len(base) - node.level + 1] + ([node.module]
                                                                     if node.module else []))
            else:
                mod = node.module or ""
            cands = [f"{mod}.{a.name}" for a in node.names]
            cands = [c for c in cands if c in modules] or [mod]
        elif isinstance(node, ast.Import):
            cands = [a.name for a in node.names]
        else:
            continue
        found.update((c, id(node) in in_function) for c in cands
                     if c in modules and c != name)
    return found if with_lazy else {c for c, _ in found}


def _rank(module):
    """Layer index of a module (-1 for the low top-level modules, None for the package top)."""
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in ("__main__",):
        return None                                     # bayescal / __main__: above everything
    if parts[1] in TOP_LOW:
        return -1
    return LAYERS.index(parts[1])


def upward_imports(pkg=PKG):
    """Imports that point from a layer to a higher one, minus the allowed lazy methods."""
    modules = _modules(pkg)
    bad = []
    for name, path in modules.items():
        src = _rank(name)
        if src is None:
            continue
        for target, lazy in sorted(_imports(name, path, modules, with_lazy=True)):
            dst = _rank(target)
            if dst is None and target == "bayescal" and name.split(".")[1] in PUBLIC_API_CLIENTS:
                continue
            if dst is None or dst > src:
                if lazy and (name, target) in LAZY_METHOD_IMPORTS:
                    continue
                bad.append((name, target))
    return bad


def test_every_subpackage_has_a_layer():
    found = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert found == set(LAYERS)


def test_imports_point_down():
    assert upward_imports() == []


def test_lazy_method_imports_are_still_needed():
    modules = _modules()
    used = {(n, t) for n, p in modules.items() for t, lazy in
            _imports(n, p, modules, with_lazy=True) if lazy}
    assert LAZY_METHOD_IMPORTS <= used


def test_planted_upward_import_is_caught(tmp_path):
    """The check itself: a copy of the package with one upward import planted fails it."""
    import shutil

    copy = tmp_path / "bayescal"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    cam = copy / "sensor" / "camera.py"
    cam.write_text(cam.read_text() + "\n\nfrom ..results.metrics import reconstruction_error\n")
    assert ("bayescal.sensor.camera", "bayescal.results.metrics") in upward_imports(copy)
    lazy = copy / "scene" / "floorplan.py"
    lazy.write_text(lazy.read_text() + "\n\ndef _f():\n    from ..fit import schur\n")
    assert ("bayescal.scene.floorplan", "bayescal.fit.schur") in upward_imports(copy)


def test_module_counts():
    top = sorted(p.name for p in PKG.glob("*.py"))
    assert len(top) <= MAX_TOP_MODULES, top
    for layer in LAYERS:
        n = len(list((PKG / layer).glob("*.py"))) - 1      # without __init__
        assert n <= MAX_SUBPACKAGE_MODULES, (layer, n)


def test_no_import_cycles():
    modules = _modules()
    graph = {n: _imports(n, p, modules) for n, p in modules.items()}
    # the package __init__ re-exports; a submodule importing the package itself is a cycle
    cycles = []
    state = {}

    def visit(n, stack):
        state[n] = 1
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                cycles.append(stack[stack.index(m):] + [m])
            elif m not in state:
                visit(m, stack + [m])
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n, [n])
    found = {tuple(sorted(set(c))) for c in cycles}
    assert found == KNOWN_CYCLES, found


@pytest.mark.parametrize("path", sorted(PKG.rglob("*.py")),
                         ids=lambda p: str(p.relative_to(PKG)))
def test_module_and_function_sizes(path):
    text = path.read_text()
    name = str(path.relative_to(PKG))
    assert (len(text.splitlines()) <= MAX_MODULE_LINES) != (name in KNOWN_LARGE_MODULES)
    long = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            start = body[0].lineno
            if isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None),
                                                             ast.Constant):
                start = body[1].lineno if len(body) > 1 else body[0].end_lineno
            n = node.end_lineno - start + 1
            if n > MAX_FUNCTION_LINES:
                long.append((name, node.name))
    assert set(long) == {k for k in KNOWN_LONG_FUNCTIONS if k[0] == name}


def test_every_subpackage_is_packaged():
    """pyproject's package list reaches every subpackage: with the top level alone a
    wheel (``pip install .``) held 5 modules and no layer."""
    import tomllib
    from setuptools import find_packages

    cfg = tomllib.loads((PKG.parent / "pyproject.toml").read_text())["tool"]["setuptools"]
    pk = cfg.get("packages", {})
    listed = set(pk) if isinstance(pk, list) else set(find_packages(str(PKG.parent),
                                                                    **pk["find"]))
    on_disk = {"bayescal"} | {"bayescal." + p.parent.name for p in PKG.glob("*/__init__.py")}
    assert on_disk <= listed, sorted(on_disk - listed)
