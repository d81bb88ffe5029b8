"""The "Sketch Abstraction" sub-panel and the scene's choice of abstraction."""

from __future__ import annotations

import bpy

from ..abstraction_io import abstraction_collections
from ..panel import GesturePoseSubPanel
from .abstraction import GESTUREPOSE_OT_drawover, GESTUREPOSE_OT_pose_abstraction


def _is_abstraction(_self, coll: bpy.types.Collection) -> bool:
    """Poll of ``scene.gesture_pose_abstraction``: collections with curve-like objects."""
    return any(o.type in {"MESH", "CURVE", "GREASEPENCIL"} for o in coll.all_objects)


class VIEW3D_PT_gesture_pose_abstraction(GesturePoseSubPanel, bpy.types.Panel):
    """Sketch abstractions and draw-over posing."""

    bl_idname = "VIEW3D_PT_gesture_pose_abstraction"
    bl_label = "Sketch Abstraction"

    def draw(self, context: bpy.types.Context) -> None:
        """The abstraction picker and both operators."""
        layout = self.layout
        layout.prop(context.scene, "gesture_pose_abstraction", text="Abstraction")
        if context.scene.gesture_pose_abstraction is None:
            found = abstraction_collections(context.scene)
            layout.label(text=f"Using: {found[0].name}" if found else "No abstraction found",
                         icon="INFO")
        col = layout.column(align=True)
        col.operator(GESTUREPOSE_OT_pose_abstraction.bl_idname, icon="OUTLINER_OB_CURVE")
        col.operator(GESTUREPOSE_OT_drawover.bl_idname, icon="GREASEPENCIL")


CLASSES = (VIEW3D_PT_gesture_pose_abstraction,)


def register_extra() -> None:
    """Add ``scene.gesture_pose_abstraction`` (the chosen abstraction collection)."""
    bpy.types.Scene.gesture_pose_abstraction = bpy.props.PointerProperty(
        name="Abstraction", type=bpy.types.Collection, poll=_is_abstraction,
        description="Collection of curves, Grease Pencil strokes or mesh edges that deform "
        "with the armature (empty: the first child of 'Sketch Abstraction')")


def unregister_extra() -> None:
    """Remove ``scene.gesture_pose_abstraction``."""
    del bpy.types.Scene.gesture_pose_abstraction
