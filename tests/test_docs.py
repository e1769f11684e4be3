"""The documentation: every public name has its place in the API reference, and the
examples in the public docstrings run (doctests)."""

import doctest
import importlib.util
import pathlib
import sys

import numpy as np
import pytest

import bayescal as bc

DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"


def _conf():
    spec = importlib.util.spec_from_file_location("_docs_conf", DOCS / "conf.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_public_name_is_in_the_reference():
    sections = _conf().public_api_by_layer()
    placed = [n for names in sections.values() for n in names]
    assert sorted(placed) == sorted(bc.__all__)
    assert len(placed) == len(set(placed))
    layers = [s for s in sections if " " not in s]
    assert layers == [s for s in layers if s in _conf()._layers()] or all(
        (pathlib.Path(bc.__file__).parent / s).is_dir() for s in layers)


def _public_modules():
    mods = {getattr(bc, n).__module__ for n in bc.__all__ if callable(getattr(bc, n))}
    return sorted(m for m in mods if m != "bayescal.mcmc.nuts")


@pytest.mark.parametrize("module", _public_modules())
def test_docstring_examples_run(module):
    mod = sys.modules[module]
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = [t for t in finder.find(mod, module) if t.examples]
    for t in tests:
        t.globs.setdefault("np", np)
        runner.run(t, out=lambda s: None)
    res = runner.summarize(verbose=False)
    assert res.failed == 0, f"{res.failed} of {res.attempted} examples failed in {module}"
