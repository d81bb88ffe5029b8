"""Read the meshes an armature deforms: rest and posed vertices, triangles, bone weights.

Positions are read in bulk (``foreach_get``) and put in world space. Weights come from the
vertex groups named after the skeleton's bones and are normalized per vertex. When a
modifier changes a mesh's vertex count (e.g. Subdivision Surface) the evaluated mesh no
longer matches the rest vertices; the posed vertices are then computed by linear blend
skinning from the armature's current pose, ``x' = sum_i w_i (F_i R_i^T (x - r_i) + h_i)``
(world rest frames ``R``, heads ``r``; posed frames ``F``, heads ``h``), and a warning
says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ..core.exceptions import InputError
from ..core.skeleton import PoseState, Skeleton


@dataclass(frozen=True)
class MeshData:
    """The skinned meshes of an armature, concatenated.

    Attributes:
        object_names: Names of the mesh objects, in the order their vertices appear.
        vertex_offsets: Start of each object's vertices, shape ``(k + 1,)``.
        rest_vertices: World positions before deformation, ``(V, 3)``.
        deformed_vertices: World positions after all modifiers, ``(V, 3)``.
        triangles: Vertex indices into the concatenated vertices, ``(T, 3)`` int.
        weights: Bone weights summing to 1 per vertex (0 for unweighted vertices),
            ``(V, n_bones)`` float32, columns in skeleton order.
        warnings: Notes about the read (e.g. skinning computed here).
    """

    object_names: tuple[str, ...]
    vertex_offsets: np.ndarray
    rest_vertices: np.ndarray
    deformed_vertices: np.ndarray
    triangles: np.ndarray
    weights: np.ndarray
    warnings: tuple[str, ...] = ()


def meshes_of(arm_obj: bpy.types.Object) -> list[bpy.types.Object]:
    """Mesh objects of the scene deformed by ``arm_obj``.

    A mesh counts when one of its Armature modifiers points at ``arm_obj`` or when it is
    parented to ``arm_obj`` with parent type ``'ARMATURE'``.

    Args:
        arm_obj: The armature object.

    Returns:
        The mesh objects, sorted by name.
    """
    found = []
    for obj in bpy.context.scene.objects:
        if obj.type != "MESH":
            continue
        by_modifier = any(m.type == "ARMATURE" and m.object == arm_obj for m in obj.modifiers)
        by_parent = obj.parent == arm_obj and obj.parent_type == "ARMATURE"
        if by_modifier or by_parent:
            found.append(obj)
    return sorted(found, key=lambda o: o.name)


def _world(points: np.ndarray, matrix) -> np.ndarray:
    m = np.array(matrix, dtype=float)
    return points @ m[:3, :3].T + m[:3, 3]


def _positions(mesh) -> np.ndarray:
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def _triangles(mesh) -> np.ndarray:
    mesh.calc_loop_triangles()
    tris = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", tris)
    return tris.reshape(-1, 3)


def _weights(obj, skeleton: Skeleton, groups: dict[str, str]) -> np.ndarray:
    """Raw (unnormalized) bone weights of one mesh object, ``(v, n_bones)`` float32.

    ``groups`` maps vertex groups to the skeleton bones they deform with when the names
    differ (a Rigify rig's ``DEF-`` segments to its reading bones).
    """
    mesh = obj.data
    column = np.full(max(len(obj.vertex_groups), 1), -1, dtype=np.int64)
    bone = {name: i for i, name in enumerate(skeleton.names)}
    for vg in obj.vertex_groups:
        column[vg.index] = bone.get(vg.name, bone.get(groups.get(vg.name, ""), -1))
    # One pass over the (vertex, group) pairs: Blender has no bulk reader for them.
    pairs = [(v.index, g.group, g.weight) for v in mesh.vertices for g in v.groups]
    out = np.zeros((len(mesh.vertices), skeleton.n_bones), dtype=np.float32)
    if pairs:
        vi, gi, w = (np.array(c) for c in zip(*pairs, strict=True))
        keep = column[gi] >= 0
        np.add.at(out, (vi[keep], column[gi[keep]]), w[keep].astype(np.float32))
    return out


def _blend_skin(rest: np.ndarray, weights: np.ndarray, skeleton: Skeleton,
                state: PoseState) -> np.ndarray:
    """Linear blend skinning of world rest points ``(v, 3)`` with normalized weights."""
    rot = state.frames @ np.swapaxes(skeleton.rest_frames, 1, 2)
    out = np.zeros_like(rest)
    for b in np.flatnonzero(weights.any(axis=0)):
        moved = (rest - skeleton.rest_heads[b]) @ rot[b].T + state.heads[b]
        out += weights[:, b : b + 1] * moved
    unweighted = weights.sum(axis=1) <= 0
    out[unweighted] = rest[unweighted]
    return out


def rest_skin(arm_obj: bpy.types.Object, skeleton: Skeleton
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """Rest vertices and normalized bone weights of the meshes ``arm_obj`` deforms.

    No evaluation: only the meshes' own vertices and vertex groups are read.

    Args:
        arm_obj: The armature object.
        skeleton: Its skeleton; weight columns follow its bone order.

    Returns:
        ``(vertices (V, 3) world, weights (V, n_bones) float32)``, or None without meshes.
    """
    objects = meshes_of(arm_obj)
    if not objects:
        return None
    groups = _groups(arm_obj)
    parts = [_object_skin(o, skeleton, groups) for o in objects]
    return np.concatenate([v for v, _ in parts]), np.concatenate([w for _, w in parts])


def _groups(arm_obj: bpy.types.Object) -> dict[str, str]:
    """Vertex groups read as other bones: a generated Rigify rig's deform bones."""
    from .rigify import rigify_map

    rig = rigify_map(arm_obj)
    return rig.groups if rig is not None else {}


def _object_skin(obj, skeleton: Skeleton, groups: dict[str, str]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """One mesh object's rest vertices in world space and normalized bone weights."""
    w = _weights(obj, skeleton, groups)
    total = w.sum(axis=1, keepdims=True)
    return (_world(_positions(obj.data), obj.matrix_world),
            np.divide(w, total, out=np.zeros_like(w), where=total > 0))


def read_skinned_meshes(arm_obj: bpy.types.Object, skeleton: Skeleton,
                        depsgraph: bpy.types.Depsgraph | None = None,
                        state: PoseState | None = None) -> MeshData:
    """Read every mesh deformed by ``arm_obj``.

    Args:
        arm_obj: The armature object.
        skeleton: Its skeleton (from ``read_armature``); weight columns follow its order.
        depsgraph: Evaluated depsgraph (the context's when None).
        state: The armature's current posed state, used only for meshes whose modifiers
            change the vertex count (computed from the current pose when None).

    Returns:
        The concatenated mesh data.

    Raises:
        InputError: No mesh is deformed by the armature.
    """
    objects = meshes_of(arm_obj)
    if not objects:
        raise InputError(f"No mesh is deformed by '{arm_obj.name}': add an Armature "
                         "modifier pointing at it (or parent the mesh with automatic weights).")
    depsgraph = bpy.context.evaluated_depsgraph_get() if depsgraph is None else depsgraph
    rest, deformed, tris, weights, warnings = [], [], [], [], []
    offset = 0
    groups = _groups(arm_obj)
    for obj in objects:
        r, w = _object_skin(obj, skeleton, groups)
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            d = _positions(mesh)
        finally:
            evaluated.to_mesh_clear()
        if len(d) == len(r):
            d = _world(d, evaluated.matrix_world)
        else:
            if state is None:
                from .read_armature import read_armature

                posed = read_armature(arm_obj)
                state = posed.skeleton.forward(posed.pose)
            d = _blend_skin(r, w, skeleton, state)
            warnings.append(f"'{obj.name}': a modifier changes the vertex count; posed "
                            "vertices were computed by linear blend skinning.")
        rest.append(r)
        deformed.append(d)
        tris.append(_triangles(obj.data) + offset)
        weights.append(w)
        offset += len(r)
    sizes = [len(r) for r in rest]
    return MeshData(
        object_names=tuple(o.name for o in objects),
        vertex_offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        rest_vertices=np.concatenate(rest),
        deformed_vertices=np.concatenate(deformed),
        triangles=np.concatenate(tris),
        weights=np.concatenate(weights),
        warnings=tuple(warnings),
    )
