"""Exceptions, warnings and exit codes shared by the command line, the readers, the
samplers and the jobs.

This module imports nothing from bayescal, so every other module may import it
without closing an import cycle.

Every exception the package raises derives from :class:`BayescalError`, so that one
``except bc.BayescalError`` clause catches them all; each also keeps the built-in base a
caller may already catch (``ValueError`` for a bad value, ``TypeError`` for a bad type,
``RuntimeError`` for a fit that failed, ``FileNotFoundError``, ``FileExistsError``,
``ImportError``). Every warning derives from :class:`BayescalWarning` (a ``UserWarning``).

Exit codes of the ``bayescal`` command: :data:`EXIT_OK` (0) success,
:data:`EXIT_FAILED` (1) the job ran but failed or did not converge,
:data:`EXIT_USAGE` (2) bad usage or bad input (nothing written),
:data:`EXIT_INTERRUPTED` (130) interrupted by Ctrl-C (nothing left behind).
"""

from __future__ import annotations

__all__ = ["BayescalError", "BayescalWarning", "UsageError", "Failure", "InvalidValueError",
           "InvalidTypeError", "MissingFileError", "OutputExistsError", "MissingDependencyError",
           "FitError", "UnsupportedError", "InputError", "DegenerateInputError",
           "ExtractionError", "NotConvergedWarning", "NotConvergedError",
           "NoiseAtBoundWarning", "EXIT_OK", "EXIT_FAILED", "EXIT_USAGE", "EXIT_INTERRUPTED"]

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class BayescalError(Exception):
    """The base of every exception bayescal raises."""


class BayescalWarning(UserWarning):
    """The base of every warning bayescal issues."""


class UsageError(BayescalError):
    """Bad usage or bad input found before any output is written: exit code 2."""


class Failure(BayescalError):
    """The job ran but failed (e.g. no convergence): exit code 1."""


class InvalidValueError(BayescalError, ValueError):
    """An argument's value is outside what the function accepts (its message names the
    argument, the value and what was expected)."""


class InvalidTypeError(BayescalError, TypeError):
    """An argument of the wrong type (its message names the argument and the type
    expected)."""


class MissingFileError(BayescalError, FileNotFoundError):
    """A file the call reads does not exist."""


class OutputExistsError(BayescalError, FileExistsError):
    """A file the call would write exists and overwriting was not asked for."""


class MissingDependencyError(BayescalError, ImportError):
    """An optional dependency the call needs is not installed (the message names the
    extra to install)."""


class FitError(BayescalError, RuntimeError):
    """A computation could not proceed on well-formed input (no start inside the support,
    a prior without mass where the model is defined)."""


class UnsupportedError(BayescalError, NotImplementedError):
    """A combination of options the package does not implement."""


class InputError(BayescalError, ValueError):
    """A data file is unreadable or inconsistent (the command line exits with code 2).

    Attributes
    ----------
    path : str
        The file.
    line : int or None
        1-based line in a CSV file (the header is line 1), or 0-based index in
        an NPZ array.
    column : str or None
        The column (CSV) or array (NPZ) name.
    """

    def __init__(self, message, *, path=None, line=None, column=None):
        super().__init__(message)
        self.path, self.line, self.column = path, line, column


class DegenerateInputError(BayescalError, ValueError):
    """Well-formed input that cannot calibrate (too few points, one azimuth, no scene
    information, points on the axis): bad input, exit code 2 from the command line."""


class NotConvergedWarning(BayescalWarning):
    """The chain did not meet its convergence rule (results may be biased)."""


class NoiseAtBoundWarning(BayescalWarning):
    """An inferred noise level's posterior piles up at its prior's lower bound."""


class NotConvergedError(BayescalError, RuntimeError):
    """The chain did not converge; ``.tau`` holds the autocorrelation times, ``.posterior``
    the (unconverged) result."""

    def __init__(self, message, tau=None, posterior=None):
        super().__init__(message)
        self.tau = tau
        self.posterior = posterior


class ExtractionError(BayescalError, ValueError):
    """An image whose laser extraction is implausible: no ring, most of it flagged, too few
    azimuths, or a ring far from the mirror's image (bad input: exit code 2 from the command
    line, nothing written).

    Attributes
    ----------
    reason : str
        What is implausible, with the numbers that show it.
    advice : str
        What to try (a laser-off image, the centre, the colour channel).
    """

    def __init__(self, reason, advice=""):
        super().__init__(f"{reason}. {advice}".strip() if advice else reason)
        self.reason, self.advice = reason, advice
