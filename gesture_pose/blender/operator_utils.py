"""What every Gesture Pose operator shares: finding its inputs and reporting its errors.

Operators read Blender state once, solve, and write last, so that an error raised while
reading or solving leaves the scene untouched. :class:`GesturePoseOperatorMixin` turns the
package's own errors into an ERROR report and ``{'CANCELLED'}``; any other exception is a
bug and propagates.
"""

from __future__ import annotations

import bpy

from ..core.exceptions import GesturePoseError, InputError

SKETCH_TYPES = frozenset({"GREASEPENCIL", "CURVE"})
#: Custom property naming the curve sketch a fit overlay object belongs to.
FIT_OF = "gesture_pose_fit_of"


def _settings(context):
    return getattr(context.scene, "gesture_pose", None)


def _named(name: str, kinds: frozenset[str], what: str, wanted: str) -> bpy.types.Object:
    obj = bpy.data.objects.get(name)
    if obj is None:
        raise InputError(f"No object named '{name}': check the {what} name.")
    if obj.type not in kinds:
        article = "an" if obj.type[0] in "AEIOU" else "a"
        raise InputError(f"'{name}' is {article} {obj.type.lower()} object but the {what} must be "
                         f"{wanted}: pick another object.")
    return obj


def resolve_armature(context, name: str | None = None) -> bpy.types.Object:
    """The armature an operator should pose.

    In order: the object called ``name``; the armature picked in the Gesture Pose panel;
    the active object if it is an armature; the only selected armature.

    Args:
        context: Blender context (or override).
        name: Explicit object name (an operator property), empty or None to search.

    Returns:
        An object of type ``'ARMATURE'``.

    Raises:
        InputError: The named object is not an armature, or no armature was found.
    """
    if name:
        return _named(name, frozenset({"ARMATURE"}), "armature", "an armature")
    settings = _settings(context)
    if settings is not None and settings.armature is not None:
        return settings.armature
    active = getattr(context, "active_object", None)
    if active is not None and active.type == "ARMATURE":
        return active
    selected = [o for o in getattr(context, "selected_objects", ()) if o.type == "ARMATURE"]
    if len(selected) == 1:
        return selected[0]
    raise InputError("No armature: select the character's armature or pick it in the "
                     "Gesture Pose panel.")


def resolve_sketch(context, name: str | None = None,
                   armature: bpy.types.Object | None = None) -> bpy.types.Object:
    """The Grease Pencil (or curve) object holding the drawing.

    In order: the object called ``name`` (Grease Pencil or curve); the sketch picked in the
    Gesture Pose panel; the active object if it is Grease Pencil; the only selected Grease
    Pencil object; the only Grease Pencil object in the scene; among several, the only one
    parented to ``armature``. The search skips the fit overlays Fit Drawing makes for
    curve sketches (objects carrying :data:`FIT_OF`).

    Args:
        context: Blender context (or override).
        name: Explicit object name, empty or None to search.
        armature: The armature being posed, used to break ties.

    Returns:
        An object of type ``'GREASEPENCIL'`` (or ``'CURVE'`` when named or picked).

    Raises:
        InputError: The named object has the wrong type, or no single sketch was found.
    """
    if name:
        return _named(name, SKETCH_TYPES, "sketch", "a Grease Pencil or curve object")
    settings = _settings(context)
    if settings is not None and settings.sketch is not None:
        return settings.sketch
    def drawn(obj) -> bool:
        return obj.type == "GREASEPENCIL" and not obj.get(FIT_OF)

    active = getattr(context, "active_object", None)
    if active is not None and drawn(active):
        return active
    selected = [o for o in getattr(context, "selected_objects", ()) if drawn(o)]
    if len(selected) == 1:
        return selected[0]
    found = [o for o in context.scene.objects if drawn(o)]
    if len(found) == 1:
        return found[0]
    if found and armature is not None:
        children = [o for o in found if o.parent == armature]
        if len(children) == 1:
            return children[0]
    if found:
        raise InputError(f"{len(found)} Grease Pencil objects: select the one you drew in or "
                         "pick it in the Gesture Pose panel.")
    raise InputError("No sketch: draw with Grease Pencil (Shift+A > Grease Pencil) or pick "
                     "the sketch in the Gesture Pose panel.")


def report_result(op: bpy.types.Operator, text: str) -> None:
    """Report an operator's outcome to the user (INFO level)."""
    op.report({"INFO"}, text)


def nothing_to_do(op: bpy.types.Operator, reason: str) -> set[str]:
    """Warn that the operator had nothing to do; returns ``{'CANCELLED'}`` for ``run``."""
    op.report({"WARNING"}, f"Nothing to do: {reason}")
    return {"CANCELLED"}


class GesturePoseOperatorMixin:
    """Base for Gesture Pose operators: subclasses implement :meth:`run`.

    Mix in before ``bpy.types.Operator``::

        class GESTUREPOSE_OT_example(GesturePoseOperatorMixin, bpy.types.Operator):
            bl_idname = "gesture_pose.example"
            bl_label = "Example"
            bl_options = {'REGISTER', 'UNDO'}

            def run(self, context):
                ...
                return {'FINISHED'}

    ``run`` must raise before writing anything to the scene; this mixin reports the
    error and returns ``{'CANCELLED'}``.
    """

    bl_options = {"REGISTER", "UNDO"}

    def run(self, context: bpy.types.Context) -> set[str]:
        """The operator's body; return ``{'FINISHED'}`` or ``{'CANCELLED'}``."""
        raise NotImplementedError

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Run :meth:`run`, turning a ``GesturePoseError`` into an ERROR report."""
        try:
            return self.run(context)
        except GesturePoseError as err:
            self.report({"ERROR"}, str(err))
            return {"CANCELLED"}
