"""Scene settings of gesture_pose: which armature to pose and which sketch to read.

Stored on every scene as ``scene.gesture_pose`` (a :class:`GesturePoseSettings`).
"""

from __future__ import annotations

import bpy


def _is_armature(_self, obj: bpy.types.Object) -> bool:
    return obj.type == "ARMATURE"


def _is_sketch(_self, obj: bpy.types.Object) -> bool:
    return obj.type in {"GREASEPENCIL", "CURVE"}


#: The Facing of Pose and Fit Drawing (``core.gesture.embedding.facing_turn``).
DRAWING_FACING_ITEMS = [
    ("auto", "As Seen", "The side the character shows in this view in its bind pose"),
    ("front", "Front", "The drawing shows the character's front"),
    ("back", "Back", "The drawing shows the character's back (its left on the image's "
     "left)"),
    ("turned", "Turned Round", "The drawing shows the character turned half round from "
     "how this view shows it in its bind pose (a profile facing the other way)"),
]


def drawing_facing(op: bpy.types.Operator, context: bpy.types.Context) -> str:
    """An operator's ``facing`` when it was given, else the panel's (``"auto"`` without)."""
    if op.properties.is_property_set("facing"):
        return op.facing
    settings = getattr(context.scene, "gesture_pose", None)
    return settings.facing if settings is not None else "auto"


class GesturePoseSettings(bpy.types.PropertyGroup):
    """The armature and sketch the Gesture Pose operators use by default."""

    armature: bpy.props.PointerProperty(
        name="Armature",
        description="Character armature to pose (the active armature when empty)",
        type=bpy.types.Object,
        poll=_is_armature,
    )
    sketch: bpy.props.PointerProperty(
        name="Sketch",
        description="Grease Pencil or curve object holding the drawing (the active or only "
        "Grease Pencil object when empty)",
        type=bpy.types.Object,
        poll=_is_sketch,
    )
    facing: bpy.props.EnumProperty(
        name="Facing",
        description="Which side of the character the gesture drawing shows",
        items=DRAWING_FACING_ITEMS,
        default="auto",
    )


CLASSES = (GesturePoseSettings,)


def register_extra() -> None:
    """Attach the settings to every scene as ``scene.gesture_pose``."""
    bpy.types.Scene.gesture_pose = bpy.props.PointerProperty(type=GesturePoseSettings)


def unregister_extra() -> None:
    """Remove ``scene.gesture_pose``."""
    del bpy.types.Scene.gesture_pose
