"""The "Pose" and "Flip Depth" operators: pose a character from a gesture drawing.

Pose reads the armature, its skinned meshes, the view and the drawing once, fits the 2D
skeletal embedding as Fit Drawing does (:func:`.fit_drawing.fit_scene_drawing`, Gesture3D
Sections 4-6), lifts it to 3D (:func:`gesture_pose.core.gesture.depth.solve_pose3d`,
Section 7; with ``DepthOptions.limb_labels``, also with symmetric limbs' labels exchanged,
keeping the labelling the joints' ranges support, :mod:`gesture_pose.core.gesture.depth.labels`),
then writes and keys the changed solving bones at the current frame. Every
Pose starts from the bind pose of the solving bones, so posing again after editing the
drawing does not drift; bones outside the solving skeleton keep their local rotations.

Flip Depth mirrors the depth of the selected limb about the view plane through its root
joint, for the foreshortened limbs the drawing leaves ambiguous.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import bpy
import numpy as np

from ...core.camera import Camera
from ...core.exceptions import InputError
from ...core.gesture.depth import DepthOptions, Pose3DResult, flip_depth, solve_pose3d, start
from ...core.gesture.depth.labels import LabelChoice, choose_labels
from ...core.gesture.types import Embedding2D
from ..operator_utils import (
    GesturePoseOperatorMixin,
    report_result,
    resolve_armature,
    resolve_sketch,
)
from ..panel import GesturePoseSubPanel
from ..properties import (
    DrawingSettingsProperties,
    drawing_settings_note,
    pass_drawing_settings,
)
from ..read_armature import read_armature
from ..read_view import camera_from_context
from ..write_pose import apply_pose
from .fit_drawing import FIT_LAYER, draw_fit, fit_scene_drawing


@dataclass(frozen=True)
class PoseDrawingReport:
    """What one Pose did.

    Attributes:
        embedding: The 2D skeletal embedding of the drawing.
        result: The 3D solve.
        written: Names of the bones written (and keyed).
        seconds: Wall time of the whole Pose, seconds.
        timings: Seconds per stage (``"fit"`` with reading the scene, ``"solve3d"``,
            ``"write"``).
        warnings: Notes from reading the armature (e.g. rotation locks of an imported
            rig's bones that do not fall on the axes it is solved in).
        labels: The choice between left/right labellings of the fit
            (``DepthOptions.limb_labels``), None when off; ``embedding`` has the chosen
            labels.
        facing: The Facing the drawing was read with (``"auto"``: As Seen).
    """

    embedding: Embedding2D
    result: Pose3DResult
    written: tuple[str, ...]
    seconds: float
    timings: dict
    warnings: tuple[str, ...] = ()
    labels: LabelChoice | None = None
    facing: str = "auto"


def pose_from_drawing(arm_obj: bpy.types.Object, sketch_obj: bpy.types.Object,
                      camera: Camera, *, frame: int | None = None, insert_keys: bool = True,
                      show_fit: bool = True, options: DepthOptions | None = None,
                      facing: str = "auto", body_up: str = "up",
                      progress: Callable[[float], None] | None = None) -> PoseDrawingReport:
    """Pose an armature from a gesture drawing and key it (the whole "Pose" action).

    Args:
        arm_obj: The character's armature object (skinned meshes are read from it).
        sketch_obj: Grease Pencil (or curve) object holding the drawing's contours.
        camera: The view the drawing was made in.
        frame: Scene frame whose drawing is read and keyed (the current frame when None).
        insert_keys: Key the changed bones in their rotation modes.
        show_fit: Keep the fit shown in the sketch's fit layer (as Fit Drawing draws it);
            off removes that layer.
        options: 3D solve parameters (the paper's defaults when None).
        facing: The side of the character the drawing shows: ``"auto"`` (the side its bind
            pose shows in this view), ``"front"``, ``"back"`` or ``"turned"``
            (``core.gesture.embedding.facing_turn``).
        body_up: Which way the character's up points in the drawing: ``"up"`` (as it
            stands), ``"left"``, ``"down"`` or ``"right"``
            (``core.gesture.embedding.rolled_in_view``).
        progress: Called with the fraction done, in ``[0, 1]``.

    Returns:
        The embedding, the 3D result and what was written.

    Raises:
        GesturePoseError: Bad input or a failed solve; nothing is written then.
    """
    tick = progress or (lambda _f: None)
    t0 = time.perf_counter()
    frame = bpy.context.scene.frame_current if frame is None else int(frame)
    data = read_armature(arm_obj)
    tick(0.05)
    embedding, _ = fit_scene_drawing(arm_obj, sketch_obj, camera, frame, facing=facing,
                                     body_up=body_up)
    timings = {"fit": time.perf_counter() - t0}
    tick(0.8)
    t1 = time.perf_counter()
    lock, limits, axes = data.axis_settings()
    # The rest joints are world positions: a rig lying at rest carries its up with its
    # object (an imported Y-up rig's object is turned to stand: start.rig_up tells them).
    up = start.rig_up(embedding.solving, data.matrix_world[:3, 2])
    options = replace(options or DepthOptions(), rest_up=tuple(float(v) for v in up))
    rig = {"lock_rotation": lock, "ik_limits": limits, "pinned": data.pinned,
           "limit_axes": axes}
    choice = None
    if options.limb_labels:
        # The 3D pose tells apart left/right labellings the 2D fit guessed (ours).
        choice = choose_labels(data.skeleton, embedding, camera, data.pose, options=options,
                               **rig)
        embedding, result = choice.embedding, choice.result
    else:
        result = solve_pose3d(data.skeleton, embedding, camera, data.pose, options=options,
                              **rig)
    timings["solve3d"] = time.perf_counter() - t1
    tick(0.95)
    t2 = time.perf_counter()
    written = apply_pose(arm_obj, data, result.pose, bones=[int(b) for b in result.bones],
                         insert_keys=insert_keys, frame=frame, pin_hint=True)
    if sketch_obj.type == "GREASEPENCIL":
        if show_fit:
            draw_fit(sketch_obj, embedding, camera,
                     float(np.mean(camera.depth(result.joints3d))), frame)
        elif sketch_obj.data.layers.get(FIT_LAYER) is not None:
            sketch_obj.data.layers.remove(sketch_obj.data.layers[FIT_LAYER])
    timings["write"] = time.perf_counter() - t2
    tick(1.0)
    return PoseDrawingReport(embedding, result, tuple(written), time.perf_counter() - t0,
                             timings, data.warnings, choice, facing)


def flip_limb_depth(arm_obj: bpy.types.Object, bone_name: str, camera: Camera, *,
                    frame: int | None = None, insert_keys: bool = True) -> list[str]:
    """Mirror the depth of the limb below ``bone_name`` and key it ("Flip Depth").

    Args:
        arm_obj: The armature object.
        bone_name: First bone of the limb; the limb is that bone and every bone below it
            (but bones locked on every axis, which keep their rotation).
        camera: The view (the mirror plane is the view plane through the bone's head).
        frame: Frame to key (the current frame when None).
        insert_keys: Key the changed bones.

    Returns:
        Names of the bones written.

    Raises:
        InputError: No such bone.
    """
    data = read_armature(arm_obj)
    if data.rigify is not None:  # a Rigify control names the limb it poses
        bone_name = data.rigify.reading_of(bone_name)
    root = data.skeleton.index(bone_name)
    # A bone locked on every axis keeps its rotation (Rigify's heels and palms follow
    # their parents); the bones below it are mirrored all the same.
    chain = np.array([b for b in data.skeleton.descendants(root)
                      if b == root or not data.lock_rotation[b].all()], dtype=int)
    state = data.skeleton.forward(data.pose)
    forward = camera.view_directions(state.heads[root][None])[0]
    new_pose = flip_depth(data.skeleton, data.pose, chain, forward)
    return apply_pose(arm_obj, data, new_pose, bones=[int(b) for b in chain],
                      insert_keys=insert_keys, frame=frame)


def summary(rep: PoseDrawingReport) -> str:
    """The one-line report of a Pose: bones, times, coverage, depth orders and labels.

    When the joints' ranges chose other left/right labels than the 2D fit's
    (``DepthOptions.limb_labels``), the line names the exchanged pair, so the user knows
    why a limb took the other side's outline. A Facing or Body Up other than the default
    is named too: both are scene settings that stay set for the next drawing.

    Args:
        rep: What the Pose did.

    Returns:
        The report's text.
    """
    orders = len(rep.result.ordering)
    text = (f"Posed {len(rep.written)} bones in {rep.seconds:.2f} s "
            f"(fit {rep.timings['fit']:.2f} s, 3D {rep.timings['solve3d']:.2f} s); "
            f"drawing coverage {100 * rep.embedding.coverage:.0f}%, {orders} depth "
            f"order{'' if orders == 1 else 's'} read from overlapping parts")
    if rep.labels is not None and rep.labels.chosen != 0:
        text += (f"; left/right labels {rep.labels.names[rep.labels.chosen]} exchanged "
                 "(the joints' ranges prefer them to the fit's)")
    return text + drawing_settings_note(rep.facing, rep.embedding.body_up)


def _progress(context) -> tuple[Callable[[float], None], Callable[[], None]]:
    """Progress callbacks on the window manager's cursor indicator (no-ops headless)."""
    wm = getattr(context, "window_manager", None)
    if wm is None or getattr(context, "window", None) is None:
        return (lambda _f: None), (lambda: None)
    wm.progress_begin(0.0, 1.0)
    return wm.progress_update, wm.progress_end


class GESTUREPOSE_OT_pose_drawing(GesturePoseOperatorMixin, DrawingSettingsProperties,
                                  bpy.types.Operator):
    """Pose the character from the gesture drawing over it and key the pose."""

    bl_idname = "gesture_pose.pose_drawing"
    bl_label = "Pose"
    bl_description = ("Fit the character's skeleton to the drawing, recover the 3D pose it "
                      "shows and key the changed bones at the current frame")
    bl_options = {"REGISTER", "UNDO"}

    armature: bpy.props.StringProperty(name="Armature", description="Armature to pose "
                                       "(empty: the one picked in the panel or selected)")
    sketch: bpy.props.StringProperty(name="Sketch", description="Grease Pencil object "
                                     "holding the drawing (empty: automatic)")
    insert_keys: bpy.props.BoolProperty(name="Insert Keys", default=True,
                                        description="Key the changed bones")
    show_fit: bpy.props.BoolProperty(name="Show Fit", default=True,
                                     description=f"Keep the fitted skeleton in the sketch's "
                                     f"'{FIT_LAYER}' layer (off: remove that layer)")

    def run(self, context: bpy.types.Context) -> set[str]:
        """Read, fit, lift, then write and key (see the module docstring)."""
        arm = resolve_armature(context, self.armature)
        sketch = resolve_sketch(context, self.sketch, arm)
        camera = camera_from_context(context)
        update, end = _progress(context)
        try:
            rep = pose_from_drawing(arm, sketch, camera, insert_keys=self.insert_keys,
                                    show_fit=self.show_fit, progress=update,
                                    **self.drawing_settings(context))
        finally:
            end()
        for warning in (*rep.warnings, *rep.embedding.warnings, *rep.result.warnings):
            self.report({"WARNING"}, warning)
        report_result(self, summary(rep))
        return {"FINISHED"}


class GESTUREPOSE_OT_flip_depth(GesturePoseOperatorMixin, bpy.types.Operator):
    """Mirror the selected limb's depth about the view plane through its root joint."""

    bl_idname = "gesture_pose.flip_depth"
    bl_label = "Flip Depth"
    bl_description = ("Mirror the depth of the active bone and the bones below it (towards "
                      "or away from the view), for limbs the drawing leaves ambiguous")
    bl_options = {"REGISTER", "UNDO"}

    armature: bpy.props.StringProperty(name="Armature", description="Armature (empty: the "
                                       "one picked in the panel or selected)")
    bone: bpy.props.StringProperty(name="Bone", description="First bone of the limb "
                                   "(empty: the active bone)")
    insert_keys: bpy.props.BoolProperty(name="Insert Keys", default=True)

    def run(self, context: bpy.types.Context) -> set[str]:
        """Flip the limb and key it."""
        arm = resolve_armature(context, self.armature)
        name = self.bone
        if not name:
            active = getattr(context, "active_pose_bone", None) or arm.data.bones.active
            if active is None:
                raise InputError("No bone to flip: select the first bone of the limb in Pose "
                                 "Mode, or give its name.")
            name = active.name
        written = flip_limb_depth(arm, name, camera_from_context(context),
                                  insert_keys=self.insert_keys)
        if not written:
            self.report({"WARNING"}, f"Nothing to do: the limb below '{name}' lies in the view "
                                     "plane, flipping its depth changes nothing.")
            return {"CANCELLED"}
        report_result(self, f"Flipped the depth of {len(written)} bones below '{name}'")
        return {"FINISHED"}


class VIEW3D_PT_gesture_pose_drawing(GesturePoseSubPanel, bpy.types.Panel):
    """Gesture drawings: the main Pose button and Flip Depth."""

    bl_idname = "VIEW3D_PT_gesture_pose_drawing"
    bl_label = "Pose from Drawing"
    bl_order = 0
    bl_options = {"HIDE_HEADER"}

    def draw(self, context: bpy.types.Context) -> None:
        """The large Pose button, the drawing's Facing, then Flip Depth."""
        col = self.layout.column()
        big = col.row()
        big.scale_y = 2.0
        settings = pass_drawing_settings(
            big.operator(GESTUREPOSE_OT_pose_drawing.bl_idname, text="Pose",
                         icon="ARMATURE_DATA"), context)
        if settings is not None:
            col.prop(settings, "facing")
            col.prop(settings, "body_up")
        col.operator(GESTUREPOSE_OT_flip_depth.bl_idname, icon="MOD_MIRROR")


CLASSES = (GESTUREPOSE_OT_pose_drawing, GESTUREPOSE_OT_flip_depth,
           VIEW3D_PT_gesture_pose_drawing)
