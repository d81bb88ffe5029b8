"""Read sketch abstractions from Blender, and evaluate the Blender rig as a black box.

An abstraction is a set of objects that deform with the armature: curve objects, Grease
Pencil strokes or mesh edges (an Armature modifier with vertex groups, or bone parenting).
They live in a collection named "Sketch Abstraction": its child collections are separate
abstractions of one character (e.g. "Stick Figure", "Outline") and one is chosen at a time
(``scene.gesture_pose_abstraction`` or an operator's ``abstraction`` name); objects directly
in it form one abstraction.

Curves are read as evaluated world polylines (mesh edges and curve outlines chained, Grease
Pencil strokes as drawn). Bone weights come from vertex groups named after bones, else from
the bone the object (or Grease Pencil layer) is parented to, else from the nearest skinned
mesh vertex (with a warning).
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np
from scipy.spatial import cKDTree

from ..core.abstraction.curves import CurveLayout
from ..core.abstraction.parameters import ParameterSpace, RigPose
from ..core.exceptions import InputError
from ..core.joint_skeleton import from_joint_pose
from ..core.skeleton import Pose, Skeleton
from .read_armature import ArmatureData
from .read_strokes import chain_edges, drawing_arrays
from .write_pose import set_rotation

#: Collection holding a character's abstractions.
ABSTRACTION_COLLECTION = "Sketch Abstraction"
_KINDS = frozenset({"MESH", "CURVE", "GREASEPENCIL"})


def abstraction_collections(scene: bpy.types.Scene) -> list[bpy.types.Collection]:
    """The abstractions of the scene: the children of "Sketch Abstraction" (or itself)."""
    root = bpy.data.collections.get(ABSTRACTION_COLLECTION)
    if root is None:
        return []
    children = list(root.children)
    return children if children else [root]


def resolve_abstraction(context, name: str = "") -> list[bpy.types.Object]:
    """Objects of the chosen abstraction, sorted by name.

    In order: the collection or object called ``name``; the abstraction picked in the panel;
    the first abstraction of the "Sketch Abstraction" collection.

    Raises:
        InputError: Nothing found, or no curve-like object in it.
    """
    objs: list = []
    if name:
        coll = bpy.data.collections.get(name)
        if coll is not None:
            objs = list(coll.all_objects)
        elif bpy.data.objects.get(name) is not None:
            objs = [bpy.data.objects[name]]
        else:
            raise InputError(f"No collection or object named '{name}': check the abstraction "
                             "name.")
    else:
        picked = getattr(context.scene, "gesture_pose_abstraction", None)
        colls = [picked] if picked is not None else abstraction_collections(context.scene)
        if not colls:
            raise InputError(f"No abstraction: put curves, Grease Pencil strokes or mesh edges "
                             f"that deform with the armature in a collection named "
                             f"'{ABSTRACTION_COLLECTION}', or pick one in the panel.")
        objs = list(colls[0].all_objects)
    objs = sorted((o for o in objs if o.type in _KINDS), key=lambda o: o.name)
    if not objs:
        raise InputError("The abstraction has no curve, Grease Pencil or mesh object.")
    return objs


def _world(points: np.ndarray, matrix) -> np.ndarray:
    """Points ``(v, 3)`` in an object's space to world space with its 4x4 ``matrix``."""
    m = np.array(matrix, dtype=float)
    return points @ m[:3, :3].T + m[:3, 3]


def mesh_arrays(obj, depsgraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Evaluated world vertices, edges and per-edge face counts of a mesh or curve object."""
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        co = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        edges = np.empty(len(mesh.edges) * 2, dtype=np.int64)
        mesh.edges.foreach_get("vertices", edges)
        loops = np.empty(len(mesh.loops), dtype=np.int64)
        mesh.loops.foreach_get("edge_index", loops)
        faces = np.bincount(loops, minlength=len(mesh.edges))
    finally:
        evaluated.to_mesh_clear()
    return _world(co.reshape(-1, 3), evaluated.matrix_world), edges.reshape(-1, 2), faces


def _gp_arrays(obj, depsgraph) -> tuple[np.ndarray, list[tuple[int, int]], list[str]]:
    """Evaluated world points, stroke spans and layer names of a Grease Pencil object."""
    evaluated = obj.evaluated_get(depsgraph)
    pts, spans, layers, start = [], [], [], 0
    for layer in evaluated.data.layers:
        key = layer.current_frame()
        if layer.hide or key is None or len(key.drawing.strokes) == 0:
            continue
        pos, off, _ = drawing_arrays(key.drawing)
        m = np.array(evaluated.matrix_world) @ np.array(layer.matrix_local)
        pts.append(_world(pos, m))
        spans += [(start + int(a), start + int(b)) for a, b in zip(off[:-1], off[1:],
                                                                     strict=True)]
        layers += [layer.name] * (len(off) - 1)
        start += len(pos)
    return (np.concatenate(pts) if pts else np.zeros((0, 3))), spans, layers


def _object_points(obj, depsgraph) -> np.ndarray:
    """All evaluated world points of an abstraction object, ``(v, 3)``."""
    if obj.type == "GREASEPENCIL":
        return _gp_arrays(obj, depsgraph)[0]
    return mesh_arrays(obj, depsgraph)[0]


def _vertex_group_weights(obj, skeleton: Skeleton) -> np.ndarray | None:
    """Bone weights of a mesh object's vertices, ``(v, n)``, or None without bone groups."""
    bone = {name: i for i, name in enumerate(skeleton.names)}
    column = np.full(max(len(obj.vertex_groups), 1), -1, dtype=np.int64)
    for vg in obj.vertex_groups:
        column[vg.index] = bone.get(vg.name, -1)
    if not np.any(column >= 0):
        return None
    # Blender has no foreach_get for vertex-group memberships: gather the (vertex, group,
    # weight) triples in one pass, then scatter them into the matrix with numpy.
    triples = [(v.index, g.group, g.weight) for v in obj.data.vertices for g in v.groups]
    out = np.zeros((len(obj.data.vertices), skeleton.n_bones))
    if triples:
        vi, gi, w = (np.array(c) for c in zip(*triples, strict=True))
        gi = gi.astype(np.int64)
        keep = (gi < len(column)) & (column[np.minimum(gi, len(column) - 1)] >= 0)
        np.add.at(out, (vi[keep], column[gi[keep]]), w[keep])
    return out if np.any(out.sum(axis=1) > 0) else None


def _parent_bone(obj, arm_obj, skeleton: Skeleton) -> int | None:
    """The bone ``obj`` is parented to (``Parent > Bone`` on the armature), or None."""
    if obj.parent == arm_obj and obj.parent_type == "BONE" and obj.parent_bone in skeleton.names:
        return skeleton.index(obj.parent_bone)
    return None


@dataclass(frozen=True)
class AbstractionData:
    """An abstraction read from Blender.

    Attributes:
        objects: Names of the objects, in reading order.
        layout: Curves of the raw points (names ``"object:i"``).
        points: Raw points at the current pose, ``(m, 3)`` world.
        weights: Bone weights of the points, ``(m, n)``.
        picks: Per object, indices of its evaluated points used (in curve order).
        warnings: Notes (e.g. weights borrowed from the mesh).
    """

    objects: tuple[str, ...]
    layout: CurveLayout
    points: np.ndarray
    weights: np.ndarray
    picks: tuple[np.ndarray, ...]
    warnings: tuple[str, ...]


def read_abstraction(objects: list, arm: ArmatureData, arm_obj, depsgraph,
                     mesh_points: np.ndarray | None = None,
                     mesh_weights: np.ndarray | None = None) -> AbstractionData:
    """Read an abstraction's curves and bone weights at the current pose.

    Args:
        objects: Abstraction objects (see :func:`resolve_abstraction`).
        arm: The armature data.
        arm_obj: The armature object.
        depsgraph: Evaluated depsgraph.
        mesh_points: Deformed skinned mesh vertices ``(V, 3)`` for borrowed weights.
        mesh_weights: Their weights ``(V, n)``.

    Raises:
        InputError: An object has no curve, or no weights can be found.
    """
    skel = arm.skeleton
    names, offsets, pts, wts, picks, warnings = [], [0], [], [], [], []
    tree = None
    for obj in objects:
        own = _vertex_group_weights(obj, skel) if obj.type == "MESH" else None
        allpts = _object_points(obj, depsgraph)
        if obj.type == "GREASEPENCIL":
            _, spans, _ = _gp_arrays(obj, depsgraph)
            chains = [np.arange(a, b) for a, b in spans if b - a >= 2]
        else:
            verts, edges, faces = mesh_arrays(obj, depsgraph)
            keep = faces <= 1 if obj.type == "CURVE" else faces >= 0
            chains = [c for c in chain_edges(edges[keep], len(verts)) if len(c) >= 2]
            if own is not None and len(own) != len(verts):
                own = None
        if not chains:
            raise InputError(f"Abstraction object '{obj.name}' has no curve (edges or strokes).")
        pick = np.concatenate(chains)
        bone = _parent_bone(obj, arm_obj, skel)
        if own is not None:
            w = own[pick]
        elif bone is not None:
            w = np.zeros((len(pick), skel.n_bones))
            w[:, bone] = 1.0
        elif mesh_points is not None and mesh_weights is not None:
            if tree is None:
                ok = np.flatnonzero(mesh_weights.sum(axis=1) > 0)
                tree = (cKDTree(mesh_points[ok]), ok)
            _, nearest = tree[0].query(allpts[pick])
            w = np.asarray(mesh_weights[tree[1][nearest]], dtype=float)
            warnings.append(f"'{obj.name}' has no bone weights: it follows the nearest "
                            "mesh vertices.")
        else:
            raise InputError(f"Abstraction object '{obj.name}' has no bone weights: give it "
                             "vertex groups or parent it to a bone.")
        for i, c in enumerate(chains):
            names.append(f"{obj.name}:{i}")
            offsets.append(offsets[-1] + len(c))
        pts.append(allpts[pick])
        wts.append(w)
        picks.append(pick)
    return AbstractionData(tuple(o.name for o in objects),
                           CurveLayout(tuple(names), np.array(offsets)), np.concatenate(pts),
                           np.concatenate(wts), tuple(picks), tuple(warnings))


def abstraction_points_now(objects: list, picks: tuple[np.ndarray, ...], depsgraph) -> np.ndarray:
    """Raw abstraction points re-evaluated in the order of :func:`read_abstraction`."""
    if not objects:
        return np.zeros((0, 3))
    return np.concatenate([_object_points(o, depsgraph)[p] for o, p in zip(objects, picks,
                                                                         strict=True)])


def deformed_vertices(mesh_objects: list, depsgraph) -> np.ndarray:
    """Evaluated world vertices of the skinned meshes, concatenated, ``(V, 3)``."""
    out = []
    for obj in mesh_objects:
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            co = np.empty(len(mesh.vertices) * 3)
            mesh.vertices.foreach_get("co", co)
        finally:
            evaluated.to_mesh_clear()
        out.append(_world(co.reshape(-1, 3), evaluated.matrix_world))
    return np.concatenate(out)


def set_rig_pose(arm_obj, names: tuple[str, ...], pose: RigPose, bones: np.ndarray,
                 object_scale: float, frame_change: np.ndarray | None = None) -> None:
    """Write rotations, uniform scales and translations of ``bones`` to the pose bones.

    ``frame_change`` is ``ArmatureData.frame_change``: for a rig read as its joint
    skeleton, the pose is conjugated back to the real bones' frames first
    (``Q = C Q' C^T``, ``t = C t'``; see ``core/joint_skeleton.py``).
    """
    real = Pose(pose.rotations, pose.translations)
    if frame_change is not None:
        real = from_joint_pose(real, frame_change)
    for b in bones:
        pb = arm_obj.pose.bones[names[b]]
        set_rotation(pb, real.rotations[b])
        pb.scale = (float(pose.scales[b]),) * 3
        pb.location = real.translations[b] / object_scale


class BlenderRigEvaluator:
    """The Blender rig as a black box: set a pose, let Blender evaluate, read points.

    Constraints, drivers and shape keys are evaluated by Blender; the original pose-bone
    transforms are restored by :meth:`restore`.
    """

    def __init__(self, context, arm_obj, arm: ArmatureData, space: ParameterSpace,
                 objects: list, picks: tuple[np.ndarray, ...], mesh_objects: list) -> None:
        """Remember what to evaluate, and the pose bones' transforms to restore.

        Args:
            context: The Blender context (its view layer is updated per evaluation).
            arm_obj: The armature object.
            arm: Its data as read before the solve.
            space: Free parameters (only their bones are written per evaluation).
            objects: Abstraction objects, in :func:`read_abstraction` order.
            picks: Per object, the indices of its evaluated points used.
            mesh_objects: The skinned character meshes.
        """
        self._context, self._arm_obj, self._arm = context, arm_obj, arm
        self._objects, self._picks, self._meshes = objects, picks, mesh_objects
        self._bones = np.unique(np.concatenate([space.rotation_bones, space.scale_bones,
                                                space.translation_bones]))
        self._saved = {pb.name: pb.matrix_basis.copy() for pb in arm_obj.pose.bones}
        self.evaluations = 0

    def __call__(self, pose: RigPose) -> tuple[np.ndarray, np.ndarray]:
        """``(raw abstraction points (m, 3), mesh vertices (V, 3))`` at ``pose``."""
        set_rig_pose(self._arm_obj, self._arm.names, pose, self._bones, self._arm.object_scale,
                     self._arm.frame_change)
        self._context.view_layer.update()
        depsgraph = self._context.evaluated_depsgraph_get()
        self.evaluations += 1
        return (abstraction_points_now(self._objects, self._picks, depsgraph),
                deformed_vertices(self._meshes, depsgraph))

    def restore(self) -> None:
        """Put back the pose bones' transforms as they were before the first evaluation."""
        for name, basis in self._saved.items():
            self._arm_obj.pose.bones[name].matrix_basis = basis
        self._context.view_layer.update()


def read_rig_pose(arm_obj, arm: ArmatureData) -> tuple[RigPose, list[str]]:
    """The current pose with uniform bone scales (the mean of each bone's scale vector).

    Returns:
        ``(pose, warnings)``; a warning lists bones with non-uniform scale.
    """
    scales = np.array([tuple(arm_obj.pose.bones[n].scale) for n in arm.names], dtype=float)
    uneven = [n for n, s in zip(arm.names, scales, strict=True) if np.ptp(s) > 1e-6]
    warnings = [f"Non-uniform scale on {uneven[:5]}: treated as uniform."] if uneven else []
    return RigPose.from_pose(arm.pose, scales.mean(axis=1)), warnings
