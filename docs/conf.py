"""Sphinx configuration of the bayescal documentation (``make docs``).

The API reference is generated at build time from ``bayescal.__all__``, grouped by the
layer (subpackage) each object is defined in, in the order ``tests/test_structure.py``
declares: a new public name gets its page without anyone editing the docs.
"""

import ast
import os
import pathlib
import sys

import matplotlib

matplotlib.use("agg")

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import bayescal  # noqa: E402

project = "bayescal"
author = "the bayescal developers"
copyright = "2026, the bayescal developers"
release = version = bayescal.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "sphinxarg.ext",
    "sphinxcontrib.mermaid",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "tutorials", "**/*.ipynb", "auto_tutorials/*.py",
                    "auto_tutorials/*.ipynb", "auto_tutorials/*.zip",
                    # study outputs (tables next to their figures), linked, not pages
                    "img/**/*.md"]
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath"]
myst_fence_as_directive = ["mermaid"]     # diagrams drawn in the browser
autosummary_generate = True
autodoc_default_options = {"members": False}
numpydoc_show_class_members = False
numpydoc_xref_param_type = False
html_theme = "pydata_sphinx_theme"
html_title = "bayescal"
html_theme_options = {"navigation_with_keys": False}
suppress_warnings = ["myst.header"]       # the pages start at level 1 and may skip levels

# Tutorials run when the docs are built (sphinx-gallery); BAYESCAL_DOCS_QUICK=1 (CI) makes
# them cheap: fewer points and samples, same code path.
sphinx_gallery_conf = {
    "examples_dirs": "tutorials",
    "gallery_dirs": "auto_tutorials",
    "filename_pattern": r"/\d\d_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "matplotlib_animations": False,
}


def _layers():
    """``LAYERS`` of ``tests/test_structure.py``, read from its source (not imported: that
    needs pytest, which the docs extra does not install)."""
    tree = ast.parse((ROOT / "tests" / "test_structure.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "LAYERS"
                                                for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise RuntimeError("tests/test_structure.py defines no LAYERS tuple")


def public_api_by_layer():
    """``{layer: [name, ...]}`` for every name in ``bayescal.__all__``, layers in the
    declared order (an unknown subpackage is added after them; top-level modules last)."""
    groups = {layer: [] for layer in _layers()}
    for name in bayescal.__all__:
        obj = getattr(bayescal, name)
        module = getattr(obj, "__module__", None) or "bayescal"
        parts = module.split(".")
        layer = parts[1] if len(parts) > 2 and callable(obj) else "constants and errors"
        groups.setdefault(layer, []).append(name)
    return {k: sorted(v, key=str.lower) for k, v in groups.items() if v}


def _write_api(app):
    api = HERE / "api"
    api.mkdir(exist_ok=True)
    sections = public_api_by_layer()
    lines = ["API reference", "=============", "",
             "Every public name of ``bayescal`` (``import bayescal as bc``), grouped by the "
             "layer it is defined in (:doc:`../architecture`).", ""]
    for layer, names in sections.items():
        title = layer if " " in layer else f"``{layer}/``"
        lines += [title, "-" * len(title), ""]
        funcs = [n for n in names if callable(getattr(bayescal, n))]
        consts = [n for n in names if n not in funcs]
        if funcs:
            lines += [".. currentmodule:: bayescal", "", ".. autosummary::",
                      "   :toctree: generated", ""] + [f"   {n}" for n in funcs] + [""]
        for n in consts:
            lines += [f".. data:: bayescal.{n}", "", f"   ``{getattr(bayescal, n)!r}``", ""]
    (api / "index.rst").write_text("\n".join(lines) + "\n")


# written before Sphinx reads the sources, so that autosummary generates their stubs
if "sphinx.application" in sys.modules:
    _write_api(None)


def setup(app):
    os.environ.setdefault("MPLBACKEND", "agg")
