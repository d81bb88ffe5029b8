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
    facing_name = {i: n for i, n, _ in DRAWING_FACING_ITEMS}[facing]
    body_up_name = {i: n for i, n, _ in DRAWING_BODY_UP_ITEMS}[body_up]
    read = ([f"Facing {facing_name}"] if facing != "auto" else []) + (
        [f"Body Up {body_up_name}"] if body_up != "up" else [])
    return f"; read with {', '.join(read)}" if read else ""


class DrawingSettingsProperties:
    """Facing and Body Up on an operator reading a gesture drawing (Pose, Fit Drawing).

    Mix in before ``bpy.types.Operator``. Both are SKIP_SAVE: unset, the operator takes
    the panel's (:meth:`drawing_settings`), and a panel button passes it
    (:func:`pass_drawing_settings`) so the redo panel shows the value used.
    """

    facing: bpy.props.EnumProperty(name="Facing", items=DRAWING_FACING_ITEMS, default="auto",
                                   options={"SKIP_SAVE"},
                                   description="Which side of the character the drawing "
                                   "shows (unset: the panel's Facing)")
    body_up: bpy.props.EnumProperty(name="Body Up", items=DRAWING_BODY_UP_ITEMS,
                                    default="up", options={"SKIP_SAVE"},
                                    description="Which way the character's up points in the "
                                    "drawing (unset: the panel's Body Up)")

    def drawing_settings(self, context: bpy.types.Context) -> dict[str, str]:
        """``{"facing": ..., "body_up": ...}`` as this run reads the drawing."""
        return {name: drawing_setting(self, context, name) for name in _DRAWING_DEFAULTS}


def pass_drawing_settings(op, context: bpy.types.Context):
    """Give a panel's operator button the scene's Facing and Body Up.

    Args:
        op: The button's operator properties.
        context: The panel's context.

    Returns:
        The scene's settings, or None (nothing passed) when the scene has none.
    """
    settings = getattr(context.scene, "gesture_pose", None)
    if settings is not None:
        for name in _DRAWING_DEFAULTS:
            setattr(op, name, getattr(settings, name))
    return settings


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
