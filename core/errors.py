"""The package's error hierarchy: every error raised on bad input is a :class:`PiezopreloadError`.

The command line prints such an error as one ``error: ...`` line and exits 2 (bad input) or 1
(:class:`InternalError`, a failure of the tool itself). Errors that are also ``ValueError``
(a value out of range, a malformed file) subclass both, so ``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = ["PiezopreloadError", "InputError", "ArtifactError", "InfeasibleError", "InternalError"]


class PiezopreloadError(Exception):
    """Base class of every error the package raises on purpose; the message names the argument,
    the value received and what was expected."""


class InputError(PiezopreloadError, ValueError):
    """Bad input from the user (a file, an argument, a value out of range): exit code 2."""


class ArtifactError(InputError):
    """An artifact file that cannot be used (wrong schema, missing field, changed after writing)."""


class InfeasibleError(InputError):
    """A request no solution meets (a design, a tuning specification); the message names the
    constraints that bind and by how much."""


class InternalError(PiezopreloadError, RuntimeError):
    """A failure of the tool itself, not of its input: exit code 1."""
