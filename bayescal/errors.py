"""Exceptions, warnings and exit codes shared by the command line, the readers, the
samplers and the jobs.

This module imports nothing from bayescal, so every other module may import it
without closing an import cycle.

Exit codes of the ``bayescal`` command: :data:`EXIT_OK` (0) success,
:data:`EXIT_FAILED` (1) the job ran but failed or did not converge,
:data:`EXIT_USAGE` (2) bad usage or bad input (nothing written),
:data:`EXIT_INTERRUPTED` (130) interrupted by Ctrl-C (nothing left behind).
"""

from __future__ import annotations

__all__ = ["UsageError", "Failure", "InputError", "DegenerateInputError", "ExtractionError",
           "NotConvergedWarning", "NotConvergedError",
           "NoiseAtBoundWarning", "EXIT_OK", "EXIT_FAILED", "EXIT_USAGE", "EXIT_INTERRUPTED"]

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """Bad usage or bad input found before any output is written: exit code 2."""


class Failure(Exception):
    """The job ran but failed (e.g. no convergence): exit code 1."""


class InputError(ValueError):
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


class DegenerateInputError(ValueError):
    """Well-formed input that cannot calibrate (too few points, one azimuth, no scene
    information, points on the axis): bad input, exit code 2 from the command line."""


class NotConvergedWarning(UserWarning):
    """The chain did not meet its convergence rule (results may be biased)."""


class NoiseAtBoundWarning(UserWarning):
    """An inferred noise level's posterior piles up at its prior's lower bound."""


class NotConvergedError(RuntimeError):
    """The chain did not converge; ``.tau`` holds the autocorrelation times, ``.posterior``
    the (unconverged) result."""

    def __init__(self, message, tau=None, posterior=None):
        super().__init__(message)
        self.tau = tau
        self.posterior = posterior


class ExtractionError(ValueError):
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
