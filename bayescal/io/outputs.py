"""Output folders that are all-or-nothing and never touch files bayescal did not write.

Rules (``docs/cli.md``, "Output folders"):

* :func:`check_out` refuses, before any work, a ``--out`` that is a file, that
  holds one of the input files, that is read-only, or that is not empty --
  unless ``force`` is given *and* the folder was written by bayescal (it holds
  the manifest :data:`MANIFEST` listing bayescal's own files).
* :class:`OutputFolder` writes into a hidden temporary folder next to the
  target and moves the result into place only when the job finishes (each
  file with an atomic :func:`os.replace`). A failure or Ctrl-C removes the
  temporary folder, so nothing is left behind. With ``force``, only the files
  listed in the previous manifest are replaced or deleted; a new file whose name
  collides with a file bayescal did not write is refused.
* While the files move into place, Ctrl-C is held back (:func:`_sigint_held`):
  a merge into an existing folder is never left half done. A Ctrl-C that came
  during the move is reported as a warning; the files are then complete.
"""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import shutil
import signal
import stat
import tempfile
import threading
import warnings

from ..errors import UsageError

__all__ = ["MANIFEST", "check_out", "OutputFolder", "is_inside"]

MANIFEST = ".bayescal-output.json"


def is_inside(path, folder):
    """True when ``path`` is ``folder`` or lies below it (after resolving links)."""
    try:
        pathlib.Path(path).resolve().relative_to(pathlib.Path(folder).resolve())
        return True
    except ValueError:
        return False


def _existing_ancestor(path):
    p = pathlib.Path(path).absolute()
    while not p.exists():
        p = p.parent
    return p


def _writable(folder):
    """Write permission for us, judged by the mode bits too (root ignores os.access)."""
    mode = folder.stat().st_mode
    return os.access(folder, os.W_OK | os.X_OK) and bool(mode & stat.S_IWUSR)


def _manifest_files(folder, *, parent=True):
    """Files bayescal wrote in ``folder`` (its manifest), or None. A sub-folder without a
    manifest of its own (a demo stage) counts by the files its parent's manifest lists in it."""
    folder = pathlib.Path(folder)
    try:
        data = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        return [str(f) for f in data.get("files", [])]
    except (OSError, ValueError, AttributeError):
        pass
    up = _manifest_files(folder.absolute().parent, parent=False) if parent else None
    prefix = folder.name + "/"
    mine = [f[len(prefix):] for f in up or () if f.startswith(prefix)]
    return mine or None


def check_out(out, *, force, inputs=(), option="--out"):
    """Check that ``out`` may be written; nothing is created here.

    Parameters
    ----------
    out : str or pathlib.Path
        The output folder (new, empty, or written by bayescal before).
    force : bool
        Allow replacing what bayescal wrote there earlier.
    inputs : sequence of path or None
        Input files: ``out`` may not hold any of them.
    option : str
        Option name used in the messages.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    UsageError
        ``out`` is a file; it holds an input file; it (or the folder it would be
        created in) is not writable; it is not empty and has no bayescal manifest
        (whatever ``force``); or it holds bayescal's outputs and ``force`` is False. The
        messages suggest a free folder name.
    """
    out = pathlib.Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{option} {out} is a file; expected a folder")
    for p in inputs:
        if p is not None and is_inside(p, out):
            raise UsageError(f"refusing to write into {out}: it holds the input file {p}; "
                             f"choose another {option} (bayescal never writes next to your data)")
    anc = _existing_ancestor(out)
    if not anc.is_dir() or not _writable(anc):
        raise UsageError(f"{option} {out}: {anc} is not a writable folder; expected a folder "
                         "bayescal may create files in")
    if out.is_dir() and any(out.iterdir()):
        if _manifest_files(out) is None:
            raise UsageError(f"output folder {out} is not empty and was not written by bayescal "
                             f"(no readable {MANIFEST}), so it is left alone, --force or not: "
                             f"choose a new or empty folder, e.g. {option} {_free_name(out)}")
        if not force:
            raise UsageError(f"output folder {out} holds an earlier bayescal run; pass --force "
                             f"to replace it, or choose another {option}, e.g. "
                             f"{_free_name(out)}")
    return out


def _free_name(out):
    """``out-2``, ``out-3``, ...: the first that does not exist yet."""
    k = 2
    while out.with_name(f"{out.name}-{k}").exists():
        k += 1
    return out.with_name(f"{out.name}-{k}")


def _umask():
    """The process's umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


class _SubFolder:
    """A sub-folder of an :class:`OutputFolder`; its files go in the parent's manifest."""

    def __init__(self, root, name):
        self.path = root.path / name
        self.path.mkdir(exist_ok=True)
        self.add = root.add


@contextlib.contextmanager
def _sigint_held():
    """Hold back SIGINT (Ctrl-C) inside the block; yields a list that records one.

    Only the main thread can set a signal handler; elsewhere the block runs as is.
    """
    came = []
    if threading.current_thread() is not threading.main_thread():
        yield came
        return
    old = signal.signal(signal.SIGINT, lambda signum, frame: came.append(signum))
    try:
        yield came
    finally:
        signal.signal(signal.SIGINT, old if old is not None else signal.default_int_handler)


class OutputFolder:
    """Stage a job's files in a temporary folder; move them into ``out`` at the end.

    Use as a context manager: on a normal exit the files move into place
    (:meth:`commit`); on any exception, including ``KeyboardInterrupt``, the
    temporary folder is removed and ``out`` is left as it was.

    Parameters
    ----------
    out : str or pathlib.Path
        Target folder, already checked by :func:`check_out`.

    Attributes
    ----------
    path : pathlib.Path
        The staging folder to write into (valid inside the ``with`` block).
    target : pathlib.Path
    files : list of str
        Files recorded with :meth:`add`, relative to the folder.
    committed : bool
        True once every file is in place in ``target``.
    """

    def __init__(self, out):
        self.target = pathlib.Path(out)
        self.committed = False
        self.path = None
        self.files = []
        self._created = []

    def __enter__(self):
        parent = self.target.absolute().parent
        missing = []
        p = parent
        while not p.exists():
            missing.append(p)
            p = p.parent
        try:
            for d in reversed(missing):
                d.mkdir()
                self._created.append(d)
            self.path = pathlib.Path(tempfile.mkdtemp(prefix=f".{self.target.name}.",
                                                      suffix=".bayescal-tmp", dir=parent))
            # mkdtemp makes the folder 0700; the output folder is renamed from it, so give
            # it the mode a plain mkdir would (0777 less the umask, e.g. 0755)
            os.chmod(self.path, 0o777 & ~_umask())
        except OSError as exc:
            self._remove_created()
            raise UsageError(f"cannot write into {parent}: {exc.strerror}") from None
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        else:
            self.discard()
        return False

    def add(self, *paths):
        """Record written files (paths inside the staging folder); returns the first one."""
        for p in paths:
            rel = pathlib.Path(p).resolve().relative_to(self.path.resolve())
            if str(rel) not in self.files:
                self.files.append(str(rel))
        return paths[0] if paths else None

    def sub(self, name):
        """A sub-folder whose files are recorded in this folder's manifest."""
        return _SubFolder(self, name)

    def discard(self):
        """Remove the staging folder and any parent folder created for it."""
        if self.path is not None:
            shutil.rmtree(self.path, ignore_errors=True)
            self.path = None
        self._remove_created()

    def _remove_created(self):
        for d in reversed(self._created):
            try:
                d.rmdir()
            except OSError:
                pass
        self._created = []

    def _write_manifest(self, folder):
        tmp = folder / (MANIFEST + ".tmp")
        tmp.write_text(json.dumps({"written_by": "bayescal", "files": self.files}, indent=2)
                       + "\n", encoding="utf-8")
        os.replace(tmp, folder / MANIFEST)

    def commit(self):
        """Move the staged files into the target folder (see the class docstring).

        Ctrl-C is held back until every file is in place, then reported as a
        warning: the folder is complete, never half merged.
        """
        target, stage = self.target, self.path
        with _sigint_held() as came:
            try:
                if not target.exists():
                    self._write_manifest(stage)
                    os.rename(stage, target)
                else:
                    self._merge_into(target, stage)
                    shutil.rmtree(stage, ignore_errors=True)
            except BaseException:
                self.discard()
                raise
            self.path = target
            self._created = []
            self.committed = True
        if came:
            warnings.warn(f"Ctrl-C came while the results moved into {target}; it was held "
                          "back until they were all in place: the folder is complete",
                          RuntimeWarning, stacklevel=2)

    def _merge_into(self, target, stage):
        old = _manifest_files(target) or []
        clash = [f for f in self.files if (target / f).exists() and f not in old]
        if clash:
            raise UsageError(f"output folder {target} holds {', '.join(clash)}, which bayescal "
                             "did not write; --force never replaces such files: choose another "
                             "--out")
        for f in old:
            p = target / f
            if f not in self.files and is_inside(p, target) and p.is_file():
                p.unlink()
        for f in self.files:
            (target / f).parent.mkdir(parents=True, exist_ok=True)
            os.replace(stage / f, target / f)
        self._write_manifest(target)
        for d in sorted((p for p in target.rglob("*") if p.is_dir()), reverse=True):
            if not any(d.iterdir()):
                d.rmdir()
