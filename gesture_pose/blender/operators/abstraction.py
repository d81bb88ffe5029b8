"""Operators "Pose from Abstraction" and "Draw-over" (Hahn et al. 2015).

Pose from Abstraction: the newest strokes of the sketch are the targets of the chosen
abstraction's curves. Draw-over: the last two strokes are a source drawn on the character
and its target. Both read Blender once (:mod:`.abstraction_job`), solve with
:mod:`gesture_pose.core.abstraction`, then write and key only the bones that changed
(rotations, and scales / root location when freed). Bad input (strokes far from the
character, a source off the mesh, ...) raises before anything is written: pose, keys and
strokes stay as they were. The sub-panel is in :mod:`.abstraction_ui`.
"""

from __future__ import annotations

import time

import bpy
import numpy as np

from ...core.abstraction import (
    RigPose,
    build_blackbox_problem,
    build_drawover_problem,
    build_lbs_problem,
    solve_abstraction,
)
from ...core.abstraction.curves import CurveLayout
from ...core.abstraction.rig import lbs_weighted_rest, pose_bones, skin
from ...core.exceptions import InputError
from ..abstraction_io import BlenderRigEvaluator, read_abstraction, resolve_abstraction
from ..operator_utils import GesturePoseOperatorMixin, resolve_armature, resolve_sketch
from ..read_strokes import read_sketch, remove_strokes, strokes_to_2d, write_strokes
from ..read_view import camera_from_context
from .abstraction_job import (
    mesh_objects,
    read_rig_job,
    report,
    solve_options,
    stroke_labels,
    write_result,
)

CORRESPONDENCE_ITEMS = [
    ("IN_ORDER", "In Order", "Match along the drawing direction, by arc length"),
    ("CLOSEST", "Closest Point", "Match each point to the closest point of the other curve"),
    ("IN_ORDER_CLOSEST", "In Order, then Closest",
     "In order first, then closest point from there (for curves that stretch)"),
]
ASSIGNMENT_ITEMS = [
    ("PROXIMITY", "Proximity", "Each stroke goes to the nearest abstraction curve"),
    ("ORDER", "Drawing Order", "The i-th newest stroke goes to the i-th curve"),
]
MOVED_ITEMS = [
    ("DRAWN", "Drawn Bones", "Only the bones the matched curves are drawn on (and those "
     "between them) move; the rest of the rig is kept as it is"),
    ("DRAWN_AND_LIMB", "Drawn Bones and Limb", "Also the bones above them up to where the "
     "limb branches (upper arm and shoulder for a forearm, not the chest)"),
    ("DRAWN_AND_PARENTS", "Drawn Bones and Parents", "Also every bone above them (the spine "
     "when an arm is redrawn), held back by the pose regularizer"),
]


class _SolverProps:
    """Options shared by both operators."""

    armature: bpy.props.StringProperty(name="Armature", description="Armature to pose "
                                       "(empty: the one picked in the panel or selected)")
    sketch: bpy.props.StringProperty(name="Sketch", description="Grease Pencil object "
                                     "holding the strokes (empty: automatic)")
    correspondence: bpy.props.EnumProperty(name="Correspondence", items=CORRESPONDENCE_ITEMS,
                                           default="IN_ORDER")
    free_rotations: bpy.props.BoolProperty(name="Rotations", default=True,
                                           description="Optimize bone rotations")
    free_scales: bpy.props.BoolProperty(name="Scales", default=False,
                                        description="Optimize uniform bone scales (kept at "
                                        "least Min Scale; only the bones of a 'Free Scale' "
                                        "bone collection when there is one)")
    free_translation: bpy.props.BoolProperty(name="Root Translation", default=False,
                                             description="Optimize the root bones' location")
    min_scale: bpy.props.FloatProperty(name="Min Scale", default=0.1, min=0.001, soft_max=1.0)
    use_ik_limits: bpy.props.BoolProperty(name="IK Limits", default=True, description="Keep "
                                          "rotations within the pose bones' IK limits")
    black_box: bpy.props.BoolProperty(name="Black-Box Rig", default=False, description="Let "
                                      "Blender evaluate the rig (constraints, drivers, shape "
                                      "keys) with finite differences; slower")
    max_iterations: bpy.props.IntProperty(name="Max Iterations", default=50, min=1, max=500)
    representatives: bpy.props.IntProperty(name="Representatives", default=200, min=10,
                                           description="k-means representative vertices of "
                                           "the regularizers (Eq. 12)")
    insert_keys: bpy.props.BoolProperty(name="Insert Keys", default=True)


class GESTUREPOSE_OT_pose_abstraction(_SolverProps, GesturePoseOperatorMixin,
                                      bpy.types.Operator):
    """Pose the character so its sketch abstraction matches the newest strokes."""

    bl_idname = "gesture_pose.pose_abstraction"
    bl_label = "Pose from Abstraction"
    bl_description = ("Optimize the rig so the chosen sketch abstraction, seen from this "
                      "view, matches the newest strokes (one stroke per abstraction curve)")
    bl_options = {"REGISTER", "UNDO"}

    abstraction: bpy.props.StringProperty(name="Abstraction", description="Collection or "
                                          "object of the abstraction (empty: the one picked "
                                          "in the panel)")
    assignment: bpy.props.EnumProperty(name="Stroke to Curve", items=ASSIGNMENT_ITEMS,
                                       default="PROXIMITY")
    remove_used_strokes: bpy.props.BoolProperty(name="Remove Used Strokes", default=False)
    moved_bones: bpy.props.EnumProperty(name="Move", items=MOVED_ITEMS, default="DRAWN")

    def run(self, context: bpy.types.Context) -> set[str]:
        """Read, solve, write (see the module docstring)."""
        t0 = time.perf_counter()
        arm_obj = resolve_armature(context, self.armature)
        objects = resolve_abstraction(context, self.abstraction)
        sketch = resolve_sketch(context, self.sketch, arm_obj)
        if sketch in objects:
            raise InputError(f"'{sketch.name}' is part of the abstraction: draw the new pose "
                             "in another Grease Pencil object.")
        frame = context.scene.frame_current
        job = read_rig_job(self, context, arm_obj, objects)
        depsgraph = context.evaluated_depsgraph_get()
        data = read_abstraction(objects, job.armature, arm_obj, depsgraph,
                                job.mesh.deformed_vertices, job.mesh.weights)
        drawn = read_sketch(sketch, frame)
        if not drawn:
            raise InputError("The sketch has no strokes at this frame: draw the new pose over "
                             "the character, one stroke per abstraction curve.")
        used = drawn[-min(len(drawn), data.layout.n_curves):]
        camera = camera_from_context(context)
        strokes = strokes_to_2d(used, camera)
        labels = stroke_labels(used, drawn)
        options = solve_options(self, job.limits, self.assignment)
        if self.black_box:
            evaluator = BlenderRigEvaluator(context, arm_obj, job.armature, job.space,
                                            objects, data.picks, mesh_objects(arm_obj, job))
            try:
                problem = build_blackbox_problem(
                    job.armature.names, job.start, job.space, camera, strokes, evaluator,
                    data.layout, job.mesh.deformed_vertices, job.mesh.weights,
                    k=self.representatives, skeleton=job.armature.skeleton,
                    curve_weights=data.weights, stroke_labels=labels)
                result = solve_abstraction(problem, options)
            finally:
                evaluator.restore()
            path = f"black box, {evaluator.evaluations} rig evaluations"
        else:
            problem = build_lbs_problem(
                job.armature.skeleton, job.start, job.space, camera, strokes, data.points,
                data.weights, data.layout, job.mesh.rest_vertices,
                job.mesh.deformed_vertices, job.mesh.weights.astype(float),
                k=self.representatives, stroke_labels=labels)
            result = solve_abstraction(problem, options)
            path = "LBS"
        written = write_result(self, arm_obj, job, result, frame)
        if self.remove_used_strokes and sketch.type == "GREASEPENCIL":
            for layer in {s.layer_name for s in used}:
                remove_strokes(sketch, layer, [s.index for s in used if s.layer_name == layer],
                               frame)
        report(self, result, written, time.perf_counter() - t0, path,
               job.warnings + data.warnings)
        return {"FINISHED"}


class GESTUREPOSE_OT_drawover(_SolverProps, GesturePoseOperatorMixin, bpy.types.Operator):
    """Draw on the character, then redraw the stroke where it should go."""

    bl_idname = "gesture_pose.drawover"
    bl_label = "Draw-over"
    bl_description = ("The second newest stroke, drawn on the character, becomes a "
                      "temporary abstraction; the newest stroke is where it should go")
    bl_options = {"REGISTER", "UNDO"}

    keep_source: bpy.props.BoolProperty(name="Keep Source", default=False, description=(
        "Replace the two strokes by the source carried to the new pose, ready to be "
        "redrawn again (off: your strokes are left as drawn)"))
    moved_bones: bpy.props.EnumProperty(name="Move", items=MOVED_ITEMS,
                                        default="DRAWN_AND_LIMB")

    def run(self, context: bpy.types.Context) -> set[str]:
        """Read, solve, write (see the module docstring)."""
        t0 = time.perf_counter()
        arm_obj = resolve_armature(context, self.armature)
        sketch = resolve_sketch(context, self.sketch, arm_obj)
        frame = context.scene.frame_current
        drawn = read_sketch(sketch, frame)
        layer = sketch.data.layers.active if sketch.type == "GREASEPENCIL" else None
        on_layer = [s for s in drawn if layer is not None and s.layer_name == layer.name]
        drawn = on_layer if len(on_layer) >= 2 else drawn
        if len(drawn) < 2:
            raise InputError("Draw-over needs two strokes: first draw over the part to move, "
                             "then draw where it should go.")
        src_stroke, dst_stroke = drawn[-2], drawn[-1]
        camera = camera_from_context(context)
        source, target = strokes_to_2d([src_stroke, dst_stroke], camera)
        labels = (f"the target stroke ({stroke_labels([dst_stroke], drawn)[0]})",)
        job = read_rig_job(self, context, arm_obj)
        mesh = job.mesh
        weights = mesh.weights.astype(float)
        skel = job.armature.skeleton
        problem, curve = build_drawover_problem(
            skel, job.start, job.space, camera, source, target, mesh.rest_vertices,
            mesh.deformed_vertices, mesh.triangles, weights, k=self.representatives,
            stroke_labels=labels)
        options = solve_options(self, job.limits)
        path = "LBS"
        if self.black_box:
            evaluator = BlenderRigEvaluator(context, arm_obj, job.armature, job.space, [],
                                            (), mesh_objects(arm_obj, job))

            def raw(pose: RigPose) -> tuple[np.ndarray, np.ndarray]:
                """Source points on the mesh ``(q, 3)`` and mesh vertices ``(V, 3)``."""
                verts = evaluator(pose)[1]
                return curve.points(verts), verts

            try:
                problem = build_blackbox_problem(
                    job.armature.names, job.start, job.space, camera, (target,), raw,
                    CurveLayout(("draw-over",), np.array([0, curve.kept.size])),
                    mesh.deformed_vertices, weights, k=self.representatives,
                    budget=curve.kept.size, skeleton=skel,
                    curve_weights=np.asarray(curve.blend @ weights), stroke_labels=labels)
                result = solve_abstraction(problem, options)
            finally:
                evaluator.restore()
            path = f"black box, {evaluator.evaluations} rig evaluations"
        else:
            result = solve_abstraction(problem, options)
        written = write_result(self, arm_obj, job, result, frame)
        if self.keep_source and sketch.type == "GREASEPENCIL":
            y = np.zeros(weights.shape + (4,))
            ok = weights.sum(axis=1) > 0
            y[ok] = lbs_weighted_rest(mesh.rest_vertices[ok], weights[ok])
            carried = skin(pose_bones(skel, result.pose), curve.rigged_rest(y))
            layer_name = dst_stroke.layer_name
            remove_strokes(sketch, layer_name, [src_stroke.index, dst_stroke.index]
                           if src_stroke.layer_name == layer_name else [dst_stroke.index],
                           frame)
            if src_stroke.layer_name != layer_name:
                remove_strokes(sketch, src_stroke.layer_name, [src_stroke.index], frame)
            write_strokes(sketch, layer_name, [carried], frame=frame, replace=False,
                          radius=float(np.mean(src_stroke.radius)))
        report(self, result, written, time.perf_counter() - t0, path, job.warnings)
        return {"FINISHED"}


CLASSES = (GESTUREPOSE_OT_pose_abstraction, GESTUREPOSE_OT_drawover)
