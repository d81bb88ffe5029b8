"""The "Fit Drawing" and "Trace Contours" operators and the "Gesture" sub-panel.

Fit Drawing reads the armature (in its bind pose), its skinned meshes, the view and the
drawing once, runs the 2D skeletal embedding (Gesture3D Sections 4-6,
:func:`gesture_pose.core.gesture.embedding.fit_drawing`) and shows it on a layer of the
sketch called "gesture_pose fit": joints as circles, bones as lines (blue for the
character's left side, red for its right, green in the middle) and the contour pieces
matched to each bone. A curve sketch (an imported SVG) gets the same layer on a separate
Grease Pencil object "<sketch> fit". The user's own layers and objects are never touched.

Trace Contours makes test drawings: it traces the visible occluding contours of the posed,
skinned character in the view (:mod:`gesture_pose.core.gesture.trace`), optionally roughens
them like a hand drawing, and writes them to a Grease Pencil object.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import bpy
import numpy as np

from ...core.camera import Camera
from ...core.exceptions import InputError
from ...core.gesture.embedding import GestureParams, fit_drawing
from ...core.gesture.trace import Perturbation, TracedContours, perturb, trace_contours
from ...core.gesture.types import Embedding2D
from ...core.names import side_of
from ...core.skeleton import Pose
from ..operator_utils import (
    FIT_OF,
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
from ..read_armature import ArmatureData, read_armature
from ..read_mesh import read_skinned_meshes
from ..read_strokes import read_sketch, strokes_to_2d, write_strokes
from ..read_view import camera_from_context

#: Layer of the sketch that shows the fit (replaced by every fit).
FIT_LAYER = "gesture_pose fit"
#: Layers written by the extension itself, never read as drawing.
OWN_LAYER_PREFIXES = ("gesture_pose", "Gesture Fit")
#: Colours of the fit overlay: character's left, right, middle, matched contours.
COLOURS = {"L": (0.15, 0.45, 1.0, 1.0), "R": (1.0, 0.2, 0.15, 1.0),
           "C": (0.1, 0.75, 0.25, 1.0), "match": (1.0, 0.6, 0.0, 1.0)}


@dataclass(frozen=True)
class FitReport:
    """What Fit Drawing computed and wrote.

    Attributes:
        embedding: The 2D embedding.
        camera: The view it was fitted in.
        seconds: Wall time of the whole operation.
        n_strokes: Strokes read from the sketch.
    """

    embedding: Embedding2D
    camera: Camera
    seconds: float
    n_strokes: int


def bind_pose(data: ArmatureData) -> Pose:
    """The armature's pose with every deforming bone at rest (the paper's bind pose)."""
    idx = np.flatnonzero(data.skeleton.deform)
    return data.pose.with_rotations(idx, np.tile(np.eye(3), (len(idx), 1, 1)))


def fit_scene_drawing(arm_obj: bpy.types.Object, sketch_obj: bpy.types.Object,
                      camera: Camera, frame: int | None = None,
                      params: GestureParams | None = None,
                      facing: str = "auto", body_up: str = "up") -> tuple[Embedding2D, int]:
    """Read the scene once and fit the drawing (no scene change).

    Args:
        arm_obj: The character's armature.
        sketch_obj: Grease Pencil or curve object with the drawing.
        camera: The view the drawing was made in.
        frame: Scene frame of the drawing (current when None).
        params: Embedding parameters (the paper's defaults when None).
        facing: The side of the character the drawing shows, ``"auto"`` (the side its bind
            pose shows in this view), ``"front"``, ``"back"`` or ``"turned"``
            (``fit_drawing``'s).
        body_up: Which way the character's up points in the drawing: ``"up"``,
            ``"left"``, ``"down"`` or ``"right"`` (``fit_drawing``'s).

    Returns:
        ``(embedding, number of strokes)``.

    Raises:
        InputError: No strokes, no mesh, a drawing far smaller than the character.
    """
    frame = bpy.context.scene.frame_current if frame is None else int(frame)
    if sketch_obj.get(FIT_OF):
        raise InputError(f"'{sketch_obj.name}' is the fit shown for "
                         f"'{sketch_obj[FIT_OF]}': pick that drawing as the sketch.")
    data = read_armature(arm_obj)
    strokes = [s for s in read_sketch(sketch_obj, frame)
               if not s.layer_name.startswith(OWN_LAYER_PREFIXES)]
    if not strokes:
        raise InputError(f"'{sketch_obj.name}' has no strokes at frame {frame}: draw the "
                         "character's contours over it (or use Trace Contours).")
    bind = bind_pose(data)
    meshes = read_skinned_meshes(arm_obj, data.skeleton, state=data.skeleton.forward(bind))
    embedding = fit_drawing(strokes_to_2d(strokes, camera), data.skeleton, bind,
                            meshes.rest_vertices, camera, meshes.weights, params=params,
                            override=data.gesture_override, facing=facing,
                            object_up=data.matrix_world[:3, 2], body_up=body_up)
    return embedding, len(strokes)


def _circle(centre: np.ndarray, radius: float, n: int = 24) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    return centre + radius * np.stack([np.cos(t), np.sin(t)], axis=1)


def _side(name: str) -> str:
    """"L", "R" or "C" (middle) from a joint's display name."""
    return side_of(name.rpartition(" ")[0]) or "C"


def fit_overlay(embedding: Embedding2D) -> dict[str, list[np.ndarray]]:
    """The fit as 2D polylines (pixels) grouped by colour key, see :data:`COLOURS`."""
    s = embedding.solving
    out: dict[str, list[np.ndarray]] = {k: [] for k in COLOURS}
    heads, tails = embedding.bone_points()
    for k in range(s.n_bones):
        out[_side(s.joint_bones[s.tail_joint[k]])].append(np.stack([heads[k], tails[k]]))
        out["match"].extend(seg for seg in embedding.bone_segments[k] if len(seg) >= 2)
    for j in range(s.n_joints):
        out[_side(s.joint_bones[j])].append(_circle(embedding.joints2d[j],
                                                    max(embedding.joint_radius[j], 2.0)))
    return out


def _material(name: str, colour) -> bpy.types.Material:
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    if not mat.is_grease_pencil:
        bpy.data.materials.create_gpencil_data(mat)
    mat.grease_pencil.color = tuple(colour)
    return mat


def fit_target(sketch_obj: bpy.types.Object) -> bpy.types.Object:
    """The Grease Pencil object that shows the fit of ``sketch_obj``.

    A Grease Pencil sketch shows its fit on its own "gesture_pose fit" layer. A curve
    sketch (an imported SVG) cannot hold Grease Pencil strokes, so its fit goes to a
    separate Grease Pencil object, "<sketch> fit", created next to it on the first fit,
    marked with the custom property ``gesture_pose_fit_of`` and reused afterwards; the
    curve itself is never changed.

    Args:
        sketch_obj: The drawing (Grease Pencil or curve object).

    Returns:
        The Grease Pencil object to write the fit layer into.
    """
    if sketch_obj.type == "GREASEPENCIL":
        return sketch_obj
    for obj in bpy.data.objects:
        if obj.type == "GREASEPENCIL" and obj.get(FIT_OF) == sketch_obj.name:
            return obj
    name = f"{sketch_obj.name} fit"
    obj = bpy.data.objects.new(name, bpy.data.grease_pencils.new(name))
    obj[FIT_OF] = sketch_obj.name
    collections = sketch_obj.users_collection or (bpy.context.scene.collection,)
    collections[0].objects.link(obj)
    return obj


def draw_fit(sketch_obj: bpy.types.Object, embedding: Embedding2D, camera: Camera,
             depth: float, frame: int | None = None) -> int:
    """Replace the fit layer of the sketch (see :func:`fit_target`) with the embedding.

    The overlay is drawn at view depth ``depth``.

    Returns:
        Number of strokes written.
    """
    target = fit_target(sketch_obj)
    first, count = True, 0
    for key, lines in fit_overlay(embedding).items():
        if not lines:
            continue
        world = [camera.unproject_at_depth(p, depth) for p in lines]
        write_strokes(target, FIT_LAYER, world, frame=frame, replace=first,
                      material=_material(f"gesture_pose fit {key}", COLOURS[key]),
                      color=COLOURS[key])
        first, count = False, count + len(lines)
    return count


def trace_character(arm_obj: bpy.types.Object, camera: Camera,
                    perturbation: Perturbation | None = None) -> TracedContours:
    """Visible occluding contours of the posed, skinned character in the view."""
    data = read_armature(arm_obj)
    meshes = read_skinned_meshes(arm_obj, data.skeleton)
    traced = trace_contours(meshes.deformed_vertices, meshes.triangles, camera)
    return traced if perturbation is None else perturb(traced, perturbation)


def write_traced(name: str, traced: TracedContours, camera: Camera,
                 frame: int | None = None) -> bpy.types.Object:
    """Write traced contours to the Grease Pencil object ``name`` (created when missing)."""
    obj = bpy.data.objects.get(name)
    if obj is not None and obj.type != "GREASEPENCIL":
        raise InputError(f"'{name}' exists and is not Grease Pencil: choose another name.")
    if obj is None:
        obj = bpy.data.objects.new(name, bpy.data.grease_pencils.new(name))
        bpy.context.scene.collection.objects.link(obj)
    write_strokes(obj, "Lines", list(traced.world(camera)), frame=frame, replace=True,
                  material=_material("gesture_pose traced ink", (0.0, 0.0, 0.0, 1.0)),
                  radius=0.006)
    return obj


class GESTUREPOSE_OT_fit_drawing(GesturePoseOperatorMixin, DrawingSettingsProperties,
                                 bpy.types.Operator):
    """Find where every joint of the character lies in the gesture drawing."""

    bl_idname = "gesture_pose.fit_drawing"
    bl_label = "Fit Drawing"
    bl_description = ("Place the character's skeleton in the gesture drawing (2D) and show "
                      "it on the sketch's 'gesture_pose fit' layer")
    bl_options = {"REGISTER", "UNDO"}

    armature: bpy.props.StringProperty(name="Armature", description="Character armature "
                                       "(empty: the one picked in the panel or selected)")
    sketch: bpy.props.StringProperty(name="Sketch", description="Grease Pencil or curve "
                                     "object holding the drawing (empty: automatic)")
    show_fit: bpy.props.BoolProperty(name="Show Fit", default=True,
                                     description="Draw the fit on the sketch's "
                                     "'gesture_pose fit' layer (for a curve sketch, on a "
                                     "Grease Pencil object '<sketch> fit' next to it)")

    def run(self, context: bpy.types.Context) -> set[str]:
        """Read, fit, draw the overlay and report coverage and time."""
        t0 = time.perf_counter()
        arm = resolve_armature(context, self.armature)
        sketch = resolve_sketch(context, self.sketch, arm)
        camera = camera_from_context(context)
        frame = context.scene.frame_current
        read = self.drawing_settings(context)
        embedding, n_strokes = fit_scene_drawing(arm, sketch, camera, frame, **read)
        if self.show_fit:
            data = read_armature(arm)
            depth = float(np.mean(camera.depth(data.skeleton.forward(data.pose).heads)))
            draw_fit(sketch, embedding, camera, depth, frame)
        for warning in embedding.warnings:
            self.report({"WARNING"}, warning)
        report_result(self, f"Fitted {embedding.solving.n_joints} joints to {n_strokes} "
                            f"strokes in {time.perf_counter() - t0:.2f} s; coverage "
                            f"{100 * embedding.coverage:.0f}%"
                            + drawing_settings_note(**read))
        return {"FINISHED"}


class GESTUREPOSE_OT_trace_contours(GesturePoseOperatorMixin, bpy.types.Operator):
    """Trace the character's visible contours into a Grease Pencil test drawing."""

    bl_idname = "gesture_pose.trace_contours"
    bl_label = "Trace Contours"
    bl_description = ("Trace the visible silhouette and interior contours of the posed "
                      "character in this view into a Grease Pencil object")
    bl_options = {"REGISTER", "UNDO"}

    armature: bpy.props.StringProperty(name="Armature", description="Character armature "
                                       "(empty: the one picked in the panel or selected)")
    target: bpy.props.StringProperty(name="Target", default="Traced Contours",
                                     description="Grease Pencil object to write (created "
                                     "when missing; its 'Lines' layer is replaced)")
    perturb: bpy.props.BoolProperty(name="Perturb", default=False,
                                    description="Roughen like a hand drawing")
    noise: bpy.props.FloatProperty(name="Noise", default=0.004, min=0.0, max=0.05,
                                   description="Smooth wobble, fraction of the drawing size")
    overshoot: bpy.props.FloatProperty(name="Overshoot", default=0.01, min=0.0, max=0.1)
    gap_probability: bpy.props.FloatProperty(name="Gaps", default=0.3, min=0.0, max=1.0)
    scale_error: bpy.props.FloatProperty(name="Scale Error", default=0.04, min=0.0, max=0.3)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)

    def run(self, context: bpy.types.Context) -> set[str]:
        """Trace, perturb if asked, write, report."""
        t0 = time.perf_counter()
        arm = resolve_armature(context, self.armature)
        camera = camera_from_context(context)
        pert = (Perturbation(noise=self.noise, overshoot=self.overshoot,
                             gap_probability=self.gap_probability,
                             scale_error=self.scale_error, seed=self.seed)
                if self.perturb else None)
        traced = trace_character(arm, camera, pert)
        obj = write_traced(self.target, traced, camera, context.scene.frame_current)
        report_result(self, f"Traced {len(traced.pixels)} contour strokes into "
                            f"'{obj.name}' in {time.perf_counter() - t0:.2f} s")
        return {"FINISHED"}


class VIEW3D_PT_gesture_pose_gesture(GesturePoseSubPanel, bpy.types.Panel):
    """Gesture drawings: fit the skeleton to the drawing, make test drawings."""

    bl_idname = "VIEW3D_PT_gesture_pose_gesture"
    bl_label = "Gesture"

    def draw(self, context: bpy.types.Context) -> None:
        """Fit Drawing and Trace Contours buttons."""
        col = self.layout.column(align=True)
        # Facing and Body Up are shown under Pose.
        pass_drawing_settings(col.operator(GESTUREPOSE_OT_fit_drawing.bl_idname,
                                           icon="GREASEPENCIL"), context)
        col.operator(GESTUREPOSE_OT_trace_contours.bl_idname, icon="MOD_OUTLINE")
        op = col.operator(GESTUREPOSE_OT_trace_contours.bl_idname, text="Trace Rough Drawing")
        op.perturb = True


CLASSES = (GESTUREPOSE_OT_fit_drawing, GESTUREPOSE_OT_trace_contours,
           VIEW3D_PT_gesture_pose_gesture)
