"""Sketch abstractions for the sample humanoid, and the "abstraction" sample scene.

:func:`add_abstractions` gives a character built by :func:`builders.build_humanoid` two
authored abstractions (Hahn et al. 2015) in a "Sketch Abstraction" collection:

- "Stick Figure": a mesh of edge chains along the spine, arms and legs, each vertex in the
  vertex group of its bone (weight 1), deformed by an Armature modifier;
- "Outline": a U-shaped contour around every limb and the torso in the front view, whose
  vertices copy the bone weights of the nearest character vertex.

:func:`save_abstraction_scene` saves a scene with the humanoid, both abstractions, a front
camera and a Grease Pencil "Sketch" holding a redrawn stick figure (the "wave" pose).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from sample_scenes import builders  # noqa: E402

COLLECTION = "Sketch Abstraction"
STICK_CHAINS: tuple[tuple[str, ...], ...] = (
    ("pelvis", "spine", "spine.001", "chest", "neck", "head"),
    ("upper_arm.L", "forearm.L", "hand.L"),
    ("upper_arm.R", "forearm.R", "hand.R"),
    ("thigh.L", "shin.L", "foot.L"),
    ("thigh.R", "shin.R", "foot.R"),
)
#: Half-widths of the outline around each chain (metres, in the front view).
OUTLINE_WIDTH = (0.16, 0.06, 0.06, 0.08, 0.08)


def _bone_points(arm_obj: bpy.types.Object, name: str) -> tuple[np.ndarray, np.ndarray]:
    """World rest head and tail of a bone, each ``(3,)``."""
    bone = arm_obj.data.bones[name]
    m = np.array(arm_obj.matrix_world)
    return (m[:3, :3] @ np.array(bone.head_local) + m[:3, 3],
            m[:3, :3] @ np.array(bone.tail_local) + m[:3, 3])


def _collection(name: str, parent: bpy.types.Collection) -> bpy.types.Collection:
    """The collection ``name`` (created if missing), linked under ``parent``."""
    coll = bpy.data.collections.get(name) or bpy.data.collections.new(name)
    if coll.name not in parent.children:
        parent.children.link(coll)
    return coll


def _edge_mesh(name: str, polylines: Sequence[np.ndarray], weights: Sequence[np.ndarray],
               arm_obj: bpy.types.Object, coll: bpy.types.Collection) -> bpy.types.Object:
    """A mesh of edge chains with bone vertex groups and an Armature modifier."""
    verts = np.concatenate(polylines)
    edges, start = [], 0
    for p in polylines:
        edges += [(start + i, start + i + 1) for i in range(len(p) - 1)]
        start += len(p)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts.tolist(), edges, [])
    obj = bpy.data.objects.new(name, mesh)
    coll.objects.link(obj)
    w = np.concatenate(weights)
    names = [b.name for b in arm_obj.data.bones]
    for j, bone in enumerate(names):
        idx = np.flatnonzero(w[:, j] > 1e-6)
        if idx.size:
            group = obj.vertex_groups.new(name=bone)
            for value in np.unique(w[idx, j]):  # one call per distinct weight
                group.add(idx[w[idx, j] == value].tolist(), float(value), "REPLACE")
    mod = obj.modifiers.new("Armature", "ARMATURE")
    mod.object = arm_obj
    obj.hide_render = True
    return obj


def add_stick_figure(arm_obj: bpy.types.Object, coll: bpy.types.Collection,
                     per_bone: int = 4) -> bpy.types.Object:
    """The "Stick Figure" abstraction: edge chains along :data:`STICK_CHAINS`."""
    names = [b.name for b in arm_obj.data.bones]
    polylines, weights = [], []
    for chain in STICK_CHAINS:
        pts, w = [], []
        for k, bone in enumerate(chain):
            head, tail = _bone_points(arm_obj, bone)
            s = np.linspace(0.0, 1.0, per_bone + 1)
            s = s if k == len(chain) - 1 else s[:-1]
            pts.append(head + s[:, None] * (tail - head))
            wb = np.zeros((len(s), len(names)))
            wb[:, names.index(bone)] = 1.0
            w.append(wb)
        polylines.append(np.concatenate(pts))
        weights.append(np.concatenate(w))
    return _edge_mesh("Stick Figure", polylines, weights, arm_obj, coll)


def _mesh_weights(mesh_obj: bpy.types.Object, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """World vertices ``(v, 3)`` of a skinned mesh and its bone weights ``(v, n)``."""
    co = np.empty(len(mesh_obj.data.vertices) * 3)
    mesh_obj.data.vertices.foreach_get("co", co)
    m = np.array(mesh_obj.matrix_world)
    pts = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    col = np.array([names.index(g.name) if g.name in names else -1
                    for g in mesh_obj.vertex_groups] or [-1])
    # No foreach_get for vertex-group memberships: one pass, then a numpy scatter.
    triples = [(v.index, g.group, g.weight) for v in mesh_obj.data.vertices for g in v.groups]
    w = np.zeros((len(pts), len(names)))
    if triples:
        vi, gi, wt = (np.array(c) for c in zip(*triples, strict=True))
        keep = col[gi.astype(int)] >= 0
        np.add.at(w, (vi[keep], col[gi[keep].astype(int)]), wt[keep])
    return pts, w


def add_outline(arm_obj: bpy.types.Object, mesh_obj: bpy.types.Object,
                coll: bpy.types.Collection, samples: int = 6) -> bpy.types.Object:
    """The "Outline" abstraction: a U-shaped contour around each chain in the front view."""
    from scipy.spatial import cKDTree

    names = [b.name for b in arm_obj.data.bones]
    mesh_pts, mesh_w = _mesh_weights(mesh_obj, names)
    tree = cKDTree(mesh_pts)
    polylines, weights = [], []
    for chain, width in zip(STICK_CHAINS, OUTLINE_WIDTH, strict=True):
        joints = [_bone_points(arm_obj, chain[0])[0]] + [_bone_points(arm_obj, b)[1]
                                                           for b in chain]
        joints = np.array(joints)
        t = np.linspace(0.0, 1.0, samples * (len(joints) - 1) + 1)
        seg = np.minimum((t * (len(joints) - 1)).astype(int), len(joints) - 2)
        f = t * (len(joints) - 1) - seg
        line = joints[seg] + f[:, None] * (joints[seg + 1] - joints[seg])
        d = np.gradient(line, axis=0)
        side = np.stack([-d[:, 2], np.zeros(len(d)), d[:, 0]], axis=1)
        side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
        poly = np.concatenate([line + width * side, (line - width * side)[::-1]])
        _, nearest = tree.query(poly)
        polylines.append(poly)
        weights.append(mesh_w[nearest])
    return _edge_mesh("Outline", polylines, weights, arm_obj, coll)


def add_abstractions(arm_obj: bpy.types.Object, mesh_obj: bpy.types.Object
                     ) -> tuple[bpy.types.Object, bpy.types.Object]:
    """Add the "Stick Figure" and "Outline" abstractions (in that order) to a humanoid.

    Returns:
        ``(stick_figure, outline)`` mesh objects, in collections of the same names inside
        the "Sketch Abstraction" collection.
    """
    root = _collection(COLLECTION, bpy.context.scene.collection)
    stick = add_stick_figure(arm_obj, _collection("Stick Figure", root))
    outline = add_outline(arm_obj, mesh_obj, _collection("Outline", root))
    bpy.context.view_layer.update()
    return stick, outline


def evaluated_polylines(obj: bpy.types.Object) -> list[np.ndarray]:
    """World polylines of an edge-chain abstraction as currently deformed."""
    from gesture_pose.blender.abstraction_io import mesh_arrays
    from gesture_pose.blender.read_strokes import chain_edges

    pts, edges, _ = mesh_arrays(obj, bpy.context.evaluated_depsgraph_get())
    return [pts[c] for c in chain_edges(edges, len(pts))]


def save_abstraction_scene(path: str | Path, pose_name: str = "wave") -> Path:
    """Build and save the abstraction sample scene.

    The humanoid stays in its rest pose; the "Sketch" Grease Pencil object holds the stick
    figure of ``pose_name`` as five strokes, ready for "Pose from Abstraction".

    Args:
        path: Output ``.blend`` path.
        pose_name: Example pose whose stick figure is drawn.

    Returns:
        The saved path.
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    arm_obj, mesh_obj = builders.build_humanoid()
    stick, _ = add_abstractions(arm_obj, mesh_obj)
    builders.add_light()
    builders.add_camera(arm_obj, resolution=(960, 960), margin=1.5)
    builders.pose_humanoid(arm_obj, pose_name)
    bpy.context.view_layer.update()
    strokes = evaluated_polylines(stick)
    builders.pose_humanoid(arm_obj, "rest")
    builders.add_grease_pencil("Sketch", toward_camera(strokes))
    bpy.context.scene["gesture_pose_sample"] = "abstraction"
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(out), compress=True)
    return out



def toward_camera(polylines: Sequence[np.ndarray], distance: float = 0.3) -> list[np.ndarray]:
    """Slide points along their rays toward the scene camera (same picture, drawn in front)."""
    eye = np.array(bpy.context.scene.camera.matrix_world.translation)
    out = []
    for p in polylines:
        d = eye - p
        out.append(p + distance * d / np.linalg.norm(d, axis=1, keepdims=True))
    return out


def _overlay(name: str, polylines: Sequence[np.ndarray], color: Sequence[float],
             radius: float = 0.012) -> bpy.types.Object:
    """A Grease Pencil object showing polylines in one colour, in front (for pictures)."""
    from gesture_pose.blender.read_strokes import write_strokes

    polylines = toward_camera(polylines)
    obj = bpy.data.objects.get(name)
    if obj is None:
        obj = bpy.data.objects.new(name, bpy.data.grease_pencils.new(name))
        bpy.context.scene.collection.objects.link(obj)
    write_strokes(obj, "Lines", list(polylines), replace=True, color=color, radius=radius)
    return obj


def _render(path: Path, size: int = 480) -> None:
    """Render the scene camera's view with Workbench to a square PNG at ``path``."""
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)


def render_figures(outdir: str | Path) -> list[Path]:
    """Render the documentation pictures of the abstraction mode headless (Workbench).

    Pictures: ``abstraction_input.png`` (rest pose, stick figure in blue, new drawing in
    red), ``abstraction_result.png`` (after Pose from Abstraction), ``abstraction_outline.png``
    (the outline abstraction), ``abstraction_drawover_input.png`` and
    ``abstraction_drawover_result.png`` (draw-over on the left forearm).

    Args:
        outdir: Folder for the PNG files.

    Returns:
        The written paths.
    """
    import gesture_pose

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    gesture_pose.register()
    arm_obj, mesh_obj = builders.build_humanoid()
    stick, outline = add_abstractions(arm_obj, mesh_obj)
    builders.add_light()
    builders.add_camera(arm_obj, resolution=(480, 480), margin=1.5)
    builders.pose_humanoid(arm_obj, "wave")
    bpy.context.view_layer.update()
    target = evaluated_polylines(stick)
    builders.pose_humanoid(arm_obj, "rest")
    bpy.context.view_layer.update()
    builders.add_grease_pencil("Sketch", toward_camera(target, 0.35), radius=0.006)
    blue = (0.1, 0.35, 0.95, 1.0)
    written = []
    _overlay("Abstraction View", evaluated_polylines(stick), blue)
    written.append(out / "abstraction_input.png")
    _render(written[-1])
    override = {"active_object": arm_obj, "object": arm_obj, "selected_objects": [arm_obj]}
    with bpy.context.temp_override(**override):
        bpy.ops.gesture_pose.pose_abstraction(sketch="Sketch", abstraction="Stick Figure")
    bpy.context.view_layer.update()
    _overlay("Abstraction View", evaluated_polylines(stick), blue)
    written.append(out / "abstraction_result.png")
    _render(written[-1])
    arm_obj.animation_data_clear()
    builders.pose_humanoid(arm_obj, "rest")
    bpy.data.objects.remove(bpy.data.objects["Sketch"])
    bpy.context.view_layer.update()
    _overlay("Abstraction View", evaluated_polylines(outline), blue)
    written.append(out / "abstraction_outline.png")
    _render(written[-1])
    # Draw-over: a stroke along the left forearm, redrawn raised.
    m = np.array(arm_obj.matrix_world)
    bone = arm_obj.data.bones["forearm.L"]
    head, tail = (m[:3, :3] @ np.array(v) + m[:3, 3] for v in (bone.head_local,
                                                                 bone.tail_local))
    source = head + np.linspace(0.1, 0.95, 30)[:, None] * (tail - head) + [0, -0.2, 0]
    pivot = head + [0, -0.2, 0]
    ang = np.radians(-70.0)
    rot = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
    target_dw = (source - pivot) @ rot.T + pivot
    _overlay("Abstraction View", [], blue)
    builders.add_grease_pencil("Sketch", toward_camera([source, target_dw], 0.1),
                               radius=0.006)
    written.append(out / "abstraction_drawover_input.png")
    _render(written[-1])
    with bpy.context.temp_override(**override):
        bpy.ops.gesture_pose.drawover(sketch="Sketch")
    bpy.context.view_layer.update()
    written.append(out / "abstraction_drawover_result.png")
    _render(written[-1])
    return written


if __name__ == "__main__":
    print(save_abstraction_scene(sys.argv[1] if len(sys.argv) > 1
                                 else ROOT / "sample_scenes" / "abstraction.blend"))
