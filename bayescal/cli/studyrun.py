"""The shared study runner: command line, executors (inline, processes, Dask), seeded trials.

Every script in ``studies/`` runs through :func:`study_main`, so every study
takes the same options (``--out``, ``--quick``, ``--seed``, ``--workers``,
``--scheduler ADDRESS``, ``--force``) and ``bayescal study NAME`` can pass them
through. Trials are seeded by ``SeedSequence(seed).spawn(n)`` children, so the
numbers never depend on the executor.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

from ..errors import InvalidValueError, OutputExistsError, UsageError
from ..validation.executors import executor, run_trials  # noqa: F401 (the study scripts' runner)

__all__ = ["studies_dir", "list_studies", "find_study", "NOT_STUDIES", "parse_args",
           "executor", "run_trials", "OutputDir", "write_json", "study_main", "MODES"]

MODES = ("full", "quick", "smoke")
#: scripts in studies/ that are not studies (benchmark.py writes docs/performance.md)
NOT_STUDIES = frozenset({"benchmark"})


def studies_dir():
    """Folder of study scripts: ``$BAYESCAL_STUDIES_DIR`` or ``studies/`` beside the package."""
    env = os.environ.get("BAYESCAL_STUDIES_DIR")
    if env:
        return pathlib.Path(env)
    return pathlib.Path(__file__).resolve().parents[2] / "studies"


def list_studies(folder=None):
    """Names of the study scripts in ``folder`` (default :func:`studies_dir`), sorted."""
    folder = pathlib.Path(folder) if folder is not None else studies_dir()
    if not folder.is_dir():
        return []
    return sorted(p.stem for p in folder.glob("*.py")
                  if not p.stem.startswith("_") and p.stem not in NOT_STUDIES)


def find_study(name):
    """``(name, script path)`` of a study; :class:`UsageError` listing the studies if unknown."""
    folder = studies_dir()
    name = name[:-3] if name.endswith(".py") else name
    if name not in list_studies(folder):
        avail = ", ".join(list_studies(folder)) or "none"
        raise UsageError(f"no study named {name!r} in {folder}; available: {avail}")
    return name, folder / f"{name}.py"


def parse_args(description, argv=None, *, add_arguments=None):
    """The common command line of every study (``mode`` in :data:`MODES` added)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--out", required=True, help="output folder for the JSON and PNG files")
    parser.add_argument("--quick", action="store_true",
                        help="short version (about two minutes on 2 cores)")
    parser.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--workers", type=int, default=2,
                        help="local worker processes (default: 2; 1 runs inline)")
    parser.add_argument("--scheduler", default=None,
                        help="address of a Dask distributed scheduler to run the trials on")
    parser.add_argument("--force", action="store_true", help="overwrite existing result files")
    if add_arguments is not None:
        add_arguments(parser)
    args = parser.parse_args(argv)
    if args.seed < 0:
        parser.error(f"--seed must be non-negative, got {args.seed}")
    if args.workers < 1:
        parser.error(f"--workers must be at least 1, got {args.workers}")
    args.mode = "smoke" if args.smoke else ("quick" if args.quick else "full")
    return args


class OutputDir:
    """The ``--out`` folder of a study; refuses to overwrite its files unless ``force``.

    Parameters
    ----------
    path : str or pathlib.Path
    names : sequence of str
        File names the study will write; checked before any work is done.
    force : bool
    """

    def __init__(self, path, names, *, force=False):
        self.path = pathlib.Path(path)
        existing = [n for n in names if (self.path / n).exists()]
        if existing and not force:
            raise OutputExistsError(f"--out {str(self.path)!r} already holds {existing}; "
                                    "pass --force to overwrite them")
        self.path.mkdir(parents=True, exist_ok=True)
        self.names = tuple(names)

    def __truediv__(self, name):
        if name not in self.names:
            raise InvalidValueError(f"{name!r} is not among the declared result files {self.names}")
        return self.path / name


def write_json(path, data):
    """Write ``data`` as indented JSON (NaN and infinities as null)."""
    from ..io.data import to_jsonable

    path = pathlib.Path(path)
    path.write_text(json.dumps(to_jsonable(data, nonfinite="null"), indent=1) + "\n")
    return path


def study_main(run, description, argv, files, *, add_arguments=None):
    """Parse the common options, check the output folder, run ``run(args, out)``.

    Returns
    -------
    int
        Exit code: 0, or 2 when the output folder already holds the files.
    """
    args = parse_args(description, argv, add_arguments=add_arguments)
    try:
        out = OutputDir(args.out, files, force=args.force)
    except FileExistsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    run(args, out)
    # run from the CLI, the script writes into a staging folder that is moved into place
    shown = pathlib.Path(os.environ.get("BAYESCAL_STUDY_SHOWN_OUT", out.path))
    print(f"done in {time.perf_counter() - t0:.0f} s; wrote "
          + ", ".join(str(shown / n) for n in files))
    return 0
