"""Reading and writing for the abstraction operators (Pose from Abstraction, Draw-over).

Blender is read once into a :class:`RigJob` (armature, current pose, skinned meshes without
the abstraction objects, free parameters, bounds); the solve result is written back by
:func:`write_result`, which keys only bones that changed (bones the drawing does not
constrain are kept exactly by the solver, see :mod:`gesture_pose.core.abstraction.inputs`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...core.abstraction import ParameterSpace, RigPose, SolveOptions, SolveResult, StepLimits
from ...core.abstraction.problem import lbs_mismatch
from ...core.exceptions import InputError
from ...core.rotations import log_map
from ..abstraction_io import abstraction_collections, read_rig_pose
from ..operator_utils import report_result
from ..read_armature import ArmatureData, read_armature
from ..read_mesh import MeshData, meshes_of, read_skinned_meshes
from ..read_strokes import SketchStroke
from ..write_pose import apply_pose

#: Mesh vertices farther than this fraction of the character size from LBS mean a rig that
#: is not plain linear blend skinning.
LBS_TOLERANCE = 1e-3
#: Bones whose rotation-matrix entries (or scale) change less than this (about 0.06 degrees)
#: are not written or keyed.
WRITE_TOLERANCE = 1e-3
#: Bone collection restricting which bones may scale when scales are freed.
SCALE_COLLECTION = "Free Scale"


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
    if arm.rigify is not None:  # its rig parameters are its controls, not its bones
        raise InputError(f"'{arm_obj.name}' is a generated Rigify rig: the abstraction "
                         "tools do not pose it yet (Pose and Pose Stroke do, through its "
                         "FK controls). Nothing was changed.")
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


def solve_options(op, limits: StepLimits, assignment: str = "PROXIMITY") -> SolveOptions:
    """The solver settings chosen in the operator ``op`` (the paper's weights)."""
    return SolveOptions(correspondence=op.correspondence, assignment=assignment,
                        max_iterations=op.max_iterations, limits=limits,
                        moved_bones=op.moved_bones)


def stroke_labels(used: Sequence[SketchStroke], drawn: Sequence[SketchStroke]
                  ) -> tuple[str, ...]:
    """Names of the ``used`` strokes for messages: position among ``drawn`` and layer."""
    position = {id(s): i for i, s in enumerate(drawn)}
    total = len(drawn)
    out = []
    for s in used:
        i = position.get(id(s), -1) + 1
        newest = " (the newest)" if i == total else ""
        out.append(f"stroke {i} of {total}{newest} in layer '{s.layer_name}'")
    return tuple(out)


def write_result(op, arm_obj, job: RigJob, result: SolveResult, frame: int) -> list[str]:
    """Write and key the changed rotations, scales and root locations."""
    space = job.space
    written = apply_pose(arm_obj, job.armature, result.pose.to_pose(),
                         bones=list(space.rotation_bones), insert_keys=op.insert_keys,
                         frame=frame, location_bones=list(space.translation_bones),
                         tol=WRITE_TOLERANCE, pin_hint=True,
                         redirect=not getattr(op, "black_box", False))
    for b in space.scale_bones:
        if abs(result.pose.scales[b] - job.start.scales[b]) > WRITE_TOLERANCE:
            pb = arm_obj.pose.bones[job.armature.names[b]]
            pb.scale = (float(result.pose.scales[b]),) * 3
            if op.insert_keys:
                pb.keyframe_insert("scale", frame=frame, group=pb.name)
            if pb.name not in written:
                written.append(pb.name)
    return written


def report(op, result: SolveResult, written: list[str], seconds: float, path: str,
           warnings: tuple[str, ...]) -> None:
    """Report the warnings, then the outcome (bones posed, iterations, path, residuals)."""
    for w in tuple(dict.fromkeys(tuple(warnings) + result.warnings)):
        op.report({"WARNING"}, w)
    kept = f", kept {len(result.frozen)} undrawn bones" if result.frozen else ""
    report_result(op, f"Posed {len(written)} bones in {result.iterations} iterations "
                      f"({path}, {seconds * 1e3:.0f} ms{kept}): residual "
                      f"{result.initial_residual_px:.1f} -> {result.residual_px:.2f} px")


def mesh_objects(arm_obj, job: RigJob) -> list:
    """The mesh objects of ``job.mesh``, in its order (for the black-box evaluator)."""
    by_name = {o.name: o for o in meshes_of(arm_obj)}
    return [by_name[n] for n in job.mesh.object_names]
