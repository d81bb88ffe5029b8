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


#: The Body Up of Pose and Fit Drawing (``core.gesture.embedding.rolled_in_view``).
DRAWING_BODY_UP_ITEMS = [
    ("up", "Up", "The character stands as in its bind pose: its up is the drawing's up"),
    ("left", "Left", "The character lies with its up (a humanoid's head) towards the "
     "drawing's left"),
    ("down", "Down", "The character is upside down in the drawing (a handstand, a "
     "cartwheel)"),
    ("right", "Right", "The character lies with its up (a humanoid's head) towards the "
     "drawing's right"),
]

#: Defaults of the drawing settings an operator takes from the panel when not given.
_DRAWING_DEFAULTS = {"facing": "auto", "body_up": "up"}


def drawing_setting(op: bpy.types.Operator, context: bpy.types.Context, name: str) -> str:
    """An operator's ``facing`` or ``body_up``: its own when given, else the panel's.

    Args:
        op: The operator.
        context: Its context (the scene's ``gesture_pose`` settings).
        name: ``"facing"`` or ``"body_up"``.

    Returns:
        The value; the setting's default when the scene has no settings.
    """
    if op.properties.is_property_set(name):
        return getattr(op, name)
    settings = getattr(context.scene, "gesture_pose", None)
    return getattr(settings, name) if settings is not None else _DRAWING_DEFAULTS[name]


def drawing_settings_note(facing: str, body_up: str) -> str:
    """``"; read with Facing Back, Body Up Down"`` for settings other than the defaults.

    Args:
        facing: The Facing used (``DRAWING_FACING_ITEMS``' identifiers).
        body_up: The Body Up used (``DRAWING_BODY_UP_ITEMS``' identifiers).

    Returns:
        The note, empty for As Seen and Up.
    """
    names = {**{f"facing {i}": n for i, n, _ in DRAWING_FACING_ITEMS},
             **{f"body_up {i}": n for i, n, _ in DRAWING_BODY_UP_ITEMS}}
    read = ([f"Facing {names[f'facing {facing}']}"] if facing != "auto" else []) + (
        [f"Body Up {names[f'body_up {body_up}']}"] if body_up != "up" else [])
    return f"; read with {', '.join(read)}" if read else ""


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
    body_up: bpy.props.EnumProperty(
        name="Body Up",
        description="Which way the character's up (a humanoid's head) points in the "
        "gesture drawing",
        items=DRAWING_BODY_UP_ITEMS,
        default="up",
    )


CLASSES = (GesturePoseSettings,)


def register_extra() -> None:
    """Attach the settings to every scene as ``scene.gesture_pose``."""
    bpy.types.Scene.gesture_pose = bpy.props.PointerProperty(type=GesturePoseSettings)


def unregister_extra() -> None:
    """Remove ``scene.gesture_pose``."""
    del bpy.types.Scene.gesture_pose
