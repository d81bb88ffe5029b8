"""Fixtures shared by all tests. Blender-specific fixtures live in tests/blender/conftest.py."""

from __future__ import annotations

from collections.abc import Iterator
from types import ModuleType

import pytest


@pytest.fixture
def blank_blender() -> Iterator[ModuleType]:
    """Yield ``bpy`` after resetting Blender to an empty factory scene.

    Skips the test when bpy (Blender as a Python module) is not installed. bpy is imported
    lazily so that pure core tests never pay for it.
    """
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy
