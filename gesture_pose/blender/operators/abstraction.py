"""Operators "Pose from Abstraction" and "Draw-over" (Hahn et al. 2015), and their sub-panel.

Pose from Abstraction: the newest strokes of the sketch are the targets of the chosen
abstraction's curves. Draw-over: the last two strokes are a source drawn on the character
and its target. Both read Blender once, solve with :mod:`gesture_pose.core.abstraction`,
then write and key only the bones that changed (rotations, and scales / root location when
freed).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import bpy
import numpy as np

from ...core.abstraction import (
    ParameterSpace,
    RigPose,
    SolveOptions,
    SolveResult,
    StepLimits,
    build_blackbox_problem,
    build_drawover_problem,
    build_lbs_problem,
    lbs_mismatch,
    solve_abstraction,
)
from ...core.abstraction.curves import CurveLayout
from ...core.abstraction.rig import lbs_weighted_rest, pose_bones, skin
from ...core.exceptions import InputError
from ...core.rotations import log_map
from ..abstraction_io import (
    BlenderRigEvaluator,
    abstraction_collections,
    read_abstraction,
    read_rig_pose,
    resolve_abstraction,
)
from ..operator_utils import (
    GesturePoseOperatorMixin,
    report_result,
    resolve_armature,
    resolve_sketch,
)
from ..read_armature import ArmatureData, read_armature
from ..read_mesh import MeshData, meshes_of, read_skinned_meshes
from ..read_strokes import read_sketch, remove_strokes, strokes_to_2d, write_strokes
from ..read_view import camera_from_context
from ..write_pose import apply_pose

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
#: Mesh vertices farther than this fraction of the character size from LBS mean a rig that
#: is not plain linear blend skinning.
LBS_TOLERANCE = 1e-3
#: Bones whose rotation-matrix entries (or scale) change less than this (about 0.06 degrees)
#: are not written or keyed.
WRITE_TOLERANCE = 1e-3
#: Bone collection restricting which bones may scale when scales are freed.
SCALE_COLLECTION = "Free Scale"


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


@dataclass(frozen=True)
class RigJob:
    """What both operators read from Blender, once.

    Attributes:
        armature: Armature data.
        start: Current pose with scales.
        mesh: Skinned meshes.
        space: Free parameters.
        limits: Bounds of the updates.
        warnings: Notes gathered while reading.
    """

    armature: ArmatureData
    start: RigPose
    mesh: MeshData
    space: ParameterSpace
    limits: StepLimits
    warnings: tuple[str, ...]


def free_space(arm: ArmatureData, rotations: bool, scales: bool, translation: bool,
               scale_bones: np.ndarray | None = None) -> ParameterSpace:
    """Free parameters: bones that are not pinned and move the mesh (or have such children).

    Args:
        arm: The armature.
        rotations: Free the rotations.
        scales: Free the uniform scales (of ``scale_bones`` only, when given).
        translation: Free the root bones' locations.
        scale_bones: Bones allowed to scale, ``(n,)`` bool (the "Free Scale" bone
            collection), or None for all.
    """
    skel = arm.skeleton
    moves = skel.deform.copy()
    for j in range(skel.n_bones - 1, -1, -1):
        p = skel.parents[j]
        if p >= 0 and moves[j]:
            moves[p] = True
    ok = moves & ~arm.pinned
    scalable = ok & scales if scale_bones is None else ok & scales & scale_bones
    return ParameterSpace.from_masks(skel.parents, ok & rotations, scalable,
                                     ok & (skel.parents < 0) & translation)


def scale_collection(arm_obj, names: tuple[str, ...]) -> np.ndarray | None:
    """Bones of the "Free Scale" bone collection, ``(n,)`` bool, or None without it."""
    colls = [c for c in arm_obj.data.collections_all if c.name == SCALE_COLLECTION]
    if not colls:
        return None
    members = {b.name for c in colls for b in c.bones}
    return np.array([n in members for n in names], dtype=bool)


def step_limits(arm: ArmatureData, start: RigPose, use_ik: bool, min_scale: float,
                size: float) -> StepLimits:
    """IK limits (and locked axes, pinned at their current angle) as update bounds."""
    lim = arm.ik_limits.copy() if use_ik else np.full_like(arm.ik_limits, np.nan)
    theta = log_map(start.rotations)
    locked = arm.lock_rotation
    lim[locked, 0] = theta[locked]
    lim[locked, 1] = theta[locked]
    return StepLimits(min_scale=min_scale, ik_limits=lim,
                      max_translation_step=max(0.25 * size, 1e-3))


def abstraction_object_names(context, extra=()) -> set[str]:
    """Names of every object in the "Sketch Abstraction" collections, plus ``extra``."""
    names = {o.name for c in abstraction_collections(context.scene) for o in c.all_objects}
    return names | {o.name for o in extra}


def without_objects(mesh: MeshData, excluded: set[str]) -> MeshData:
    """The mesh data without the vertices and triangles of the ``excluded`` objects.

    Raises:
        InputError: Nothing is left (only abstraction objects deform with the armature).
    """
    keep_obj = [i for i, n in enumerate(mesh.object_names) if n not in excluded]
    if len(keep_obj) == len(mesh.object_names):
        return mesh
    if not keep_obj:
        raise InputError("Only abstraction objects deform with the armature: the character "
                         "needs a skinned mesh outside the 'Sketch Abstraction' collection.")
    off = mesh.vertex_offsets
    keep = np.concatenate([np.arange(off[i], off[i + 1]) for i in keep_obj])
    remap = np.full(int(off[-1]), -1)
    remap[keep] = np.arange(len(keep))
    tris = remap[mesh.triangles]
    sizes = [int(off[i + 1] - off[i]) for i in keep_obj]
    return MeshData(tuple(mesh.object_names[i] for i in keep_obj),
                    np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
                    mesh.rest_vertices[keep], mesh.deformed_vertices[keep],
                    tris[np.all(tris >= 0, axis=1)], mesh.weights[keep], mesh.warnings)


def read_rig_job(op, context, arm_obj, abstraction_objects=()) -> RigJob:
    """Read the armature, its meshes (not the abstractions) and the choices of ``op``."""
    arm = read_armature(arm_obj)
    start, warnings = read_rig_pose(arm_obj, arm)
    mesh = without_objects(
        read_skinned_meshes(arm_obj, arm.skeleton, context.evaluated_depsgraph_get()),
        abstraction_object_names(context, abstraction_objects))
    size = float(np.linalg.norm(np.ptp(mesh.deformed_vertices, axis=0)))
    space = free_space(arm, op.free_rotations, op.free_scales, op.free_translation,
                       scale_collection(arm_obj, arm.names))
    limits = step_limits(arm, start, op.use_ik_limits, op.min_scale, size)
    if not op.black_box:
        off = lbs_mismatch(arm.skeleton, start, mesh.rest_vertices,
                           mesh.weights.astype(float), mesh.deformed_vertices)
        if off > LBS_TOLERANCE * max(size, 1e-9):
            warnings.append(f"The mesh deforms {off:.3g} units away from linear blend "
                            "skinning (constraints, drivers or shape keys?): enable "
                            "Black-Box Rig for an exact result.")
    return RigJob(arm, start, mesh, space, limits, tuple(warnings) + mesh.warnings)


def _options(op, limits: StepLimits, assignment: str = "PROXIMITY") -> SolveOptions:
    return SolveOptions(correspondence=op.correspondence, assignment=assignment,
                        max_iterations=op.max_iterations, limits=limits)


def write_result(op, arm_obj, job: RigJob, result: SolveResult, frame: int) -> list[str]:
    """Write and key the changed rotations, scales and root locations."""
    space = job.space
    written = apply_pose(arm_obj, job.armature, result.pose.to_pose(),
                         bones=list(space.rotation_bones), insert_keys=op.insert_keys,
                         frame=frame, location_bones=list(space.translation_bones),
                         tol=WRITE_TOLERANCE)
    for b in space.scale_bones:
        if abs(result.pose.scales[b] - job.start.scales[b]) > WRITE_TOLERANCE:
            pb = arm_obj.pose.bones[job.armature.names[b]]
            pb.scale = (float(result.pose.scales[b]),) * 3
            if op.insert_keys:
                pb.keyframe_insert("scale", frame=frame, group=pb.name)
            if pb.name not in written:
                written.append(pb.name)
    return written


def _report(op, result: SolveResult, written: list[str], seconds: float, path: str,
            warnings: tuple[str, ...]) -> None:
    for w in tuple(warnings) + result.warnings:
        op.report({"WARNING"}, w)
    report_result(op, f"Posed {len(written)} bones in {result.iterations} iterations "
                      f"({path}, {seconds * 1e3:.0f} ms): residual "
                      f"{result.initial_residual_px:.1f} -> {result.residual_px:.2f} px")


def _mesh_objects(arm_obj, job: RigJob) -> list:
    """The mesh objects of ``job.mesh``, in its order (for the black-box evaluator)."""
    by_name = {o.name: o for o in meshes_of(arm_obj)}
    return [by_name[n] for n in job.mesh.object_names]


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
        options = _options(self, job.limits, self.assignment)
        if self.black_box:
            evaluator = BlenderRigEvaluator(context, arm_obj, job.armature, job.space,
                                            objects, data.picks, _mesh_objects(arm_obj, job))
            try:
                problem = build_blackbox_problem(
                    job.armature.names, job.start, job.space, camera, strokes, evaluator,
                    data.layout, job.mesh.deformed_vertices, job.mesh.weights,
                    k=self.representatives)
                result = solve_abstraction(problem, options)
            finally:
                evaluator.restore()
            path = f"black box, {evaluator.evaluations} rig evaluations"
        else:
            problem = build_lbs_problem(
                job.armature.skeleton, job.start, job.space, camera, strokes, data.points,
                data.weights, data.layout, job.mesh.rest_vertices,
                job.mesh.deformed_vertices, job.mesh.weights.astype(float),
                k=self.representatives)
            result = solve_abstraction(problem, options)
            path = "LBS"
        written = write_result(self, arm_obj, job, result, frame)
        if self.remove_used_strokes and sketch.type == "GREASEPENCIL":
            for layer in {s.layer_name for s in used}:
                remove_strokes(sketch, layer, [s.index for s in used if s.layer_name == layer],
                               frame)
        _report(self, result, written, time.perf_counter() - t0, path,
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
        job = read_rig_job(self, context, arm_obj)
        mesh = job.mesh
        weights = mesh.weights.astype(float)
        problem, curve = build_drawover_problem(
            job.armature.skeleton, job.start, job.space, camera, source, target,
            mesh.rest_vertices, mesh.deformed_vertices, mesh.triangles, weights,
            k=self.representatives)
        options = _options(self, job.limits)
        path = "LBS"
        if self.black_box:
            evaluator = BlenderRigEvaluator(context, arm_obj, job.armature, job.space, [],
                                            (), _mesh_objects(arm_obj, job))

            def raw(pose: RigPose):
                verts = evaluator(pose)[1]
                return curve.points(verts), verts

            try:
                problem = build_blackbox_problem(
                    job.armature.names, job.start, job.space, camera, (target,), raw,
                    CurveLayout(("draw-over",), np.array([0, curve.kept.size])),
                    mesh.deformed_vertices, weights, k=self.representatives,
                    budget=curve.kept.size)
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
            carried = skin(pose_bones(job.armature.skeleton, result.pose), curve.rigged_rest(y))
            layer_name = dst_stroke.layer_name
            remove_strokes(sketch, layer_name, [src_stroke.index, dst_stroke.index]
                           if src_stroke.layer_name == layer_name else [dst_stroke.index],
                           frame)
            if src_stroke.layer_name != layer_name:
                remove_strokes(sketch, src_stroke.layer_name, [src_stroke.index], frame)
            write_strokes(sketch, layer_name, [carried], frame=frame, replace=False,
                          radius=float(np.mean(src_stroke.radius)))
        _report(self, result, written, time.perf_counter() - t0, path, job.warnings)
        return {"FINISHED"}


def _is_abstraction(_self, coll: bpy.types.Collection) -> bool:
    return any(o.type in {"MESH", "CURVE", "GREASEPENCIL"} for o in coll.all_objects)


class VIEW3D_PT_gesture_pose_abstraction(bpy.types.Panel):
    """Sketch abstractions and draw-over posing."""

    bl_idname = "VIEW3D_PT_gesture_pose_abstraction"
    bl_label = "Sketch Abstraction"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Gesture Pose"
    bl_parent_id = "VIEW3D_PT_gesture_pose"

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


CLASSES = (GESTUREPOSE_OT_pose_abstraction, GESTUREPOSE_OT_drawover,
           VIEW3D_PT_gesture_pose_abstraction)


def register_extra() -> None:
    """Add ``scene.gesture_pose_abstraction`` (the chosen abstraction collection)."""
    bpy.types.Scene.gesture_pose_abstraction = bpy.props.PointerProperty(
        name="Abstraction", type=bpy.types.Collection, poll=_is_abstraction,
        description="Collection of curves, Grease Pencil strokes or mesh edges that deform "
        "with the armature (empty: the first child of 'Sketch Abstraction')")


def unregister_extra() -> None:
    """Remove ``scene.gesture_pose_abstraction``."""
    del bpy.types.Scene.gesture_pose_abstraction
