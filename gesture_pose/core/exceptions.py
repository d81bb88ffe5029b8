"""The one exception hierarchy of gesture_pose.

The core raises these; Blender operators are the only place that turns them into reports.
"""

from __future__ import annotations


class GesturePoseError(Exception):
    """Base class of every error gesture_pose raises on purpose."""


class InputError(GesturePoseError, ValueError):
    """Input the user can fix; the message says what is wrong and what to do."""


class SolverError(GesturePoseError, RuntimeError):
    """A solver failed to find a solution.

    Attributes:
        details: Data useful to debug the failure (solver status, residuals, ...).
    """

    def __init__(self, message: str, details: dict | None = None) -> None:
        super().__init__(message)
        self.details = dict(details or {})
