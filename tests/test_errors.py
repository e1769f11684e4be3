"""Every error bayescal raises derives from bc.BayescalError (one ``except`` clause catches
them all), keeping the built-in base a caller may already catch; every warning derives from
bc.BayescalWarning."""

import ast
import builtins
import importlib
import inspect
import pathlib
import pkgutil

import pytest

import bayescal as bc
from bayescal import errors

PACKAGE = pathlib.Path(bc.__file__).parent

#: built-in exceptions a module may still raise: the interpreter's own control flow
CONTROL_FLOW = {"SystemExit", "KeyboardInterrupt", "StopIteration", "GeneratorExit"}


def _modules():
    for info in pkgutil.walk_packages(bc.__path__, "bayescal."):
        if not info.name.endswith("__main__"):      # importing it runs the command line
            yield importlib.import_module(info.name)


def _raised_builtins(path):
    """(line, name) of every ``raise Name(...)`` or ``raise Name`` of a built-in exception."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, ast.Raise) or node.exc is None:
            continue
        exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
        name = exc.id if isinstance(exc, ast.Name) else None
        obj = getattr(builtins, name, None) if name else None
        if isinstance(obj, type) and issubclass(obj, BaseException) and name not in CONTROL_FLOW:
            out.append((node.lineno, name))
    return out


def test_no_module_raises_a_bare_builtin_exception():
    found = [f"{p.relative_to(PACKAGE.parent)}:{line} raises {name}"
             for p in sorted(PACKAGE.rglob("*.py")) for line, name in _raised_builtins(p)]
    assert not found, "\n".join(found)


def test_every_exception_and_warning_class_has_the_package_base():
    bad = []
    for mod in _modules():
        for name, obj in inspect.getmembers(mod, inspect.isclass):
            if obj.__module__ != mod.__name__ or not issubclass(obj, BaseException):
                continue
            base = bc.BayescalWarning if issubclass(obj, Warning) else bc.BayescalError
            if not issubclass(obj, base):
                bad.append(f"{mod.__name__}.{name}")
    assert not bad


@pytest.mark.parametrize("cls, builtin", [
    (errors.InvalidValueError, ValueError), (errors.InvalidTypeError, TypeError),
    (errors.InputError, ValueError), (errors.ExtractionError, ValueError),
    (errors.DegenerateInputError, ValueError), (errors.NotConvergedError, RuntimeError),
    (bc.ConvergenceError, RuntimeError), (bc.NoiseCollapseError, ValueError),
    (errors.MissingFileError, FileNotFoundError), (errors.OutputExistsError, FileExistsError),
    (errors.MissingDependencyError, ImportError), (errors.FitError, RuntimeError),
])
def test_errors_keep_their_builtin_base(cls, builtin):
    assert issubclass(cls, bc.BayescalError) and issubclass(cls, builtin)


def test_a_bad_argument_is_caught_by_one_clause():
    with pytest.raises(bc.BayescalError, match="h must be positive"):
        bc.SensorParams(xi=1, phi=0, alpha_u=55, alpha_v=-55, u0=400, v0=300, h=-1, beta=1.0)
    with pytest.raises(ValueError):     # and by the clause a caller wrote before
        bc.SensorParams(xi=1, phi=0, alpha_u=55, alpha_v=-55, u0=400, v0=300, h=-1, beta=1.0)
