"""Registration: every module's classes register, sub-panels sit under the main panel."""

from __future__ import annotations

import importlib

import pytest

from gesture_pose.blender import registration

bpy = pytest.importorskip("bpy")


def _classes():
    for name in registration.MODULES:
        module = importlib.import_module(f"gesture_pose.blender.{name}")
        yield from getattr(module, "CLASSES", ())


def test_every_class_registers_and_sub_panels_sit_under_the_main_panel(registered) -> None:
    classes = list(_classes())
    assert len(classes) >= 12
    panels = [c for c in classes if issubclass(c, bpy.types.Panel)]
    operators = [c for c in classes if issubclass(c, bpy.types.Operator)]
    assert all(c.is_registered for c in classes)
    main = [p for p in panels if not getattr(p, "bl_parent_id", "")]
    assert [p.bl_idname for p in main] == ["VIEW3D_PT_gesture_pose"]
    for panel in panels:
        assert panel.bl_category == "Gesture Pose" and panel.bl_region_type == "UI"
        if panel not in main:
            assert panel.bl_parent_id == "VIEW3D_PT_gesture_pose"
    for op in operators:
        assert op.bl_idname.startswith("gesture_pose.")
        assert "UNDO" in op.bl_options
    assert hasattr(bpy.types.Scene, "gesture_pose")
