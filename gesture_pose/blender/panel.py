"""The "Gesture Pose" sidebar panel; each mode adds its own sub-panel under it.

A mode's sub-panel, in the mode's own module, mixes in :class:`GesturePoseSubPanel`
(before ``bpy.types.Panel``) and sets its ``bl_idname``, ``bl_label`` and ``draw``.
"""

from __future__ import annotations

import bpy


class VIEW3D_PT_gesture_pose(bpy.types.Panel):
    """Pick the armature to pose and the sketch to pose it from."""

    bl_idname = "VIEW3D_PT_gesture_pose"
    bl_label = "Gesture Pose"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Gesture Pose"

    def draw(self, context: bpy.types.Context) -> None:
        """Draw the armature and sketch pickers."""
        layout = self.layout
        settings = getattr(context.scene, "gesture_pose", None)
        if settings is None:
            layout.label(text="Gesture Pose is not registered", icon="ERROR")
            return
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(settings, "armature", icon="ARMATURE_DATA")
        layout.prop(settings, "sketch", icon="OUTLINER_OB_GREASEPENCIL")


class GesturePoseSubPanel:
    """Where every mode's sub-panel goes: under the Gesture Pose tab's main panel."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Gesture Pose"
    bl_parent_id = VIEW3D_PT_gesture_pose.bl_idname


CLASSES = (VIEW3D_PT_gesture_pose,)
