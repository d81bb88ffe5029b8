"""Build sample characters, cameras and Grease Pencil sketches in code.

Tests, the demo and the benchmarks import these builders so that every scene is made the
same way, deterministically and without reading a ``.blend`` file. Three characters are
available:

- :func:`build_humanoid`: 24 deforming bones, 1.8 m tall, facing -Y, arms in an A-pose.
- :func:`build_tentacle`: a body bone and a long tapering tentacle (48 bones by default).
- :func:`build_quadruped`: spine, neck, head, a 6-bone tail and four legs (27 bones).

Each character is an armature object plus a skinned mesh (one capsule per bone, explicit
smooth vertex weights, an Armature modifier). Bone rolls are computed so that the bones'
local x/z axes are meaningful (and non-trivial): code that ignores roll gets wrong answers.

Helpers add a camera framing a character, Grease Pencil (v3) objects holding world-space
strokes, strokes drawn "over" a character as seen by the camera, named example poses and
line-of-action example strokes.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import bpy
import numpy as np
from mathutils import Matrix, Quaternion, Vector

Vec3 = tuple[float, float, float]

# --------------------------------------------------------------------------------------
# Bone specifications
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BoneSpec:
    """One bone to create, in the armature's local space.

    Attributes:
        name: Bone name.
        head: Head position.
        tail: Tail position.
        parent: Parent bone name, or None for a root.
        connected: Whether the head is connected to the parent's tail.
        roll_z: Direction the bone's local z axis should face (``EditBone.align_roll``).
        radius_head: Capsule half-widths (along bone x, along bone z) at the head.
        radius_tail: Capsule half-widths (along bone x, along bone z) at the tail.
    """

    name: str
    head: Vec3
    tail: Vec3
    parent: str | None
    connected: bool
    roll_z: Vec3
    radius_head: tuple[float, float]
    radius_tail: tuple[float, float]


def _mirror_x(v: Sequence[float]) -> Vec3:
    """Mirror a vector across the YZ plane."""
    return (-v[0], v[1], v[2])


def _mirror_name(name: str) -> str:
    """Turn a ``.L`` name into its ``.R`` counterpart."""
    return name[:-2] + ".R" if name.endswith(".L") else name


def _mirrored(specs: Iterable[BoneSpec]) -> list[BoneSpec]:
    """Return the ``.R`` mirror images of ``.L`` bone specs."""
    out = []
    for s in specs:
        parent = _mirror_name(s.parent) if s.parent else None
        out.append(BoneSpec(_mirror_name(s.name), _mirror_x(s.head), _mirror_x(s.tail),
                            parent, s.connected, _mirror_x(s.roll_z),
                            s.radius_head, s.radius_tail))
    return out


def _chain(names: Sequence[str], points: Sequence[Vec3], parent: str | None,
           first_connected: bool, roll_z: Vec3 | Sequence[Vec3],
           radii: Sequence[tuple[float, float]]) -> list[BoneSpec]:
    """Bone specs for a connected chain through ``points`` (one more point than names).

    Args:
        names: Bone names, parents first.
        points: Joint positions, ``len(names) + 1`` of them.
        parent: Parent of the first bone.
        first_connected: Whether the first bone connects to ``parent``.
        roll_z: One z-axis direction for all bones, or one per bone.
        radii: Capsule half-widths at each joint, ``len(points)`` of them.

    Returns:
        The bone specs.
    """
    if len(roll_z) == 3 and not isinstance(roll_z[0], Sequence):
        roll_z = [roll_z] * len(names)
    specs = []
    for i, name in enumerate(names):
        specs.append(BoneSpec(name, tuple(points[i]), tuple(points[i + 1]),
                              parent if i == 0 else names[i - 1],
                              first_connected if i == 0 else True,
                              tuple(roll_z[i]), radii[i], radii[i + 1]))
    return specs


HUMANOID_HEIGHT = 1.8


def humanoid_specs() -> list[BoneSpec]:
    """Bone specs of the humanoid: 24 bones, 1.8 m tall, facing -Y, arms in an A-pose.

    Returns:
        The specs, parents first.
    """
    front, back, up = (0.0, -1.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    # Torso, neck and head: local z axes face backward (+Y), so their rolls are about 180
    # degrees; the limbs' z axes face forward or up.
    specs = _chain(["pelvis"], [(0, 0.0, 0.93), (0, -0.01, 1.04)], None, False, back,
                   [(0.15, 0.10), (0.14, 0.09)])
    specs += _chain(["spine", "spine.001", "chest", "neck", "head"],
                    [(0, -0.01, 1.04), (0, 0.0, 1.16), (0, 0.01, 1.28), (0, 0.0, 1.45),
                     (0, -0.01, 1.56), (0, -0.02, 1.72)],
                    "pelvis", True, back,
                    [(0.14, 0.09), (0.14, 0.09), (0.16, 0.10), (0.17, 0.10), (0.05, 0.05),
                     (0.075, 0.085)])
    # Head: a bigger, rounder capsule (its top is at about 1.81 m).
    specs[-1] = BoneSpec("head", specs[-1].head, specs[-1].tail, "neck", True, back,
                         (0.08, 0.09), (0.085, 0.09))
    # Left arm (character's left is +X), A-pose 40 degrees below horizontal; elbow slightly
    # behind so the arm has a natural bend direction.
    a = math.radians(40.0)
    d = (math.cos(a), 0.0, -math.sin(a))
    sh = (0.18, 0.01, 1.43)
    elbow = (sh[0] + 0.29 * d[0], sh[1] + 0.025, sh[2] + 0.29 * d[2])
    wrist = (elbow[0] + 0.26 * d[0], elbow[1] - 0.03, elbow[2] + 0.26 * d[2])
    knuckles = (wrist[0] + 0.09 * d[0], wrist[1] - 0.005, wrist[2] + 0.09 * d[2])
    tip = (knuckles[0] + 0.08 * d[0], knuckles[1] - 0.005, knuckles[2] + 0.08 * d[2])
    left = _chain(["shoulder.L"], [(0.03, 0.0, 1.42), sh], "chest", False, back,
                  [(0.05, 0.05), (0.055, 0.055)])
    left += _chain(["upper_arm.L", "forearm.L", "hand.L", "fingers.L"],
                   [sh, elbow, wrist, knuckles, tip], "shoulder.L", True,
                   [front, front, front, front],
                   [(0.05, 0.05), (0.04, 0.04), (0.03, 0.032), (0.016, 0.045),
                    (0.012, 0.035)])
    # Left leg: knee slightly forward, ankle slightly back, foot pointing forward (-Y).
    hip, knee, ankle = (0.10, 0.0, 0.93), (0.11, -0.025, 0.51), (0.12, 0.02, 0.09)
    ball, toe = (0.125, -0.10, 0.025), (0.13, -0.18, 0.02)
    left += _chain(["thigh.L", "shin.L"], [hip, knee, ankle], "pelvis", False, front,
                   [(0.085, 0.085), (0.06, 0.06), (0.045, 0.045)])
    left += _chain(["foot.L", "toe.L"], [ankle, ball, toe], "shin.L", True, up,
                   [(0.045, 0.04), (0.045, 0.025), (0.04, 0.02)])
    specs += left + _mirrored(left)
    return specs


def tentacle_specs(n_joints: int = 48) -> list[BoneSpec]:
    """Bone specs of the tentacle creature: a body bone and a tapering, curling tentacle.

    Args:
        n_joints: Total number of bones in the chain (body included), at least 3.

    Returns:
        The specs, parents first: ``body``, ``tentacle.000``, ``tentacle.001``, ...
    """
    if n_joints < 3:
        raise ValueError("n_joints must be at least 3")
    n = n_joints - 1
    # Bone lengths shrink geometrically; the total tentacle length is 1.6 m.
    ratio = 0.97
    lengths = ratio ** np.arange(n)
    lengths *= 1.6 / lengths.sum()
    # The tentacle leans and curls slightly in the XZ plane (bending toward +X).
    bend = np.linspace(0.0, math.radians(70.0), n) ** 1.5 / math.radians(70.0) ** 0.5
    pts = [np.array([0.0, 0.0, 0.35])]
    for length, theta in zip(lengths, bend, strict=True):
        step = np.array([math.sin(theta), 0.0, math.cos(theta)]) * length
        pts.append(pts[-1] + step)
    radii = np.linspace(0.09, 0.012, n + 1)
    names = [f"tentacle.{i:03d}" for i in range(n)]
    # Twist the bones' z axes gradually from front (-Y) toward +X (the curl side).
    twist = np.linspace(0.0, math.radians(80.0), n)
    rolls = [(math.sin(t) * math.cos(b), -math.cos(t), -math.sin(t) * math.sin(b))
             for t, b in zip(twist, bend, strict=True)]
    body = BoneSpec("body", (0.0, 0.0, 0.05), (0.0, 0.0, 0.35), None, False,
                    (0.0, -1.0, 0.0), (0.2, 0.2), (0.14, 0.14))
    return [body] + _chain(names, [tuple(p) for p in pts], "body", True, rolls,
                           [(float(r), float(r)) for r in radii])


def quadruped_specs() -> list[BoneSpec]:
    """Bone specs of the quadruped: 27 bones, about 1.4 m long, facing -Y.

    Returns:
        The specs, parents first.
    """
    up, front, down = (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)
    spine_pts = [(0, 0.45, 0.80), (0, 0.25, 0.83), (0, 0.05, 0.84), (0, -0.15, 0.83),
                 (0, -0.35, 0.82)]
    specs = _chain(["hips", "spine", "spine.001", "chest"], spine_pts, None, False, up,
                   [(0.16, 0.16), (0.15, 0.15), (0.14, 0.15), (0.15, 0.16), (0.15, 0.16)])
    specs += _chain(["neck", "neck.001", "head"],
                    [(0, -0.35, 0.82), (0, -0.45, 0.95), (0, -0.52, 1.08),
                     (0, -0.78, 1.02)],
                    "chest", True, [up, up, up],
                    [(0.10, 0.10), (0.08, 0.08), (0.075, 0.085), (0.05, 0.05)])
    tail_pts = [(0.0, 0.45 + 0.12 * i, 0.80 + 0.05 * i - 0.012 * i * i) for i in range(7)]
    specs += _chain([f"tail.{i:03d}" for i in range(6)], tail_pts, "hips", False, down,
                    [(r, r) for r in np.linspace(0.05, 0.015, 7).tolist()])
    # Left legs (+X). Front: upper_arm, forearm, front_paw; hind: thigh, shin, hind_foot,
    # hind_paw. Rolls: front legs' z axes face forward, hind legs' backward.
    back = (0.0, 1.0, 0.0)
    left = _chain(["upper_arm.L", "forearm.L", "front_paw.L"],
                  [(0.11, -0.28, 0.76), (0.12, -0.22, 0.45), (0.12, -0.26, 0.08),
                   (0.12, -0.36, 0.02)],
                  "chest", False, [front, front, up],
                  [(0.065, 0.065), (0.045, 0.045), (0.035, 0.035), (0.035, 0.02)])
    left += _chain(["thigh.L", "shin.L", "hind_foot.L", "hind_paw.L"],
                   [(0.11, 0.42, 0.76), (0.12, 0.30, 0.48), (0.12, 0.42, 0.22),
                    (0.12, 0.38, 0.05), (0.12, 0.30, 0.02)],
                   "hips", False, [back, front, back, up],
                   [(0.08, 0.08), (0.05, 0.05), (0.035, 0.035), (0.035, 0.035),
                    (0.03, 0.02)])
    specs += left + _mirrored(left)
    return specs


# --------------------------------------------------------------------------------------
# Armature and skinned mesh
# --------------------------------------------------------------------------------------


def _link(obj: bpy.types.Object) -> None:
    """Link an object into the active scene's collection."""
    bpy.context.scene.collection.objects.link(obj)


def _create_armature(name: str, specs: Sequence[BoneSpec],
                     location: Sequence[float]) -> bpy.types.Object:
    """Create an armature object from bone specs (edit mode, then back to object mode).

    Args:
        name: Object and data name.
        specs: Bones, parents first.
        location: Object location.

    Returns:
        The armature object, linked to the scene and left active.
    """
    data = bpy.data.armatures.new(name)
    obj = bpy.data.objects.new(name, data)
    obj.location = tuple(location)
    _link(obj)
    view_layer = bpy.context.view_layer
    for other in view_layer.objects:
        other.select_set(False)
    view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.object.mode_set(mode='EDIT')
    for s in specs:
        eb = data.edit_bones.new(s.name)
        eb.head, eb.tail = s.head, s.tail
        eb.align_roll(Vector(s.roll_z))
        eb.use_deform = True
    for s in specs:
        if s.parent:
            eb = data.edit_bones[s.name]
            eb.parent = data.edit_bones[s.parent]
            eb.use_connect = s.connected
    bpy.ops.object.mode_set(mode='OBJECT')
    data.display_type = 'OCTAHEDRAL'
    obj.show_in_front = True
    return obj


def _capsule(length: float, r0: tuple[float, float], r1: tuple[float, float],
             n_around: int, n_rings: int, n_cap: int) -> tuple[np.ndarray, np.ndarray, list]:
    """A closed capsule along +Y in bone space, elliptic cross-section.

    Args:
        length: Distance between the two hemisphere centres.
        r0: Half-widths (x, z) at y=0.
        r1: Half-widths (x, z) at y=length.
        n_around: Vertices per ring.
        n_rings: Rings along the straight part (at least 2).
        n_cap: Extra rings per hemispherical cap.

    Returns:
        ``(verts (n, 3), t (n,))`` with t the parameter along the bone clipped to [0, 1],
        and the list of faces (tuples of vertex indices).
    """
    ang = np.linspace(0.0, 2.0 * math.pi, n_around, endpoint=False)
    c, s = np.cos(ang), np.sin(ang)
    rings = []  # (y, rx, rz)
    for k in range(n_cap, 0, -1):  # head cap, from near the pole to the equator
        phi = 0.5 * math.pi * k / (n_cap + 1)
        rings.append((-math.sin(phi) * min(r0), r0[0] * math.cos(phi), r0[1] * math.cos(phi)))
    for t in np.linspace(0.0, 1.0, n_rings):
        rings.append((t * length, r0[0] + t * (r1[0] - r0[0]), r0[1] + t * (r1[1] - r0[1])))
    for k in range(1, n_cap + 1):
        phi = 0.5 * math.pi * k / (n_cap + 1)
        rings.append((length + math.sin(phi) * min(r1), r1[0] * math.cos(phi),
                      r1[1] * math.cos(phi)))
    ring_arr = np.array(rings)
    verts = np.empty((len(rings) * n_around + 2, 3))
    verts[:-2, 0] = (ring_arr[:, 1:2] * c).ravel()
    verts[:-2, 1] = np.repeat(ring_arr[:, 0], n_around)
    verts[:-2, 2] = (ring_arr[:, 2:3] * s).ravel()
    verts[-2] = (0.0, -min(r0), 0.0)
    verts[-1] = (0.0, length + min(r1), 0.0)
    faces: list[tuple[int, ...]] = []
    for r in range(len(rings) - 1):
        for i in range(n_around):
            j = (i + 1) % n_around
            a, b = r * n_around, (r + 1) * n_around
            faces.append((a + i, a + j, b + j, b + i))
    south, north, last = len(verts) - 2, len(verts) - 1, (len(rings) - 1) * n_around
    for i in range(n_around):
        j = (i + 1) % n_around
        faces.append((south, j, i))
        faces.append((north, last + i, last + j))
    t = np.clip(verts[:, 1] / length, 0.0, 1.0)
    return verts, t, faces


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """Cubic smoothstep of ``x`` clipped to [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _piece_weights(spec: BoneSpec, t: np.ndarray, specs_by_name: Mapping[str, BoneSpec],
                   children: Sequence[BoneSpec], blend: float) -> dict[str, np.ndarray]:
    """Normalized weights of one capsule's vertices: its bone, blended into neighbours.

    Near the head the weights blend with the parent (50/50 at the head); near the tail they
    blend with the connected children (50/50 at the tail), so the weights of neighbouring
    capsules agree where they overlap.

    Args:
        spec: The capsule's bone.
        t: Vertex parameters along the bone, in [0, 1].
        specs_by_name: All bone specs by name.
        children: Bones whose parent is ``spec``.
        blend: Fraction of the bone length over which weights blend.

    Returns:
        Weights per bone name, summing to one per vertex.
    """
    raw = {spec.name: np.ones_like(t)}
    if spec.parent is not None and spec.parent in specs_by_name:
        raw[spec.parent] = _smoothstep(1.0 - t / blend)
    for child in children:
        if child.connected:
            raw[child.name] = _smoothstep(1.0 - (1.0 - t) / blend)
    total = sum(raw.values())
    return {k: v / total for k, v in raw.items()}


def _create_skin(name: str, arm_obj: bpy.types.Object, specs: Sequence[BoneSpec],
                 n_around: int = 12, n_rings: int = 6, n_cap: int = 3,
                 blend: float = 0.3) -> bpy.types.Object:
    """Build the capsule mesh of a character, weight it and bind it to the armature.

    Args:
        name: Mesh object name.
        arm_obj: The armature object (rest bones are read from it).
        specs: The bone specs used to build the armature.
        n_around: Vertices per capsule ring.
        n_rings: Rings along each capsule.
        n_cap: Rings per capsule end cap.
        blend: Fraction of each bone over which weights blend into its neighbours.

    Returns:
        The mesh object, parented to the armature with an Armature modifier.
    """
    bones = arm_obj.data.bones
    by_name = {s.name: s for s in specs}
    all_verts, all_faces = [], []
    weights: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {s.name: [] for s in specs}
    offset = 0
    for s in specs:
        bone = bones[s.name]
        m = np.array(bone.matrix_local)
        verts, t, faces = _capsule(bone.length, s.radius_head, s.radius_tail,
                                   n_around, n_rings, n_cap)
        verts = verts @ m[:3, :3].T + m[:3, 3]
        children = [c for c in specs if c.parent == s.name]
        for bname, w in _piece_weights(s, t, by_name, children, blend).items():
            weights[bname].append((np.arange(len(verts)) + offset, w))
        all_verts.append(verts)
        all_faces.extend(tuple(i + offset for i in f) for f in faces)
        offset += len(verts)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.concatenate(all_verts).tolist(), [], all_faces)
    mesh.update()
    mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    _link(obj)
    for bname, parts in weights.items():
        group = obj.vertex_groups.new(name=bname)
        for idx, w in parts:
            for i, wi in zip(idx.tolist(), w.tolist(), strict=True):
                if wi > 1e-6:
                    group.add([i], wi, 'REPLACE')
    obj.parent = arm_obj
    mod = obj.modifiers.new("Armature", 'ARMATURE')
    mod.object = arm_obj
    return obj


def _build_character(name: str, specs: Sequence[BoneSpec], location: Sequence[float],
                     **skin_kwargs) -> tuple[bpy.types.Object, bpy.types.Object]:
    """Create armature and skinned mesh from specs; the mesh is named ``<name>_Mesh``."""
    arm_obj = _create_armature(name, specs, location)
    mesh_obj = _create_skin(f"{name}_Mesh", arm_obj, specs, **skin_kwargs)
    bpy.context.view_layer.update()
    return arm_obj, mesh_obj


def build_humanoid(name: str = "Humanoid", location: Sequence[float] = (0.0, 0.0, 0.0),
                   ) -> tuple[bpy.types.Object, bpy.types.Object]:
    """Build a 24-bone humanoid (1.8 m, facing -Y, A-pose) with a skinned capsule mesh.

    Bones: ``pelvis`` (root), ``spine``, ``spine.001``, ``chest``, ``neck``, ``head``, and
    per side ``shoulder``, ``upper_arm``, ``forearm``, ``hand``, ``fingers``, ``thigh``,
    ``shin``, ``foot``, ``toe`` with ``.L`` (+X) / ``.R`` (-X) suffixes. Arms, legs and the
    spine are connected chains; shoulders and thighs are not connected to their parents.

    Args:
        name: Armature object name; the mesh is ``<name>_Mesh``.
        location: Armature object location (feet on its z).

    Returns:
        ``(armature_obj, mesh_obj)``.
    """
    return _build_character(name, humanoid_specs(), location)


def build_tentacle(name: str = "Tentacle", n_joints: int = 48,
                   location: Sequence[float] = (0.0, 0.0, 0.0),
                   ) -> tuple[bpy.types.Object, bpy.types.Object]:
    """Build a tentacle creature: ``body`` plus a ``n_joints - 1`` bone tapering tentacle.

    Args:
        name: Armature object name; the mesh is ``<name>_Mesh``.
        n_joints: Bones in the chain, body included.
        location: Armature object location.

    Returns:
        ``(armature_obj, mesh_obj)``.
    """
    return _build_character(name, tentacle_specs(n_joints), location,
                            n_around=10, n_rings=3, n_cap=2, blend=0.5)


def build_quadruped(name: str = "Quadruped", location: Sequence[float] = (0.0, 0.0, 0.0),
                    ) -> tuple[bpy.types.Object, bpy.types.Object]:
    """Build a 27-bone quadruped facing -Y with a skinned capsule mesh.

    Bones: ``hips`` (root), ``spine``, ``spine.001``, ``chest``, ``neck``, ``neck.001``,
    ``head``, ``tail.000``..``tail.005``, and per side ``upper_arm``, ``forearm``,
    ``front_paw``, ``thigh``, ``shin``, ``hind_foot``, ``hind_paw`` (``.L``/``.R``).

    Args:
        name: Armature object name; the mesh is ``<name>_Mesh``.
        location: Armature object location.

    Returns:
        ``(armature_obj, mesh_obj)``.
    """
    return _build_character(name, quadruped_specs(), location)


def deform_bone_names(arm_obj: bpy.types.Object) -> list[str]:
    """Names of the armature's deforming bones, in armature order."""
    return [b.name for b in arm_obj.data.bones if b.use_deform]


# --------------------------------------------------------------------------------------
# Cameras and projection
# --------------------------------------------------------------------------------------


def _world_bounds(target: bpy.types.Object) -> np.ndarray:
    """World-space points bounding an object and its mesh children, ``(n, 3)``."""
    pts = []
    for obj in [target, *target.children_recursive]:
        if obj.type == 'ARMATURE':
            mw = obj.matrix_world
            for b in obj.data.bones:
                pts += [mw @ b.head_local, mw @ b.tail_local]
        elif obj.type in {'MESH', 'GREASEPENCIL', 'CURVE'}:
            pts += [obj.matrix_world @ Vector(c) for c in obj.bound_box]
    return np.array([tuple(p) for p in pts]) if pts else np.array([tuple(target.location)])


def add_camera(target: bpy.types.Object | Sequence[float] | np.ndarray,
               direction: Sequence[float] = (0.0, -1.0, 0.0), distance: float | None = None,
               lens: float = 50.0, ortho: bool = False,
               resolution: tuple[int, int] = (960, 960), margin: float = 1.15,
               name: str = "Camera") -> bpy.types.Object:
    """Add a camera looking at a character or point and make it the scene camera.

    Args:
        target: An object (framed with its children and its armature's rest bones), a
            world-space point, or world-space points ``(n, 3)`` to frame (e.g. a posed
            character's deformed vertices).
        direction: From the target toward the camera; ``(0, -1, 0)`` is the front view.
        distance: Camera distance from the target centre; None fits the target.
        lens: Focal length in mm (sensor width 36 mm, fit AUTO).
        ortho: Orthographic camera if True.
        resolution: Render resolution ``(width, height)``; sets the scene's resolution.
        margin: Frame size over the target's extent when fitting.
        name: Object and data name.

    Returns:
        The camera object.
    """
    scene = bpy.context.scene
    width, height = resolution
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    if isinstance(target, bpy.types.Object):
        pts = _world_bounds(target)
        centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    else:
        pts = np.atleast_2d(np.asarray(target, dtype=float))
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise ValueError(f"add_camera frames a point (3,) or points (n, 3), got an array "
                             f"of shape {np.shape(target)}")
        centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    back = np.asarray(direction, dtype=float)
    back /= np.linalg.norm(back)
    quat = Vector(tuple(-back)).to_track_quat('-Z', 'Y')
    rot = np.array(quat.to_matrix())
    right, up = rot[:, 0], rot[:, 1]
    rel = pts - centre
    ext_r = max(float(np.abs(rel @ right).max()), 1e-3) * margin
    ext_u = max(float(np.abs(rel @ up).max()), 1e-3) * margin
    ext_d = float(np.abs(rel @ back).max())
    aspect = width / height
    data = bpy.data.cameras.new(name)
    data.lens = lens
    data.sensor_fit = 'AUTO'
    tan_w = data.sensor_width / (2.0 * lens) * (1.0 if aspect >= 1.0 else aspect)
    tan_h = tan_w / aspect
    if ortho:
        data.type = 'ORTHO'
        data.ortho_scale = 2.0 * max(ext_r, ext_u * aspect) if aspect >= 1.0 else \
            2.0 * max(ext_u, ext_r / aspect)
        if distance is None:
            distance = 2.0 * ext_d + 5.0
    elif distance is None:
        distance = max(ext_r / tan_w, ext_u / tan_h) + ext_d
    data.clip_start = 0.01
    data.clip_end = max(100.0, 4.0 * distance)
    obj = bpy.data.objects.new(name, data)
    obj.location = tuple(centre + back * distance)
    obj.rotation_mode = 'QUATERNION'
    obj.rotation_quaternion = quat
    _link(obj)
    scene.camera = obj
    bpy.context.view_layer.update()
    return obj


def _render_size() -> tuple[float, float]:
    """Scene render size in pixels (resolution times percentage)."""
    r = bpy.context.scene.render
    scale = r.resolution_percentage / 100.0
    return r.resolution_x * scale, r.resolution_y * scale


def project_to_pixels(points_world: np.ndarray, camera_obj: bpy.types.Object) -> np.ndarray:
    """Project world points to render pixels (origin bottom-left, x right, y up).

    Args:
        points_world: ``(n, 3)`` points.
        camera_obj: The camera object (the scene's render size is used).

    Returns:
        ``(n, 2)`` pixel coordinates.
    """
    from bpy_extras.object_utils import world_to_camera_view

    scene = bpy.context.scene
    width, height = _render_size()
    ndc = np.array([tuple(world_to_camera_view(scene, camera_obj, Vector(p)))
                    for p in np.asarray(points_world, dtype=float).reshape(-1, 3)])
    return ndc[:, :2] * np.array([width, height])


def strokes_through(points_world_list: Sequence[np.ndarray], camera_obj: bpy.types.Object,
                    depth_point: Sequence[float]) -> list[np.ndarray]:
    """Move 3D polylines onto a plane facing the camera without changing their pixels.

    Each point slides along its camera ray (perspective) or along the view axis
    (orthographic) onto the plane through ``depth_point`` parallel to the image plane, so
    the strokes look in the camera exactly like the input polylines, as if drawn over the
    character at that depth.

    Args:
        points_world_list: Polylines, each ``(n, 3)`` in world space.
        camera_obj: The camera object.
        depth_point: A world point on the target plane.

    Returns:
        The strokes, each ``(n, 3)`` in world space on the plane.
    """
    mw = np.array(camera_obj.matrix_world.normalized())
    origin, axis = mw[:3, 3], -mw[:3, 2]  # camera looks along its -Z
    d = np.asarray(depth_point, dtype=float)
    plane_depth = float(axis @ (d - origin))
    out = []
    for pts in points_world_list:
        p = np.asarray(pts, dtype=float).reshape(-1, 3)
        if camera_obj.data.type == 'ORTHO':
            out.append(p + np.outer(plane_depth - (p - origin) @ axis, axis))
        else:
            depth = (p - origin) @ axis
            if np.any(depth <= 1e-9):
                raise ValueError("stroke points behind the camera cannot be moved")
            out.append(origin + (p - origin) * (plane_depth / depth)[:, None])
    return out


# --------------------------------------------------------------------------------------
# Grease Pencil (v3)
# --------------------------------------------------------------------------------------


def _gp_material(name: str = "Sketch Ink") -> bpy.types.Material:
    """A Grease Pencil stroke material (reused if it exists)."""
    mat = bpy.data.materials.get(name)
    if mat is None:
        mat = bpy.data.materials.new(name)
        bpy.data.materials.create_gpencil_data(mat)
        mat.grease_pencil.color = (0.85, 0.1, 0.05, 1.0)
    return mat


def add_grease_pencil(name: str, strokes_world: Sequence[np.ndarray], layer: str = "Lines",
                      radius: float = 0.01) -> bpy.types.Object:
    """Add a Grease Pencil object whose drawing at the current frame holds the strokes.

    Args:
        name: Object and data name.
        strokes_world: Strokes, each ``(n, 3)`` world-space points.
        layer: Layer name (made active).
        radius: Stroke point radius in world units.

    Returns:
        The Grease Pencil object (at the origin, linked to the scene).
    """
    data = bpy.data.grease_pencils.new(name)
    obj = bpy.data.objects.new(name, data)
    _link(obj)
    data.materials.append(_gp_material())
    data.layers.new(layer, set_active=True)
    bpy.context.view_layer.update()
    add_strokes(obj, strokes_world, radius=radius)
    return obj


def _drawing_at_current_frame(gp_obj: bpy.types.Object):
    """The active layer's drawing at the scene frame, creating a frame if needed."""
    layer = gp_obj.data.layers.active
    frame_no = bpy.context.scene.frame_current
    frame = layer.current_frame()
    if frame is None or frame.frame_number != frame_no:
        frame = layer.frames.new(frame_no)
    return layer, frame.drawing


def _point_attribute(drawing, name: str, n_old: int, n_total: int, new_value: float):
    """Write a FLOAT point attribute: keep the first ``n_old`` values, set the rest."""
    attr = drawing.attributes.get(name)
    values = np.full(n_total, new_value, dtype=np.float32)
    if attr is None:
        attr = drawing.attributes.new(name, 'FLOAT', 'POINT')
    elif n_old:
        old = np.empty(n_total, dtype=np.float32)
        attr.data.foreach_get("value", old)
        values[:n_old] = old[:n_old]
    attr.data.foreach_set("value", values)


def add_strokes(gp_obj: bpy.types.Object, strokes_world: Sequence[np.ndarray],
                radius: float = 0.01) -> None:
    """Append world-space strokes to the active layer's drawing at the current frame.

    Args:
        gp_obj: A Grease Pencil (v3) object.
        strokes_world: Strokes, each ``(n, 3)`` world-space points (n >= 1).
        radius: Radius of the new points in world units; opacity is 1.
    """
    strokes = [np.asarray(s, dtype=float).reshape(-1, 3) for s in strokes_world]
    if not strokes:
        return
    layer, drawing = _drawing_at_current_frame(gp_obj)
    to_local = np.array((gp_obj.matrix_world @ layer.matrix_local).inverted())
    pos = drawing.attributes.get("position")
    n_old = len(pos.data) if pos is not None else 0
    old = np.empty(n_old * 3, dtype=np.float32)
    if n_old:
        pos.data.foreach_get("vector", old)
    drawing.add_strokes([len(s) for s in strokes])
    new = np.concatenate(strokes)
    new = new @ to_local[:3, :3].T + to_local[:3, 3]
    flat = np.concatenate([old, new.astype(np.float32).ravel()])
    drawing.attributes["position"].data.foreach_set("vector", flat)
    n_total = n_old + len(new)
    _point_attribute(drawing, "radius", n_old, n_total, radius)
    _point_attribute(drawing, "opacity", n_old, n_total, 1.0)


def read_strokes(gp_obj: bpy.types.Object) -> list[np.ndarray]:
    """World-space strokes of the active layer's drawing at the current frame.

    Args:
        gp_obj: A Grease Pencil (v3) object.

    Returns:
        One ``(n, 3)`` array per stroke (empty list if there is no drawing).
    """
    layer = gp_obj.data.layers.active
    frame = layer.current_frame() if layer else None
    if frame is None:
        return []
    d = frame.drawing
    pos = d.attributes.get("position")
    if pos is None or not len(pos.data):
        return []
    flat = np.empty(len(pos.data) * 3, dtype=np.float32)
    pos.data.foreach_get("vector", flat)
    offsets = np.empty(len(d.curve_offsets), dtype=np.int32)
    d.curve_offsets.foreach_get("value", offsets)
    mw = np.array(gp_obj.matrix_world @ layer.matrix_local)
    pts = flat.reshape(-1, 3).astype(float) @ mw[:3, :3].T + mw[:3, 3]
    return [pts[a:b] for a, b in zip(offsets[:-1], offsets[1:], strict=True)]


# --------------------------------------------------------------------------------------
# Joints and poses
# --------------------------------------------------------------------------------------


def joint_positions(arm_obj: bpy.types.Object) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World-space posed head and tail of every bone (after a view-layer update).

    Args:
        arm_obj: The armature object.

    Returns:
        ``{bone name: (head (3,), tail (3,))}``.
    """
    bpy.context.view_layer.update()
    mw = arm_obj.matrix_world
    return {pb.name: (np.array(mw @ pb.head), np.array(mw @ pb.tail))
            for pb in arm_obj.pose.bones}


def sketch_over(arm_obj: bpy.types.Object, skeleton, camera, radius: float = 0.005,
                in_front: float = 0.5, name: str = "Sketch") -> bpy.types.Object:
    """Trace the posed character into a Grease Pencil drawing over it, then rest it.

    The visible contours of the armature's skinned meshes as posed now
    (``core.gesture.trace``), drawn ``in_front`` world units nearer the eye than the
    contours along their view rays; the armature is then put back at rest.

    Args:
        arm_obj: The posed armature object.
        skeleton: Its skeleton (``read_armature(arm_obj).skeleton``).
        camera: The core camera to trace through.
        radius: Stroke radius, world units.
        in_front: How far in front of the contours the strokes lie, world units.
        name: The Grease Pencil object's name.

    Returns:
        The Grease Pencil object.
    """
    from gesture_pose.blender.read_mesh import read_skinned_meshes
    from gesture_pose.core.gesture.trace import trace_contours

    meshes = read_skinned_meshes(arm_obj, skeleton)
    traced = trace_contours(meshes.deformed_vertices, meshes.triangles, camera)
    strokes = [camera.unproject_at_depth(p, d - in_front)
               for p, d in zip(traced.pixels, traced.depths, strict=True)]
    reset_pose(arm_obj)
    bpy.context.view_layer.update()
    return add_grease_pencil(name, strokes, radius=radius)


def reset_pose(arm_obj: bpy.types.Object) -> None:
    """Clear every pose bone's location, rotation (all modes) and scale."""
    for pb in arm_obj.pose.bones:
        pb.location = (0.0, 0.0, 0.0)
        pb.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
        pb.rotation_euler = (0.0, 0.0, 0.0)
        pb.rotation_axis_angle = (0.0, 0.0, 1.0, 0.0)
        pb.scale = (1.0, 1.0, 1.0)
    bpy.context.view_layer.update()


def add_ik_leg(arm_obj: bpy.types.Object, side: str = "R", pole_distance: float = 0.5
               ) -> None:
    """Rig a leg of the humanoid with IK, as animators do.

    ``shin.<side>`` is aimed at a control ``foot_ik.<side>`` shaped like the foot (which
    the foot copies the rotation of), with a pole ``knee_pole.<side>`` in front of the
    knee (-Y); the controls deform nothing. The pole angle is the quarter turn that keeps
    the rest pose.

    Args:
        arm_obj: An armature built by :func:`build_humanoid` (or with the same leg names).
        side: ``"L"`` or ``"R"``.
        pole_distance: How far in front of the knee the pole is, world units.

    Raises:
        RuntimeError: No quarter-turn pole angle keeps the rest pose.
    """
    foot_name, shin = f"foot.{side}", f"shin.{side}"
    target, pole_name = f"foot_ik.{side}", f"knee_pole.{side}"
    bpy.context.view_layer.objects.active = arm_obj
    bpy.ops.object.mode_set(mode="EDIT")
    bones = arm_obj.data.edit_bones
    foot, knee = bones[foot_name], bones[shin].head.copy()
    control = bones.new(target)
    control.head, control.tail, control.roll = foot.head, foot.tail, foot.roll
    pole = bones.new(pole_name)
    pole.head = knee + Vector((0.0, -pole_distance, 0.0))
    pole.tail = knee + Vector((0.0, -pole_distance - 0.1, 0.0))
    control.use_deform = pole.use_deform = False
    bpy.ops.object.mode_set(mode="OBJECT")
    constrain_ik_leg(arm_obj, side)


def constrain_ik_leg(arm_obj: bpy.types.Object, side: str = "L") -> None:
    """The constraints of :func:`add_ik_leg` on a leg whose controls exist.

    ``shin.<side>`` gets an IK constraint (chain of 2) aimed at ``foot_ik.<side>`` with
    the pole ``knee_pole.<side>``, at the quarter-turn pole angle that keeps the rest
    pose; ``foot.<side>`` copies the control's rotation.

    Raises:
        RuntimeError: No quarter-turn pole angle keeps the rest pose.
    """
    shin, thigh, target = f"shin.{side}", f"thigh.{side}", f"foot_ik.{side}"
    ik = arm_obj.pose.bones[shin].constraints.new("IK")
    ik.target, ik.subtarget, ik.chain_count = arm_obj, target, 2
    ik.pole_target, ik.pole_subtarget = arm_obj, f"knee_pole.{side}"
    copy = arm_obj.pose.bones[f"foot.{side}"].constraints.new("COPY_ROTATION")
    copy.target, copy.subtarget = arm_obj, target
    rest = {n: np.array(arm_obj.pose.bones[n].matrix) for n in (thigh, shin)}
    for angle in (-90.0, 90.0, 0.0, 180.0):
        ik.pole_angle = math.radians(angle)
        bpy.context.view_layer.update()
        if all(np.allclose(np.array(arm_obj.pose.bones[n].matrix), m, atol=1e-4)
               for n, m in rest.items()):
            return
    raise RuntimeError(f"No pole angle keeps the rest pose of the {side} leg.")


def _set_local_rotation(pb: bpy.types.PoseBone, quat: Quaternion) -> None:
    """Write a local rotation in the pose bone's current rotation mode."""
    mode = pb.rotation_mode
    if mode == 'QUATERNION':
        pb.rotation_quaternion = quat
    elif mode == 'AXIS_ANGLE':
        axis, angle = quat.to_axis_angle()
        pb.rotation_axis_angle = (angle, *axis)
    else:
        pb.rotation_euler = quat.to_euler(mode)


def _local_rotation(pb: bpy.types.PoseBone) -> Matrix:
    """The pose bone's local rotation as a 3x3 matrix, whatever its rotation mode."""
    mode = pb.rotation_mode
    if mode == 'QUATERNION':
        return pb.rotation_quaternion.normalized().to_matrix()
    if mode == 'AXIS_ANGLE':
        angle, *axis = pb.rotation_axis_angle
        return Matrix.Rotation(angle, 3, Vector(axis))
    return pb.rotation_euler.to_matrix()


def apply_rotations(arm_obj: bpy.types.Object,
                    rotations: Mapping[str, tuple[Sequence[float], float]],
                    offsets: Mapping[str, Sequence[float]] | None = None) -> None:
    """Pose bones by rotations about armature-space axes, relative to their parents.

    Each entry rotates the bone (and so its subtree) by ``angle`` degrees about ``axis``
    (armature space), on top of whatever its ancestors' rotations did. Bones not listed
    keep rest orientation relative to their parent. Rotations are written in each pose
    bone's rotation mode (quaternion by default). Bones must use default inheritance.

    Args:
        arm_obj: The armature object; its current pose is replaced.
        rotations: ``{bone name: (axis (3,), angle in degrees)}``.
        offsets: ``{root bone name: armature-space translation of its head}``; only for
            bones without a parent.
    """
    reset_pose(arm_obj)
    accumulated: dict[str, Matrix] = {}  # armature-space rotation applied to each bone
    for pb in arm_obj.pose.bones:  # parents come before children
        parent_rot = accumulated.get(pb.parent.name) if pb.parent else None
        parent_rot = parent_rot if parent_rot is not None else Matrix.Identity(3)
        own = Matrix.Identity(3)
        if pb.name in rotations:
            axis, angle = rotations[pb.name]
            own = Matrix.Rotation(math.radians(angle), 3, Vector(axis).normalized())
        total = own @ parent_rot
        accumulated[pb.name] = total
        if pb.name in rotations:
            rest = pb.bone.matrix_local.to_3x3()
            local = rest.transposed() @ parent_rot.transposed() @ total @ rest
            _set_local_rotation(pb, local.to_quaternion())
    for name, offset in (offsets or {}).items():
        pb = arm_obj.pose.bones[name]
        if pb.parent is not None:
            raise ValueError(f"offsets are only supported for root bones, not {name!r}")
        pb.location = pb.bone.matrix_local.to_3x3().transposed() @ Vector(offset)
    bpy.context.view_layer.update()


def set_rotation_modes(arm_obj: bpy.types.Object, mode_by_bone: Mapping[str, str]) -> None:
    """Change pose bones' rotation modes, keeping their current rotations.

    Args:
        arm_obj: The armature object.
        mode_by_bone: ``{bone name: mode}`` with modes ``'QUATERNION'``, ``'AXIS_ANGLE'``
            or an Euler order such as ``'XYZ'``, ``'ZXY'``.
    """
    for name, mode in mode_by_bone.items():
        pb = arm_obj.pose.bones[name]
        rot = _local_rotation(pb)
        pb.rotation_mode = mode
        _set_local_rotation(pb, rot.to_quaternion())
    bpy.context.view_layer.update()


X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
_A_POSE_ARM_L = (math.cos(math.radians(40.0)), 0.0, -math.sin(math.radians(40.0)))


def _swing(from_dir: Sequence[float], to_dir: Sequence[float]) -> tuple[Vec3, float]:
    """Axis and angle (degrees) of the shortest rotation from one direction to another."""
    a, b = Vector(from_dir).normalized(), Vector(to_dir).normalized()
    axis = a.cross(b)
    angle = math.degrees(a.angle(b))
    return (tuple(axis.normalized()), angle)


# Armature-space rotations per bone, relative to the posed parent (see apply_rotations).
# The character faces -Y; its left is +X. A rotation about +Y swings a bone from +Z to +X.
HUMANOID_POSES: dict[str, dict[str, tuple[Vec3, float]]] = {
    # Right arm raised high above the shoulder, forearm bent inward, hand waving.
    "wave": {"upper_arm.R": (Y, 110.0), "forearm.R": (Y, 30.0), "hand.R": (Y, 15.0),
             "head": (X, -8.0)},
    # Left leg forward (hip flexed, knee bent), arms swinging in opposition.
    "step": {"thigh.L": (X, -40.0), "shin.L": (X, 35.0), "foot.L": (X, -10.0),
             "thigh.R": (X, 12.0), "upper_arm.L": (X, 25.0), "upper_arm.R": (X, -25.0),
             "forearm.R": (X, -20.0)},
    # Both arms stretched forward and up, torso leaning forward.
    "reach": {"spine.001": (X, 10.0), "chest": (X, 10.0),
              "upper_arm.L": _swing(_A_POSE_ARM_L, (0.25, -0.9, 0.35)),
              "upper_arm.R": _swing(_mirror_x(_A_POSE_ARM_L), (-0.25, -0.9, 0.35)),
              "forearm.L": (Z, 10.0), "forearm.R": (Z, -10.0)},
    # Deep knee bend, torso forward, arms forward for balance.
    "crouch": {"pelvis": (X, 20.0), "spine": (X, 10.0), "thigh.L": (X, -100.0),
               "thigh.R": (X, -100.0), "shin.L": (X, 120.0), "shin.R": (X, 120.0),
               "foot.L": (X, -40.0), "foot.R": (X, -40.0),
               "upper_arm.L": (X, -50.0), "upper_arm.R": (X, -50.0)},
    # Left arm raised sideways and up (target pose of the example arm stroke).
    "raise_left_arm": {"upper_arm.L": (Y, -85.0), "forearm.L": (Y, -25.0),
                       "hand.L": (Y, -15.0)},
    # Right leg kicked out sideways and forward, knee bent (target of the example leg
    # stroke).
    "kick_right_leg": {"thigh.R": _swing((0.0, 0.0, -1.0), (-0.6, -0.35, -0.7)),
                       "shin.R": (Y, -30.0), "foot.R": (Y, -20.0)},
}


# Directions used by HUMANOID_FAR_POSES: each chain's bones are swung one after the
# other, so a child's swing starts from the direction its parent's swing gave it.
_RUN_ARM_R, _RUN_ARM_L = (-0.25, -0.75, -0.6), (0.25, 0.6, -0.75)
_LUNGE_THIGH_L = (0.35, -0.75, -0.55)
_THROW_ARM_R = (-0.6, 0.5, 0.6)
_CROSS_ARM_L, _CROSS_ARM_R = (0.3, -0.45, -0.84), (-0.3, -0.4, -0.87)
_SIT_ARM_L = (0.3, -0.6, -0.75)

# Poses far from the bind pose, for tests and benchmarks that must tell a real result from
# leaving the character as it is: several limbs changed, in and out of the view plane.
# Same conventions as HUMANOID_POSES (armature-space rotations relative to the posed
# parent; the character faces -Y, its left is +X; about +X a positive angle swings a
# downward bone backwards, so hips flex with negative and knees with positive angles).
HUMANOID_FAR_POSES: dict[str, dict[str, tuple[Vec3, float]]] = {
    # Running: left knee high in front, right leg pushing off behind, torso leaning
    # forward, right arm forward with the elbow bent up, left arm back.
    "run": {"spine": (X, 12.0), "thigh.L": (X, -65.0), "shin.L": (X, 85.0),
            "foot.L": (X, -20.0), "thigh.R": (X, 30.0), "shin.R": (X, 75.0),
            "foot.R": (X, 30.0),
            "upper_arm.R": _swing(_mirror_x(_A_POSE_ARM_L), _RUN_ARM_R),
            "forearm.R": _swing(_RUN_ARM_R, (-0.2, -0.6, 0.75)),
            "upper_arm.L": _swing(_A_POSE_ARM_L, _RUN_ARM_L),
            "forearm.L": _swing(_RUN_ARM_L, (0.15, -0.5, -0.85))},
    # Lunge forward and to the left: the left thigh reaches forward and out, its shin
    # upright; the right leg stretched behind; both arms raised forward overhead.
    "lunge": {"thigh.L": _swing((0.0, 0.0, -1.0), _LUNGE_THIGH_L),
              "shin.L": _swing(_LUNGE_THIGH_L, (0.1, -0.2, -0.97)),
              "thigh.R": (X, 40.0), "shin.R": (X, 15.0), "foot.R": (X, 45.0),
              "upper_arm.L": _swing(_A_POSE_ARM_L, (0.3, -0.5, 0.8)),
              "upper_arm.R": _swing(_mirror_x(_A_POSE_ARM_L), (-0.3, -0.5, 0.8))},
    # Throw, wind-up: torso twisted to the right, right arm up and back with the forearm
    # up, left arm pointing forward at the target, left leg stepping forward.
    "throw": {"spine.001": (Z, -30.0),
              "upper_arm.R": _swing(_mirror_x(_A_POSE_ARM_L), _THROW_ARM_R),
              "forearm.R": _swing(_THROW_ARM_R, (-0.2, -0.3, 0.93)),
              "upper_arm.L": _swing(_A_POSE_ARM_L, (0.35, -0.9, 0.25)),
              "thigh.L": (X, -35.0), "shin.L": (X, 25.0), "thigh.R": (X, 15.0),
              "shin.R": (X, 20.0)},
    # Arms crossed in front of the chest (the left forearm in front of the right one),
    # standing on the left leg with the right knee raised in front.
    "cross_arms": {"upper_arm.L": _swing(_A_POSE_ARM_L, _CROSS_ARM_L),
                   "forearm.L": _swing(_CROSS_ARM_L, (-0.93, -0.3, 0.2)),
                   "upper_arm.R": _swing(_mirror_x(_A_POSE_ARM_L), _CROSS_ARM_R),
                   "forearm.R": _swing(_CROSS_ARM_R, (0.93, -0.2, 0.3)),
                   "thigh.R": (X, -70.0), "shin.R": (X, 90.0)},
    # Sitting on an invisible stool: thighs forward, shins down, leaning back a little,
    # hands resting on the knees.
    "sit": {"spine": (X, -10.0), "thigh.L": (X, -85.0), "shin.L": (X, 85.0),
            "thigh.R": (X, -80.0), "shin.R": (X, 100.0),
            "upper_arm.L": _swing(_A_POSE_ARM_L, _SIT_ARM_L),
            "forearm.L": _swing(_SIT_ARM_L, (0.05, -0.9, -0.4)),
            "upper_arm.R": _swing(_mirror_x(_A_POSE_ARM_L), _mirror_x(_SIT_ARM_L)),
            "forearm.R": _swing(_mirror_x(_SIT_ARM_L), (-0.05, -0.9, -0.4))},
}


# Root translations (armature space) of the poses that need them.
HUMANOID_POSE_OFFSETS: dict[str, dict[str, Vec3]] = {"crouch": {"pelvis": (0.0, 0.12, -0.5)}}


def pose_humanoid(arm_obj: bpy.types.Object, pose_name: str) -> None:
    """Put the humanoid in a named example pose (``"rest"`` clears the pose).

    Poses: ``"wave"`` (right arm raised), ``"step"`` (left leg forward), ``"reach"`` (arms
    forward and up), ``"crouch"``, ``"raise_left_arm"``, ``"kick_right_leg"``.

    Args:
        arm_obj: An armature built by :func:`build_humanoid`.
        pose_name: One of :data:`HUMANOID_POSES` or ``"rest"``.
    """
    if pose_name == "rest":
        reset_pose(arm_obj)
        return
    if pose_name not in HUMANOID_POSES:
        raise KeyError(f"unknown pose {pose_name!r}; choose from {sorted(HUMANOID_POSES)}")
    apply_rotations(arm_obj, HUMANOID_POSES[pose_name], HUMANOID_POSE_OFFSETS.get(pose_name))


def tentacle_curl_rotations(arm_obj: bpy.types.Object, first_deg: float = -110.0,
                            second_deg: float = 220.0) -> dict[str, tuple[Vec3, float]]:
    """Rotations bending the tentacle into an S: first half one way, second half back.

    The bends are about the armature's Y axis (in the front view's image plane), spread
    evenly over each half of the tentacle.

    Args:
        arm_obj: An armature built by :func:`build_tentacle`.
        first_deg: Total bend of the lower half (negative bends toward -X).
        second_deg: Total bend of the upper half.

    Returns:
        Rotations for :func:`apply_rotations`.
    """
    names = [b.name for b in arm_obj.data.bones if b.name.startswith("tentacle.")]
    half = len(names) // 2
    per_bone = [first_deg / max(half, 1)] * half
    per_bone += [second_deg / max(len(names) - half, 1)] * (len(names) - half)
    return {name: (Y, angle) for name, angle in zip(names, per_bone, strict=True)}


QUADRUPED_POSES: dict[str, dict[str, tuple[Vec3, float]]] = {
    # Tail swept up and curled over the back.
    "tail_up": {f"tail.{i:03d}": (X, 18.0 + 4.0 * i) for i in range(6)},
    # Left front leg lifted and reaching forward.
    "paw_forward": {"upper_arm.L": (X, -55.0), "forearm.L": (X, 25.0),
                    "front_paw.L": (X, 20.0)},
}


# --------------------------------------------------------------------------------------
# Line-of-action example strokes
# --------------------------------------------------------------------------------------


def catmull_rom(points: np.ndarray, samples_per_segment: int = 32) -> np.ndarray:
    """Centripetal Catmull-Rom spline through points (end points duplicated).

    Args:
        points: ``(n, d)`` control points, n >= 2.
        samples_per_segment: Samples per span.

    Returns:
        ``(m, d)`` samples from the first to the last point, passing through all points.
    """
    p = np.asarray(points, dtype=float)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-12])
    p = p[keep]
    if len(p) < 2:
        return p.copy()
    ext = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    u = np.linspace(0.0, 1.0, samples_per_segment, endpoint=False)[:, None]
    out = []
    for i in range(1, len(ext) - 2):
        p0, p1, p2, p3 = ext[i - 1], ext[i], ext[i + 1], ext[i + 2]
        t0 = 0.0
        t1 = t0 + np.linalg.norm(p1 - p0) ** 0.5
        t2 = t1 + np.linalg.norm(p2 - p1) ** 0.5
        t3 = t2 + np.linalg.norm(p3 - p2) ** 0.5
        t = t1 + u * (t2 - t1)
        a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
        a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
        a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
        b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
        b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
        out.append((t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2)
    out.append(p[-1:])
    return np.vstack(out)


def _resample_by_pixels(curve_world: np.ndarray, camera_obj: bpy.types.Object,
                        step_px: float) -> np.ndarray:
    """Resample a world polyline so consecutive points are ``step_px`` apart on screen."""
    px = project_to_pixels(curve_world, camera_obj)
    seg = np.linalg.norm(np.diff(px, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(int(math.ceil(s[-1] / step_px)) + 1, 2)
    target = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(target, s, curve_world[:, k]) for k in range(3)])


def chain_stroke(arm_obj: bpy.types.Object, camera_obj: bpy.types.Object,
                 chain: Sequence[str], rotations: Mapping[str, tuple[Sequence[float], float]],
                 step_px: float = 3.0) -> np.ndarray:
    """A line-of-action stroke for a bone chain: where the chain goes in a target pose.

    Poses the armature with ``rotations``, takes the chain's posed joints (each bone's head
    and the last tail), moves them onto the plane through the chain's first joint facing the
    camera, draws a Catmull-Rom curve through them and samples it every ``step_px`` pixels.
    The pose is reset to rest afterwards.

    Args:
        arm_obj: The armature object.
        camera_obj: The camera the stroke is drawn in.
        chain: Bone names from the chain's root to its end.
        rotations: Target pose for :func:`apply_rotations`.
        step_px: Distance between stroke points in pixels.

    Returns:
        ``(n, 3)`` world-space stroke starting at the first bone's head.
    """
    apply_rotations(arm_obj, rotations)
    joints = joint_positions(arm_obj)
    pts = np.array([joints[b][0] for b in chain] + [joints[chain[-1]][1]])
    reset_pose(arm_obj)
    start = joint_positions(arm_obj)[chain[0]][0]
    (on_plane,) = strokes_through([pts], camera_obj, start)
    curve = catmull_rom(on_plane, samples_per_segment=48)
    return _resample_by_pixels(curve, camera_obj, step_px)


def example_strokes_humanoid(arm_obj: bpy.types.Object, camera_obj: bpy.types.Object,
                             step_px: float = 3.0) -> list[np.ndarray]:
    """Line-of-action strokes for the humanoid: a raised left arm and a kicking right leg.

    Args:
        arm_obj: An armature built by :func:`build_humanoid` (left at rest afterwards).
        camera_obj: The camera the strokes are drawn in.
        step_px: Distance between stroke points in pixels.

    Returns:
        Two ``(n, 3)`` world strokes: from ``upper_arm.L``'s head, from ``thigh.R``'s head.
    """
    arm = chain_stroke(arm_obj, camera_obj, ["upper_arm.L", "forearm.L", "hand.L",
                                             "fingers.L"],
                       HUMANOID_POSES["raise_left_arm"], step_px)
    leg = chain_stroke(arm_obj, camera_obj, ["thigh.R", "shin.R", "foot.R", "toe.R"],
                       HUMANOID_POSES["kick_right_leg"], step_px)
    return [arm, leg]


def example_strokes_tentacle(arm_obj: bpy.types.Object, camera_obj: bpy.types.Object,
                             step_px: float = 3.0) -> list[np.ndarray]:
    """One S-shaped curling stroke starting at the tentacle's base joint.

    Args:
        arm_obj: An armature built by :func:`build_tentacle` (left at rest afterwards).
        camera_obj: The camera the stroke is drawn in.
        step_px: Distance between stroke points in pixels.

    Returns:
        One ``(n, 3)`` world stroke from ``tentacle.000``'s head.
    """
    chain = [b.name for b in arm_obj.data.bones if b.name.startswith("tentacle.")]
    return [chain_stroke(arm_obj, camera_obj, chain, tentacle_curl_rotations(arm_obj),
                         step_px)]


def example_strokes_quadruped(arm_obj: bpy.types.Object, camera_obj: bpy.types.Object,
                              step_px: float = 3.0) -> list[np.ndarray]:
    """Strokes for the quadruped: the tail swept up and the left front leg reaching forward.

    Args:
        arm_obj: An armature built by :func:`build_quadruped` (left at rest afterwards).
        camera_obj: The camera the strokes are drawn in (a side view suits these).
        step_px: Distance between stroke points in pixels.

    Returns:
        Two ``(n, 3)`` world strokes: from ``tail.000``'s head, from ``upper_arm.L``'s head.
    """
    tail = chain_stroke(arm_obj, camera_obj, [f"tail.{i:03d}" for i in range(6)],
                        QUADRUPED_POSES["tail_up"], step_px)
    leg = chain_stroke(arm_obj, camera_obj, ["upper_arm.L", "forearm.L", "front_paw.L"],
                       QUADRUPED_POSES["paw_forward"], step_px)
    return [tail, leg]


def add_light(name: str = "Sun", energy: float = 3.0,
              rotation_deg: Vec3 = (50.0, 10.0, 30.0)) -> bpy.types.Object:
    """Add a sun light to the scene.

    Args:
        name: Object and data name.
        energy: Sun strength.
        rotation_deg: Euler XYZ rotation in degrees.

    Returns:
        The light object.
    """
    data = bpy.data.lights.new(name, 'SUN')
    data.energy = energy
    obj = bpy.data.objects.new(name, data)
    obj.location = (2.0, -3.0, 5.0)
    obj.rotation_euler = tuple(math.radians(a) for a in rotation_deg)
    _link(obj)
    return obj

