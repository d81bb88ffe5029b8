"""Registration of every Blender class of the extension.

Each module named in :data:`MODULES` exposes ``CLASSES`` (registered in order) and may
expose ``register_extra()`` / ``unregister_extra()`` for properties attached to Blender
types. Modules are registered in list order and unregistered in reverse.
"""

from __future__ import annotations

import importlib
from types import ModuleType

import bpy

#: Modules relative to this package, in registration order (parents before sub-panels).
MODULES: tuple[str, ...] = (
    "properties",
    "panel",
    "operators.pose_drawing",
    "operators.pose_stroke",
    "operators.abstraction", "operators.abstraction_ui",
    "operators.fit_drawing",
    "operators.stick",
)


def _modules() -> list[ModuleType]:
    return [importlib.import_module(f".{name}", __package__) for name in MODULES]


def register() -> None:
    """Register all classes, then the extra properties of each module."""
    for module in _modules():
        for cls in getattr(module, "CLASSES", ()):
            bpy.utils.register_class(cls)
        extra = getattr(module, "register_extra", None)
        if extra is not None:
            extra()


def unregister() -> None:
    """Undo :func:`register`, in reverse order."""
    for module in reversed(_modules()):
        extra = getattr(module, "unregister_extra", None)
        if extra is not None:
            extra()
        for cls in reversed(getattr(module, "CLASSES", ())):
            bpy.utils.unregister_class(cls)
