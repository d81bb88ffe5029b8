"""The "Pose Stroke" operator: line-of-action posing from Grease Pencil strokes.

Reads the armature, the view and the sketch's strokes once, solves with
:func:`gesture_pose.core.line_of_action.pose_from_stroke` (one chain per stroke), then
writes and keys only the bones that changed, at the current frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import bpy
import numpy as np

from ...core.exceptions import InputError
from ...core.line_of_action import StrokeOptions, StrokePoseResult, pose_from_stroke
from ...core.skeleton import Pose
from ..operator_utils import (
    GesturePoseOperatorMixin,
    report_result,
    resolve_armature,
    resolve_sketch,
)
from ..panel import GesturePoseSubPanel
from ..read_armature import ArmatureData, read_armature
from ..read_strokes import SketchStroke, read_sketch, remove_strokes, strokes_to_2d
from ..read_view import camera_from_context
from ..write_pose import apply_pose

MODE_ITEMS = [
    ("DEFAULT", "Keep Depth", "Joints keep their distance from the view; bones stay rigid"),
    ("PLANE", "View Plane", "Posed bones end orthogonal to the view direction"),
]
TRACKING_ITEMS = [
    ("POSITION", "Position", "Joints land on the drawn stroke"),
    ("SHAPE", "Shape", "The chain takes the stroke's shape, scaled to the chain's length"),
]


@dataclass(frozen=True)
class StrokeJob:
    """Everything Pose Stroke reads from Blender, read once.

    Attributes:
        armature: Armature data and current pose.
        strokes: The chosen strokes in drawing order.
        options: Core options.
    """

    armature: ArmatureData
    strokes: tuple[SketchStroke, ...]
    options: StrokeOptions


def _active_layer_name(sketch: bpy.types.Object) -> str | None:
    if sketch.type != "GREASEPENCIL":
        return None
    layer = sketch.data.layers.active
    return None if layer is None else layer.name


def choose_strokes(strokes: list[SketchStroke], active_layer: str | None, index: int,
                   all_strokes: bool) -> tuple[SketchStroke, ...]:
    """Strokes to pose: all (drawing order), one by index, or the newest.

    The newest stroke is the last one of the active layer (where Blender appends a new
    stroke), else the last one read.

    Raises:
        InputError: No strokes, or the index is out of range.
    """
    if not strokes:
        raise InputError("The sketch has no strokes at this frame: draw a stroke from a joint "
                         "of the character along the part to pose.")
    if all_strokes:
        return tuple(strokes)
    if index >= 0:
        if index >= len(strokes):
            count = f"{len(strokes)} stroke" + ("s" if len(strokes) != 1 else "")
            raise InputError(f"Stroke index {index} is out of range: the sketch has {count} "
                             "at this frame.")
        return (strokes[index],)
    on_layer = [s for s in strokes if s.layer_name == active_layer]
    return ((on_layer or strokes)[-1],)


def solve_strokes(job: StrokeJob, camera) -> tuple[Pose, list[StrokePoseResult]]:
    """Pose one chain per stroke, each from the previous stroke's result.

    Raises:
        GesturePoseError: Any stroke that cannot be posed (nothing is kept).
    """
    skeleton = job.armature.skeleton
    pose, results = job.armature.pose, []
    for stroke in strokes_to_2d(list(job.strokes), camera):
        res = pose_from_stroke(skeleton, pose, camera, stroke, job.options,
                               pinned=job.armature.pinned)
        pose = res.pose
        results.append(res)
    return pose, results


class GESTUREPOSE_OT_pose_stroke(GesturePoseOperatorMixin, bpy.types.Operator):
    """Pose the chain below the joint a stroke starts from, along the stroke."""

    bl_idname = "gesture_pose.pose_stroke"
    bl_label = "Pose Stroke"
    bl_description = ("Pose the chain of bones below the joint where the stroke starts so it "
                      "follows the stroke; bones keep their lengths and depth")
    bl_options = {"REGISTER", "UNDO"}

    armature: bpy.props.StringProperty(name="Armature", description="Armature to pose "
                                       "(empty: the one picked in the panel or selected)")
    sketch: bpy.props.StringProperty(name="Sketch", description="Grease Pencil or curve "
                                     "object holding the strokes (empty: automatic)")
    stroke_index: bpy.props.IntProperty(name="Stroke", default=-1, min=-1,
                                        description="Stroke to use (-1: the newest)")
    all_strokes: bpy.props.BoolProperty(name="All Strokes", default=False,
                                        description="Pose one chain per stroke, in drawing "
                                        "order")
    mode: bpy.props.EnumProperty(name="Depth", items=MODE_ITEMS, default="DEFAULT")
    tracking: bpy.props.EnumProperty(name="Tracking", items=TRACKING_ITEMS, default="POSITION")
    start_bone: bpy.props.StringProperty(name="Start Bone", description="Bone whose head "
                                         "starts the chain (empty: nearest joint)")
    direction_bone: bpy.props.StringProperty(name="Direction Bone", description="A bone the "
                                             "chain must pass through")
    end_bone: bpy.props.StringProperty(name="End Bone", description="Last bone of the chain; "
                                       "may be in another branch (poses over the common "
                                       "ancestor)")
    feature_extraction: bpy.props.BoolProperty(name="Feature Extraction", default=True,
                                               description="Snap joints to drawn corners "
                                               "(off: uniform arc-length baseline)")
    pick_radius: bpy.props.FloatProperty(name="Pick Radius", default=40.0, min=1.0,
                                         subtype="PIXEL", description="How far from a joint "
                                         "a stroke may start")
    insert_keys: bpy.props.BoolProperty(name="Insert Keys", default=True)
    remove_used_strokes: bpy.props.BoolProperty(name="Remove Used Strokes", default=False)

    def _options(self, data) -> StrokeOptions:
        # On a Rigify rig an animator names a limb by its controls: read as its bones.
        named = data.rigify.reading_of if data.rigify is not None else str
        return StrokeOptions(
            mode=self.mode, tracking=self.tracking,
            start_bone=named(self.start_bone) if self.start_bone else None,
            direction_bone=named(self.direction_bone) if self.direction_bone else None,
            end_bone=named(self.end_bone) if self.end_bone else None,
            pick_radius=self.pick_radius, feature_extraction=self.feature_extraction)

    def run(self, context: bpy.types.Context) -> set[str]:
        """Read, solve, then write and key (see module docstring)."""
        t0 = time.perf_counter()
        arm = resolve_armature(context, self.armature)
        sketch = resolve_sketch(context, self.sketch, arm)
        frame = context.scene.frame_current
        data = read_armature(arm)
        job = StrokeJob(
            data,
            choose_strokes(read_sketch(sketch, frame), _active_layer_name(sketch),
                           self.stroke_index, self.all_strokes),
            self._options(data))
        camera = camera_from_context(context)
        pose, results = solve_strokes(job, camera)
        changed = sorted({int(i) for r in results for i in r.changed})
        written = apply_pose(arm, job.armature, pose, bones=changed,
                             insert_keys=self.insert_keys, frame=frame)
        if self.remove_used_strokes and sketch.type == "GREASEPENCIL":
            for layer in {s.layer_name for s in job.strokes}:
                idx = [s.index for s in job.strokes if s.layer_name == layer]
                remove_strokes(sketch, layer, idx, frame)
        for warning in (*job.armature.warnings, *(w for r in results for w in r.warnings)):
            self.report({"WARNING"}, warning)
        ms = (time.perf_counter() - t0) * 1e3
        mean = float(np.mean([r.mean_distance for r in results]))
        shown = ", ".join(written[:6]) + (f" and {len(written) - 6} more"
                                          if len(written) > 6 else "")
        strokes = f"{len(results)} stroke" + ("s" if len(results) != 1 else "")
        report_result(self, f"Posed {len(written)} bones ({shown}) from {strokes} in "
                            f"{ms:.1f} ms; joints {mean:.1f} px from the stroke")
        return {"FINISHED"}


class VIEW3D_PT_gesture_pose_stroke(GesturePoseSubPanel, bpy.types.Panel):
    """Line-of-action strokes: pose or refine one limb per stroke."""

    bl_idname = "VIEW3D_PT_gesture_pose_stroke"
    bl_label = "Line of Action"

    def draw(self, context: bpy.types.Context) -> None:
        """Buttons for the newest stroke and for all strokes."""
        col = self.layout.column(align=True)
        col.operator(GESTUREPOSE_OT_pose_stroke.bl_idname, icon="GREASEPENCIL")
        op = col.operator(GESTUREPOSE_OT_pose_stroke.bl_idname, text="Pose All Strokes")
        op.all_strokes = True


CLASSES = (GESTUREPOSE_OT_pose_stroke, VIEW3D_PT_gesture_pose_stroke)
