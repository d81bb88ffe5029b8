"""Gesture Pose: pose rigged characters from drawings made in the viewport.

This module only registers. Blender is imported lazily so that ``gesture_pose.core`` stays
importable (and testable) without Blender.
"""

from __future__ import annotations


def register() -> None:
    """Register the extension's properties, operators and panels with Blender."""
    from .blender import registration

    registration.register()


def unregister() -> None:
    """Unregister everything :func:`register` registered, in reverse order."""
    from .blender import registration

    registration.unregister()
