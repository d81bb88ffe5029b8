"""Fixtures for headless Blender tests: a blank scene, registration and tiny builders.

Every test in this folder is marked ``blender`` and skipped when ``bpy`` is missing.
Scenes are built in code; builders return Blender objects linked to the scene.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

_HERE = Path(__file__).resolve().parent

#: (name, head, tail, parent name or None, connected, roll in radians), armature space.
BoneRow = tuple[str, Sequence[float], Sequence[float], str | None, bool, float]


def pytest_collection_modifyitems(config, items) -> None:
    for item in items:
        if _HERE in Path(item.path).resolve().parents:
            item.add_marker(pytest.mark.blender)


@pytest.fixture
def bpy_blank():
    """An empty factory scene; returns the bpy module."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy


def _is_registered() -> bool:
    from gesture_pose.blender import properties

    return properties.GesturePoseSettings.is_registered and hasattr(bpy.types.Scene,
                                                                    "gesture_pose")


@pytest.fixture(scope="session")
def _registration():
    import gesture_pose

    gesture_pose.register()
    yield gesture_pose
    if _is_registered():
        gesture_pose.unregister()


@pytest.fixture
def registered(_registration, bpy_blank):
    """A blank scene with gesture_pose registered (registered once per session).

    Classes registered with ``bpy.utils.register_class`` survive
    ``read_factory_settings``; this re-registers them should that ever change.
    """
    if not _is_registered():
        _registration.register()
    return bpy_blank


def link(obj):
    """Link ``obj`` to the scene's master collection and return it."""
    bpy.context.scene.collection.objects.link(obj)
    return obj


def add_empty(name: str = "Target", location: Sequence[float] = (0.0, 0.0, 0.0)):
    """An empty object at ``location``, linked to the scene (a constraint's target)."""
    obj = link(bpy.data.objects.new(name, None))
    obj.location = location
    return obj


def constrain(rig, bone: str, kind: str, **settings):
    """Add a constraint of ``kind`` to a pose bone, with its settings; returns it."""
    c = rig.pose.bones[bone].constraints.new(kind)
    for key, value in settings.items():
        setattr(c, key, value)
    return c


def build_armature(rows: Sequence[BoneRow], name: str = "Rig",
                   location: Sequence[float] = (0.0, 0.0, 0.0),
                   rotation_euler: Sequence[float] = (0.0, 0.0, 0.0), scale: float = 1.0):
    """An armature object from bone rows, left in Object Mode and active."""
    arm = bpy.data.armatures.new(name)
    obj = link(bpy.data.objects.new(name, arm))
    obj.location, obj.rotation_euler, obj.scale = location, rotation_euler, (scale,) * 3
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    for bone_name, head, tail, _parent, _connected, roll in rows:
        eb = arm.edit_bones.new(bone_name)
        eb.head, eb.tail, eb.roll = head, tail, roll
    for bone_name, _head, _tail, parent, connected, _roll in rows:
        if parent is not None:
            eb = arm.edit_bones[bone_name]
            eb.parent = arm.edit_bones[parent]
            eb.use_connect = connected
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.context.view_layer.update()
    return obj


#: Two roots, a connected chain, an unconnected child and non-zero rolls (a child is listed
#: before its parent: the builder sets parents after creating every bone).
TWO_ROOTS: tuple[BoneRow, ...] = (
    ("fore", (0.7, 0.1, 1.7), (1.1, -0.2, 1.6), "arm", True, -0.8),
    ("hip", (0.0, 0.0, 1.0), (0.0, 0.1, 1.4), None, False, 0.3),
    ("spine", (0.0, 0.1, 1.4), (0.05, 0.0, 1.9), "hip", True, -0.5),
    ("arm", (0.2, 0.0, 1.8), (0.7, 0.1, 1.7), "spine", False, 1.1),
    ("prop", (1.0, 1.0, 0.0), (1.0, 1.5, 0.2), None, False, 0.7),
    ("prop_tip", (1.0, 1.5, 0.2), (1.3, 1.9, 0.2), "prop", True, 0.2),
)


@pytest.fixture
def two_root_rig(bpy_blank):
    """The TWO_ROOTS armature, moved, rotated and uniformly scaled by 1.7."""
    return build_armature(TWO_ROOTS, location=(0.4, -1.2, 0.3),
                          rotation_euler=(0.3, -0.2, 0.9), scale=1.7)


def add_camera(location: Sequence[float], target: Sequence[float], name: str = "Cam",
               ortho_scale: float | None = None, lens: float = 50.0):
    """A camera at ``location`` aimed at ``target``, made the scene camera."""
    from mathutils import Vector

    data = bpy.data.cameras.new(name)
    data.lens = lens
    if ortho_scale is not None:
        data.type, data.ortho_scale = "ORTHO", ortho_scale
    obj = link(bpy.data.objects.new(name, data))
    obj.location = location
    direction = Vector(target) - Vector(location)
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.camera = obj
    bpy.context.view_layer.update()
    return obj


def add_grease_pencil(strokes_world: Sequence[np.ndarray], name: str = "Sketch",
                      layer: str = "Lines", frame: int = 1):
    """A Grease Pencil v3 object holding world-space strokes (identity object transform)."""
    gp = bpy.data.grease_pencils.new(name)
    obj = link(bpy.data.objects.new(name, gp))
    drawing = gp.layers.new(layer, set_active=True).frames.new(frame).drawing
    drawing.add_strokes([len(s) for s in strokes_world])
    flat = np.concatenate([np.asarray(s, dtype=float) for s in strokes_world]).ravel()
    drawing.attributes["position"].data.foreach_set("vector", flat.astype(np.float32))
    return obj
