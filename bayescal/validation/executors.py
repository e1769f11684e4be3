"""Where trials run: inline, in local processes, or on a Dask cluster.

The coverage engine (:mod:`bayescal.validation.coverage`) and the study
scripts hand their trials to :func:`run_trials`; each trial gets its own
generator spawned from one seed, so a run is reproducible whatever the
executor.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import sys
import warnings

import numpy as np

from ..errors import InvalidValueError

__all__ = ["executor", "run_trials"]


class _InlineExecutor(concurrent.futures.Executor):
    """Runs every call at submission, in this process (``--workers 1``)."""

    def submit(self, fn, /, *args, **kwargs):
        fut = concurrent.futures.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 (handed to the caller through the future)
            fut.set_exception(exc)
        return fut


@contextlib.contextmanager
def executor(*, workers=2, scheduler=None):
    """A ``concurrent.futures.Executor``: inline (1 worker), local processes, or Dask.

    Parameters
    ----------
    workers : int
        Local processes (1 = inline, no process pool).
    scheduler : str, optional
        Address of a Dask ``distributed`` scheduler (e.g. ``tcp://host:8786``).
    """
    if scheduler is not None:
        try:
            import distributed
        except ImportError:
            raise InvalidValueError(f"--scheduler {scheduler!r} needs the 'dask' extra "
                                    "(the distributed package)") from None
        client = distributed.Client(scheduler, set_as_default=False, timeout="20s")
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
        return
    if workers <= 1:
        yield _InlineExecutor()
        return
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers) as pool:
        yield pool


def _call(fn, spec, seed_seq):
    """Run one trial with its own generator (top level so that it pickles)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(spec, np.random.default_rng(seed_seq))


def run_trials(fn, specs, *, seed, workers=2, scheduler=None, progress=True):
    """Run ``fn(spec, rng)`` for every spec; results in the order of ``specs``.

    Parameters
    ----------
    fn : callable
        ``fn(spec, rng) -> dict``, a module-level function (it must pickle).
    specs : list of dict
    seed : int or sequence of int
        Trial ``i`` gets ``default_rng(SeedSequence(seed).spawn(n)[i])``.
    workers, scheduler
        See :func:`executor`.

    Returns
    -------
    list
    """
    children = np.random.SeedSequence(seed).spawn(len(specs))
    if scheduler is not None and fn.__module__ in sys.modules \
            and not fn.__module__.startswith("bayescal"):
        import cloudpickle  # ship the study module to remote workers by value

        cloudpickle.register_pickle_by_value(sys.modules[fn.__module__])
    with executor(workers=workers, scheduler=scheduler) as ex:
        futures = [ex.submit(_call, fn, s, c) for s, c in zip(specs, children, strict=True)]
        out = []
        for k, fut in enumerate(futures):
            out.append(fut.result())
            if progress:
                print(f"  trial {k + 1}/{len(specs)} done", flush=True)
    return out
