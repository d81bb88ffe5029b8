"""Readers: armature, view, sketches and skinned meshes against Blender's own answers."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.exceptions import InputError

from .conftest import (
    add_camera,
    add_empty,
    add_grease_pencil,
    build_armature,
    constrain,
    link,
)

bpy = pytest.importorskip("bpy")
from mathutils import Quaternion, Vector  # noqa: E402

from gesture_pose.blender.read_armature import _parents_first, read_armature  # noqa: E402
from gesture_pose.blender.read_mesh import meshes_of, read_skinned_meshes  # noqa: E402
from gesture_pose.blender.read_strokes import (  # noqa: E402
    chain_edges,
    read_sketch,
    remove_strokes,
    strokes_to_2d,
    write_strokes,
)
from gesture_pose.blender.read_view import (  # noqa: E402
    camera_from_context,
    camera_from_object,
    camera_from_region,
)

pytestmark = pytest.mark.blender

MODES = ("QUATERNION", "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "AXIS_ANGLE")


def random_pose(obj, rng: np.random.Generator, modes=MODES) -> None:
    """Give every pose bone a random rotation (in a cycled rotation mode) and location."""
    for k, pb in enumerate(obj.pose.bones):
        pb.rotation_mode = modes[k % len(modes)]
        q = Quaternion(rng.normal(size=4)).normalized()
        if pb.rotation_mode == "QUATERNION":
            pb.rotation_quaternion = q
        elif pb.rotation_mode == "AXIS_ANGLE":
            axis, angle = q.to_axis_angle()
            pb.rotation_axis_angle = (angle, *axis)
        else:
            pb.rotation_euler = q.to_euler(pb.rotation_mode)
        pb.location = rng.normal(scale=0.2, size=3)
    bpy.context.view_layer.update()


def blender_world(obj):
    """Blender's posed world heads, tails and normalized frames, in skeleton bone order."""
    mw = obj.matrix_world
    heads = {pb.name: np.array(mw @ pb.head) for pb in obj.pose.bones}
    tails = {pb.name: np.array(mw @ pb.tail) for pb in obj.pose.bones}
    frames = {pb.name: np.array((mw @ pb.matrix).to_3x3().normalized())
              for pb in obj.pose.bones}
    return heads, tails, frames


# ----------------------------------------------------------------------------- armature


def test_parents_first_orders_any_forest():
    names = ["c", "a", "d", "b", "e"]
    parent_names = ["b", None, "c", "a", None]
    order = _parents_first(parent_names, names)
    pos = {names[i]: k for k, i in enumerate(order)}
    for name, parent in zip(names, parent_names, strict=True):
        if parent is not None:
            assert pos[parent] < pos[name]
    assert sorted(order.tolist()) == list(range(5))


@pytest.mark.parametrize("seed", [0, 1])
def test_forward_matches_blender_in_every_rotation_mode(two_root_rig, seed):
    rng = np.random.default_rng(seed)
    # Six bones: seed 0 uses modes 0-5, seed 1 modes 4-7, 0, 1, so all eight are covered.
    modes = MODES[4 * seed:] + MODES[:4 * seed]
    random_pose(two_root_rig, rng, modes)
    data = read_armature(two_root_rig)
    state = data.skeleton.forward(data.pose)
    heads, tails, frames = blender_world(two_root_rig)
    for i, name in enumerate(data.names):
        np.testing.assert_allclose(state.heads[i], heads[name], atol=1e-5)
        np.testing.assert_allclose(state.tails[i], tails[name], atol=1e-5)
        np.testing.assert_allclose(state.frames[i], frames[name], atol=1e-5)
    for name, mode in zip(data.names, data.rotation_modes, strict=True):
        assert two_root_rig.pose.bones[name].rotation_mode == mode
    assert len(set(data.rotation_modes)) == 6
    assert data.object_scale == pytest.approx(1.7, rel=1e-6)


def test_rest_data_and_flags(two_root_rig):
    data = read_armature(two_root_rig)
    sk = data.skeleton
    assert sk.names[:2] == ("hip", "prop")  # roots first, in Blender order
    assert np.all(sk.parents < np.arange(sk.n_bones))
    assert sk.parents[sk.index("fore")] == sk.index("arm")
    assert np.flatnonzero(sk.parents < 0).tolist() == [sk.index("hip"), sk.index("prop")]
    assert sk.connected[sk.index("spine")] and not sk.connected[sk.index("arm")]
    mw = two_root_rig.matrix_world
    for i, name in enumerate(sk.names):
        bone = two_root_rig.data.bones[name]
        np.testing.assert_allclose(sk.rest_heads[i], mw @ bone.head_local, atol=1e-5)
        np.testing.assert_allclose(sk.rest_tails[i], mw @ bone.tail_local, atol=1e-5)
        rest = (mw @ bone.matrix_local).to_3x3().normalized()
        np.testing.assert_allclose(sk.rest_frames[i], np.array(rest), atol=1e-5)
    np.testing.assert_allclose(data.pose.rotations, np.tile(np.eye(3), (6, 1, 1)), atol=1e-6)
    assert not data.pinned.any() and data.gesture_override is None


def test_masks_locks_and_limits(two_root_rig):
    arm = two_root_rig.data
    arm.collections.new("Pinned").assign(arm.bones["prop"])
    gesture = arm.collections.new("Gesture")
    gesture.assign(arm.bones["arm"])
    gesture.assign(arm.bones["fore"])
    two_root_rig.pose.bones["hip"]["gesture_pose_pinned"] = 1
    pb = two_root_rig.pose.bones["spine"]
    pb.lock_rotation = (True, False, True)
    pb.use_ik_limit_x, pb.ik_min_x, pb.ik_max_x = True, -0.5, 0.25
    data = read_armature(two_root_rig)
    names = data.names
    assert [names[i] for i in np.flatnonzero(data.pinned)] == ["hip", "prop"]
    assert [names[i] for i in np.flatnonzero(data.gesture_override)] == ["arm", "fore"]
    i = names.index("spine")
    assert data.lock_rotation[i].tolist() == [True, False, True]
    assert data.lock_rotation.sum() == 2
    np.testing.assert_allclose(data.ik_limits[i, 0], [-0.5, 0.25], atol=1e-7)
    assert np.isnan(np.delete(data.ik_limits.reshape(-1, 2), 3 * i, axis=0)).all()


def test_rejects_bad_objects(two_root_rig):
    two_root_rig.scale = (1.0, 2.0, 1.0)
    bpy.context.view_layer.update()
    with pytest.raises(InputError, match="non-uniform scale"):
        read_armature(two_root_rig)
    two_root_rig.scale = (-1.0, -1.0, -1.0)
    bpy.context.view_layer.update()
    with pytest.raises(InputError, match="mirrored"):
        read_armature(two_root_rig)
    two_root_rig.scale = (1.0, 1.0, 1.0)
    two_root_rig.location = (float("nan"), 0.0, 0.0)
    bpy.context.view_layer.update()
    with pytest.raises(InputError, match="NaN"):
        read_armature(two_root_rig)
    empty = link(bpy.data.objects.new("Empty", None))
    with pytest.raises(InputError, match="armature"):
        read_armature(empty)


# ----------------------------------------------------------------------------- view


def world_to_pixels(scene, cam_obj, points):
    from bpy_extras.object_utils import world_to_camera_view

    r = scene.render
    size = np.array([r.resolution_x, r.resolution_y]) * r.resolution_percentage / 100
    return np.array([world_to_camera_view(scene, cam_obj, Vector(p))[:2] for p in points]) * size


@pytest.mark.parametrize("ortho", [False, True])
def test_camera_from_object_matches_world_to_camera_view(bpy_blank, ortho):
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 640, 360
    scene.render.resolution_percentage = 50
    cam = add_camera((3.0, -5.0, 2.5), (0.2, 0.1, 0.9), ortho_scale=4.0 if ortho else None,
                     lens=35.0)
    camera = camera_from_object(cam)
    assert (camera.width, camera.height, camera.is_perspective) == (320, 180, not ortho)
    pts = np.random.default_rng(3).uniform(-1.0, 1.5, size=(20, 3))
    np.testing.assert_allclose(camera.project(pts), world_to_pixels(scene, cam, pts), atol=1e-3)


class _Region:
    def __init__(self, width, height, kind="WINDOW"):
        self.width, self.height, self.type = width, height, kind


class _RegionView3D:
    def __init__(self, view, window, perspective):
        self.view_matrix, self.window_matrix = view, window
        self.perspective_matrix = window @ view
        self.is_perspective = perspective


def test_region_stand_in_gives_the_same_camera(bpy_blank):
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 500, 700
    cam = add_camera((-2.0, -6.0, 1.0), (0.0, 0.0, 1.0))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    window = cam.calc_matrix_camera(depsgraph, x=500, y=700)
    rv3d = _RegionView3D(cam.matrix_world.normalized().inverted(), window, True)
    region = _Region(500, 700)
    from_region = camera_from_region(region, rv3d)
    from_object = camera_from_object(cam)
    np.testing.assert_allclose(from_region.view_matrix, from_object.view_matrix, atol=1e-6)
    np.testing.assert_allclose(from_region.projection_matrix, from_object.projection_matrix,
                               atol=1e-6)
    pts = np.random.default_rng(4).uniform(-1.0, 2.0, size=(10, 3))
    expect = np.array([location_3d_to_region_2d(region, rv3d, Vector(p)) for p in pts])
    np.testing.assert_allclose(from_region.project(pts), expect, atol=1e-3)


def test_camera_from_context_falls_back_to_scene_camera(bpy_blank):
    with pytest.raises(InputError, match="No view"):
        camera_from_context(bpy.context)
    cam = add_camera((0.0, -6.0, 1.0), (0.0, 0.0, 1.0))
    camera = camera_from_context(bpy.context)
    np.testing.assert_allclose(camera.location, np.array(cam.location), atol=1e-5)


# ----------------------------------------------------------------------------- sketches


def moved_gp(name="Sketch"):
    gp = bpy.data.grease_pencils.new(name)
    obj = link(bpy.data.objects.new(name, gp))
    obj.location, obj.rotation_euler, obj.scale = (1.0, -2.0, 0.5), (0.4, 0.1, -0.7), (2, 2, 2)
    bpy.context.view_layer.update()
    return obj


def lines(rng, count, n=5):
    return [rng.normal(size=(n + k, 3)) for k in range(count)]


def test_written_strokes_read_back_in_world_space(bpy_blank):
    rng = np.random.default_rng(7)
    obj = moved_gp()
    a, b = lines(rng, 2), lines(rng, 3)
    write_strokes(obj, "A", a)
    layer_b = write_strokes(obj, "B", b, radius=0.05)
    layer_b.translation, layer_b.rotation, layer_b.scale = (0.3, 0.0, -1.0), (0.5, 0.2, 0.0), (
        1.5, 1.5, 1.5)
    # Moving the layer afterwards moves the strokes with it.
    moved = np.array(layer_b.matrix_local)
    out = read_sketch(obj)
    assert [(s.layer_name, s.index) for s in out] == [("A", 0), ("A", 1), ("B", 0), ("B", 1),
                                                      ("B", 2)]
    for s, p in zip(out[:2], a, strict=True):
        np.testing.assert_allclose(s.points_world, p, atol=1e-5)
        np.testing.assert_allclose(s.radius, 0.01, atol=1e-7)
    mw = np.array(obj.matrix_world)
    for s, p in zip(out[2:], b, strict=True):
        local = (np.linalg.inv(mw) @ np.c_[p, np.ones(len(p))].T).T
        expect = (mw @ moved @ local.T).T[:, :3]
        np.testing.assert_allclose(s.points_world, expect, atol=1e-5)
        np.testing.assert_allclose(s.radius, 0.05, atol=1e-7)
    assert obj.data.materials[0].is_grease_pencil


def test_hidden_layers_and_frames(bpy_blank):
    rng = np.random.default_rng(8)
    obj = moved_gp()
    first, later, other = lines(rng, 1), lines(rng, 2), lines(rng, 1)
    write_strokes(obj, "A", first, frame=1)
    write_strokes(obj, "A", later, frame=5)
    write_strokes(obj, "B", other, frame=1)
    bpy.context.scene.frame_set(3)
    assert [len(s.points_world) for s in read_sketch(obj)] == [5, 5]
    assert [len(s.points_world) for s in read_sketch(obj, frame=7)] == [5, 6, 5]
    obj.data.layers["B"].hide = True
    out = read_sketch(obj, frame=7)
    assert [s.layer_name for s in out] == ["A", "A"]
    np.testing.assert_allclose(out[1].points_world, later[1], atol=1e-5)
    assert read_sketch(obj, frame=0) == []


def test_data_api_strokes_and_append(bpy_blank):
    rng = np.random.default_rng(9)
    first, extra = lines(rng, 2), lines(rng, 1)
    obj = add_grease_pencil(first)
    ink = bpy.data.materials.new("Ink")
    bpy.data.materials.create_gpencil_data(ink)
    obj.data.materials.append(ink)
    drawing = obj.data.layers["Lines"].current_frame().drawing
    n_old = sum(len(p) for p in first)
    for name in ("radius", "opacity"):
        attr = drawing.attributes.new(name, "FLOAT", "POINT")
        attr.data.foreach_set("value", np.full(n_old, 0.3, dtype=np.float32))
    write_strokes(obj, "Lines", extra, frame=1, replace=False, color=(1.0, 0.2, 0.1))
    out = read_sketch(obj)
    assert len(out) == 3
    np.testing.assert_allclose(out[0].radius, 0.3, atol=1e-7)
    np.testing.assert_allclose(out[2].radius, 0.01, atol=1e-7)
    opacity = np.empty(n_old + len(extra[0]), dtype=np.float32)
    drawing.attributes["opacity"].data.foreach_get("value", opacity)
    np.testing.assert_allclose(opacity, np.r_[np.full(n_old, 0.3), np.ones(len(extra[0]))])
    for s, p in zip(out, first + extra, strict=True):
        np.testing.assert_allclose(s.points_world, p, atol=1e-5)
    index = np.empty(3, dtype=np.int32)
    drawing.attributes["material_index"].data.foreach_get("value", index)
    assert index.tolist() == [0, 0, 1]
    assert obj.data.materials[1].grease_pencil.color[:] == pytest.approx((1.0, 0.2, 0.1, 1.0))


def test_remove_strokes_removes_exactly_the_asked_ones(bpy_blank):
    rng = np.random.default_rng(10)
    obj = moved_gp()
    strokes = lines(rng, 5)
    write_strokes(obj, "A", strokes)
    assert remove_strokes(obj, "A", [3, 0]) == 2
    out = read_sketch(obj)
    assert len(out) == 3
    for s, p in zip(out, [strokes[1], strokes[2], strokes[4]], strict=True):
        np.testing.assert_allclose(s.points_world, p, atol=1e-5)
    with pytest.raises(InputError, match="3 strokes"):
        remove_strokes(obj, "A", [3])
    with pytest.raises(InputError, match="no layer"):
        remove_strokes(obj, "Nope", [0])


def test_chain_edges_orders_paths_and_loops():
    # Path 4-2-0-3 given out of order, and a loop 1-5-6.
    edges = np.array([[0, 2], [6, 1], [3, 0], [5, 6], [2, 4], [1, 5]])
    chains = chain_edges(edges, 7)
    assert [c.tolist() for c in chains] == [[3, 0, 2, 4], [1, 5, 6, 1]]


def test_curve_objects_read_as_polylines(bpy_blank):
    curve = bpy.data.curves.new("Svg", "CURVE")
    curve.dimensions = "3D"
    poly = curve.splines.new("POLY")
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.5], [0.0, 2.0, 0.0]])
    poly.points.add(len(pts) - 1)
    poly.points.foreach_set("co", np.c_[pts, np.ones(len(pts))].ravel())
    bez = curve.splines.new("BEZIER")
    bez.bezier_points.add(1)
    bez.bezier_points[0].co, bez.bezier_points[1].co = (3.0, 0.0, 0.0), (3.0, 2.0, 0.0)
    for p in bez.bezier_points:
        p.handle_left_type = p.handle_right_type = "AUTO"
    curve.resolution_u = 8
    obj = link(bpy.data.objects.new("Svg", curve))
    obj.location, obj.rotation_euler = (0.5, 0.5, 0.0), (0.0, 0.0, np.pi / 2)
    bpy.context.view_layer.update()
    out = read_sketch(obj)
    assert [s.layer_name for s in out] == ["Svg", "Svg"]
    mw = np.array(obj.matrix_world)
    np.testing.assert_allclose(out[0].points_world, pts @ mw[:3, :3].T + mw[:3, 3], atol=1e-5)
    assert len(out[1].points_world) == 9
    np.testing.assert_allclose(out[1].points_world[[0, -1]], [[0.5, 3.5, 0.0], [-1.5, 3.5, 0.0]],
                               atol=1e-5)


def test_filled_closed_curve_gives_its_outline(bpy_blank):
    bpy.ops.curve.primitive_bezier_circle_add(radius=2.0, location=(1.0, 0.0, 0.0))
    obj = bpy.context.object
    obj.data.dimensions = "2D"
    obj.data.fill_mode = "BOTH"
    bpy.context.view_layer.update()
    (stroke,) = read_sketch(obj)
    np.testing.assert_allclose(stroke.points_world[0], stroke.points_world[-1])
    assert len(stroke.points_world) == 4 * obj.data.resolution_u + 1
    radius = np.linalg.norm(stroke.points_world - [1.0, 0.0, 0.0], axis=1)
    np.testing.assert_allclose(radius, 2.0, rtol=0.02)


def test_strokes_to_2d_projects_and_rejects(bpy_blank):
    cam = add_camera((0.0, -6.0, 1.0), (0.0, 0.0, 1.0))
    camera = camera_from_object(cam)
    line = np.array([[-0.5, 0.0, 1.0], [0.0, 0.0, 1.2], [0.5, 0.0, 1.0]])
    (stroke,) = strokes_to_2d([line], camera)
    np.testing.assert_allclose(stroke.points, camera.project(line))
    with pytest.raises(InputError, match="behind the view"):
        strokes_to_2d([line - [0.0, 10.0, 0.0]], camera)
    obj = add_grease_pencil([line, np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])])
    with pytest.raises(InputError, match="Stroke 1 of layer 'Lines' is a single point"):
        strokes_to_2d(read_sketch(obj), camera)


# ----------------------------------------------------------------------------- meshes

CHAIN = (
    ("lower", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), None, False, 0.0),
    ("upper", (0.0, 0.0, 1.0), (0.0, 0.0, 2.0), "lower", True, 0.4),
)


def skinned_column(arm_obj, name="Skin", parent=False, subdivide=False):
    """A thin ring-stacked column along the chain with explicit weights per ring."""
    rings = np.linspace(0.0, 2.0, 5)
    angles = np.linspace(0.0, 2 * np.pi, 4, endpoint=False)
    verts = [(0.1 * np.cos(a), 0.1 * np.sin(a), z) for z in rings for a in angles]
    faces = [(4 * r + k, 4 * r + (k + 1) % 4, 4 * (r + 1) + (k + 1) % 4, 4 * (r + 1) + k)
             for r in range(4) for k in range(4)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    obj = link(bpy.data.objects.new(name, mesh))
    lower = obj.vertex_groups.new(name="lower")
    upper = obj.vertex_groups.new(name="upper")
    extra = obj.vertex_groups.new(name="not_a_bone")
    for r, z in enumerate(rings):
        ring = [4 * r + k for k in range(4)]
        if r < 4:  # the top ring stays unweighted by bones
            lower.add(ring, float(np.clip(1.5 - z, 0.0, 1.0)) * 2.0, "REPLACE")
            upper.add(ring, float(np.clip(z - 0.5, 0.0, 1.0)) * 2.0, "REPLACE")
        extra.add(ring, 0.7, "REPLACE")
    if parent:
        obj.parent, obj.parent_type = arm_obj, "ARMATURE"
    else:
        obj.modifiers.new("Armature", "ARMATURE").object = arm_obj
    if subdivide:
        obj.modifiers.new("Subsurf", "SUBSURF").levels = 1
    return obj


def test_read_skinned_meshes(bpy_blank):
    rig = build_armature(CHAIN, location=(0.5, 0.0, 0.2), rotation_euler=(0.0, 0.2, 0.0))
    bent = skinned_column(rig, "Bent")
    parented = skinned_column(rig, "Parented", parent=True)
    link(bpy.data.objects.new("Unrelated", bpy.data.meshes.new("Unrelated")))
    assert meshes_of(rig) == [bent, parented]
    pb = rig.pose.bones["upper"]
    pb.rotation_mode = "XYZ"
    pb.rotation_euler = (0.8, 0.0, 0.3)
    bpy.context.view_layer.update()
    data = read_armature(rig)
    mesh = read_skinned_meshes(rig, data.skeleton)
    assert mesh.object_names == ("Bent", "Parented") and mesh.warnings == ()
    assert mesh.vertex_offsets.tolist() == [0, 20, 40]
    mw = np.array(bent.matrix_world)
    co = np.array([v.co for v in bent.data.vertices])
    np.testing.assert_allclose(mesh.rest_vertices[:20], co @ mw[:3, :3].T + mw[:3, 3],
                               atol=1e-6)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for k, obj in enumerate((bent, parented)):
        evaluated = obj.evaluated_get(depsgraph)
        posed = np.array([evaluated.matrix_world @ v.co for v in evaluated.data.vertices])
        np.testing.assert_allclose(mesh.deformed_vertices[20 * k: 20 * (k + 1)], posed,
                                   atol=1e-5)
    assert mesh.triangles.shape == (64, 3)
    assert mesh.triangles[:32].max() < 20 <= mesh.triangles[32:].min()
    col = {name: data.names.index(name) for name in ("lower", "upper")}
    ring_z = np.repeat(np.linspace(0.0, 2.0, 5), 4)
    raw_lower = np.clip(1.5 - ring_z, 0.0, 1.0)
    raw_upper = np.clip(ring_z - 0.5, 0.0, 1.0)
    expect_lower = np.where(ring_z < 2.0, raw_lower / (raw_lower + raw_upper), 0.0)
    np.testing.assert_allclose(mesh.weights[:20, col["lower"]], expect_lower, atol=1e-6)
    np.testing.assert_allclose(mesh.weights[:20].sum(axis=1), (ring_z < 2.0).astype(float),
                               atol=1e-6)


def test_vertex_count_changes_fall_back_to_blend_skinning(bpy_blank):
    rig = build_armature(CHAIN)
    plain = skinned_column(rig, "A")
    skinned_column(rig, "B", subdivide=True)
    rig.pose.bones["upper"].rotation_quaternion = Quaternion((1.0, 0.0, 0.0), 0.9)
    bpy.context.view_layer.update()
    data = read_armature(rig)
    mesh = read_skinned_meshes(rig, data.skeleton)
    assert len(mesh.warnings) == 1 and "'B'" in mesh.warnings[0]
    # Blender's own deformation of the identical mesh A equals the blend skinning of B.
    evaluated = plain.evaluated_get(bpy.context.evaluated_depsgraph_get())
    blender = np.array([v.co for v in evaluated.data.vertices])
    np.testing.assert_allclose(mesh.deformed_vertices[20:], blender, atol=1e-5)
    rest_top = mesh.rest_vertices[36:40]
    np.testing.assert_allclose(mesh.deformed_vertices[36:40], rest_top)


def test_no_skinned_mesh_is_an_input_error(bpy_blank):
    rig = build_armature(CHAIN)
    with pytest.raises(InputError, match="No mesh is deformed"):
        read_skinned_meshes(rig, read_armature(rig).skeleton)


# ----------------------------------------------------------------------------- operators


def test_settings_and_panel_are_registered(registered):
    from gesture_pose.blender.panel import VIEW3D_PT_gesture_pose
    from gesture_pose.blender.properties import _is_armature, _is_sketch

    assert VIEW3D_PT_gesture_pose.is_registered
    settings = bpy.context.scene.gesture_pose
    assert settings.armature is None and settings.sketch is None
    rig = build_armature(CHAIN)
    sketch = add_grease_pencil([np.zeros((2, 3))])
    settings.armature, settings.sketch = rig, sketch
    assert (settings.armature, settings.sketch) == (rig, sketch)
    assert _is_armature(settings, rig) and not _is_armature(settings, sketch)
    assert _is_sketch(settings, sketch) and not _is_sketch(settings, rig)


def test_resolve_armature_order(registered):
    from gesture_pose.blender.operator_utils import resolve_armature

    ctx = bpy.context
    with pytest.raises(InputError, match="No armature"):
        resolve_armature(ctx)
    a = build_armature(CHAIN, name="A")
    b = build_armature(CHAIN, name="B")
    sketch = add_grease_pencil([np.zeros((2, 3))])
    with ctx.temp_override(active_object=sketch, selected_objects=[sketch, b]):
        assert resolve_armature(bpy.context) == b
    with ctx.temp_override(active_object=sketch, selected_objects=[a, b]):
        with pytest.raises(InputError, match="No armature"):
            resolve_armature(bpy.context)
    with ctx.temp_override(active_object=a, selected_objects=[a, b]):
        assert resolve_armature(bpy.context) == a
        ctx.scene.gesture_pose.armature = b
        assert resolve_armature(bpy.context) == b
        assert resolve_armature(bpy.context, "A") == a
        with pytest.raises(InputError, match="must be an armature"):
            resolve_armature(bpy.context, sketch.name)
        with pytest.raises(InputError, match="No object named"):
            resolve_armature(bpy.context, "Missing")


def test_resolve_sketch_order(registered):
    from gesture_pose.blender.operator_utils import resolve_sketch

    ctx = bpy.context
    rig = build_armature(CHAIN)
    with pytest.raises(InputError, match="No sketch"):
        resolve_sketch(ctx)
    first = add_grease_pencil([np.zeros((2, 3))], name="First")
    assert resolve_sketch(ctx) == first  # the only one in the scene
    second = add_grease_pencil([np.zeros((2, 3))], name="Second")
    with ctx.temp_override(active_object=rig, selected_objects=[rig]):
        with pytest.raises(InputError, match="2 Grease Pencil objects"):
            resolve_sketch(bpy.context)
        second.parent = rig
        assert resolve_sketch(bpy.context, armature=rig) == second
    with ctx.temp_override(active_object=rig, selected_objects=[rig, first]):
        assert resolve_sketch(bpy.context) == first
    with ctx.temp_override(active_object=second, selected_objects=[first]):
        assert resolve_sketch(bpy.context) == second
        ctx.scene.gesture_pose.sketch = first
        assert resolve_sketch(bpy.context) == first
    curve = link(bpy.data.objects.new("Curve", bpy.data.curves.new("Curve", "CURVE")))
    assert resolve_sketch(ctx, "Curve") == curve
    with pytest.raises(InputError, match="must be a Grease Pencil or curve"):
        resolve_sketch(ctx, rig.name)


def test_operator_mixin_reports_errors_and_changes_nothing(registered, capsys):
    from gesture_pose.blender.operator_utils import (
        GesturePoseOperatorMixin,
        nothing_to_do,
        report_result,
        resolve_armature,
    )

    class GESTUREPOSE_OT_test_rename(GesturePoseOperatorMixin, bpy.types.Operator):
        bl_idname = "gesture_pose.test_rename"
        bl_label = "Test Rename"
        mode: bpy.props.StringProperty()

        def run(self, context):
            rig = resolve_armature(context)
            if self.mode == "skip":
                return nothing_to_do(self, "no strokes")
            rig.name = "Renamed"
            report_result(self, "renamed")
            return {"FINISHED"}

    bpy.utils.register_class(GESTUREPOSE_OT_test_rename)
    try:
        with pytest.raises(RuntimeError, match="No armature: select"):
            bpy.ops.gesture_pose.test_rename()
        rig = build_armature(CHAIN)
        with bpy.context.temp_override(active_object=rig, selected_objects=[rig]):
            assert bpy.ops.gesture_pose.test_rename(mode="skip") == {"CANCELLED"}
            assert rig.name == "Rig"
            assert bpy.ops.gesture_pose.test_rename() == {"FINISHED"}
        assert rig.name == "Renamed"
        out = capsys.readouterr().out
        assert "Nothing to do: no strokes" in out and "renamed" in out
    finally:
        bpy.utils.unregister_class(GESTUREPOSE_OT_test_rename)


def test_camera_from_context_uses_the_3d_view(bpy_blank):
    from types import SimpleNamespace

    cam = add_camera((0.0, -6.0, 1.0), (0.0, 0.0, 1.0))
    window = cam.calc_matrix_camera(bpy.context.evaluated_depsgraph_get(), x=400, y=300)
    rv3d = _RegionView3D(cam.matrix_world.normalized().inverted(), window, True)
    main, sidebar = _Region(400, 300), _Region(80, 300, "UI")
    area = SimpleNamespace(type="VIEW_3D", regions=[sidebar, _Region(10, 10), main],
                           spaces=SimpleNamespace(active=SimpleNamespace(region_3d=rv3d)))
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 1000, 1000
    for region, data in ((main, rv3d), (sidebar, None)):
        ctx = SimpleNamespace(area=area, region=region, region_data=data, scene=scene)
        camera = camera_from_context(ctx)
        assert (camera.width, camera.height) == (400, 300)
        np.testing.assert_allclose(camera.projection_matrix, np.array(window), atol=1e-7)


# -- bones posed by constraints or drivers ----------------------------------------------

#: A straight chain up the z axis: a -> b -> c -> d.
CHAIN_ROWS = [(n, (0, 0, k), (0, 0, k + 1), p, p is not None, 0.0)
              for k, (n, p) in enumerate([("a", None), ("b", "a"), ("c", "b"), ("d", "c")])]


def _rotation_overridden(rig) -> dict[str, str]:
    from gesture_pose.blender.constraints import overrides

    names = [b.name for b in rig.pose.bones]
    return {n: why for n, why in zip(names, overrides(rig, names).rotation, strict=True)
            if why}


@pytest.mark.parametrize(("count", "use_tail", "expected"), [
    (2, True, {"d", "c"}), (2, False, {"c", "b"}), (0, True, {"a", "b", "c", "d"}),
    (1, True, {"d"})])
def test_an_ik_constraint_takes_over_its_chain(bpy_blank, count, use_tail, expected):
    rig = build_armature(CHAIN_ROWS)
    constrain(rig, "d", "IK", target=add_empty(), chain_count=count, use_tail=use_tail)
    found = _rotation_overridden(rig)
    assert set(found) == expected
    assert all(why == "the IK constraint 'IK' on 'd'" for why in found.values())


def test_constraints_that_do_not_set_rotation_or_do_not_act_are_ignored(bpy_blank):
    from gesture_pose.blender.constraints import overrides

    rig = build_armature(CHAIN_ROWS)
    target = add_empty()
    constrain(rig, "a", "IK")  # targetless: Blender's Auto IK holds the chain as posed
    constrain(rig, "b", "COPY_ROTATION", target=target, mute=True)
    constrain(rig, "b", "DAMPED_TRACK", target=target, influence=0.0)
    constrain(rig, "c", "COPY_ROTATION")  # no target: invalid, not evaluated
    constrain(rig, "c", "LIMIT_ROTATION", use_limit_x=True)
    constrain(rig, "c", "COPY_SCALE", target=target)
    constrain(rig, "a", "COPY_ROTATION", target=target, mix_mode="ADD")  # an offset
    constrain(rig, "a", "CHILD_OF", target=target)  # a parent: the keys still show
    constrain(rig, "d", "COPY_LOCATION", target=target)
    constrain(rig, "d", "COPY_TRANSFORMS", target=target, mix_mode="AFTER_FULL")
    assert _rotation_overridden(rig) == {}
    found = overrides(rig, ["d", "c"])
    assert found.location == ("its constraint 'Copy Location'", "")
    # Enabled again (or given its target), the same constraints take over.
    rig.pose.bones["b"].constraints["Copy Rotation"].mute = False
    rig.pose.bones["c"].constraints["Copy Rotation"].target = target
    assert _rotation_overridden(rig) == {"b": "its constraint 'Copy Rotation'",
                                         "c": "its constraint 'Copy Rotation'"}


@pytest.mark.parametrize(("kind", "settings"), [
    ("COPY_ROTATION", {"mix_mode": "REPLACE"}), ("COPY_ROTATION", {"mix_mode": "ADD"}),
    ("COPY_ROTATION", {"mix_mode": "BEFORE"}), ("COPY_TRANSFORMS", {"mix_mode": "REPLACE"}),
    ("COPY_TRANSFORMS", {"mix_mode": "AFTER_FULL"}), ("CHILD_OF", {}), ("ARMATURE", {}),
    ("DAMPED_TRACK", {}), ("TRACK_TO", {}), ("LOCKED_TRACK", {}), ("STRETCH_TO", {}),
    ("LIMIT_ROTATION", {"use_limit_x": True, "min_x": -1.0, "max_x": 1.0,
                        "owner_space": "LOCAL"}),
    ("IK", {"chain_count": 2}), ("IK", {"chain_count": 2, "pole": True}),
    ("TRANSFORM", {"map_to": "ROTATION", "mix_mode_rot": "REPLACE"}),
    ("TRANSFORM", {"map_to": "ROTATION", "mix_mode_rot": "ADD"}), ("COPY_LOCATION", {})])
def test_a_constraint_counts_exactly_when_blender_undoes_a_keyed_turn(bpy_blank, kind,
                                                                       settings):
    """Blender's own evaluation decides: bone 'c' is turned 30 degrees about its x and
    about its z axis; a constraint counts when the evaluated bone does not follow one of
    the turns (within 15 degrees). The aiming constraints leave the twist about the aimed
    axis, Locked Track all but the turn about its locked axis: they count, as the solved
    rotation would not show."""
    rig = build_armature(CHAIN_ROWS)
    target = add_empty()
    target.location = (0.5, -0.7, 4.0)
    bone = "d" if kind == "IK" else "c"
    c = rig.pose.bones[bone].constraints.new(kind)
    if kind == "ARMATURE":
        slot = c.targets.new()
        slot.target, slot.subtarget = rig, "a"
    elif kind != "LIMIT_ROTATION":
        c.target = target
    for key, value in settings.items():
        if key == "pole":
            c.pole_target = add_empty("Pole")
            c.pole_target.location = (0.0, -2.0, 2.0)
        else:
            setattr(c, key, value)
    assert c.is_valid
    pb = rig.pose.bones["c"]
    followed = []
    for axis in ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)):
        pb.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
        bpy.context.view_layer.update()
        before = np.array(pb.matrix)[:3, :3]
        pb.rotation_quaternion = Quaternion(axis, np.radians(30.0))
        bpy.context.view_layer.update()
        turn = before.T @ np.array(pb.matrix)[:3, :3]
        followed.append(np.degrees(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1, 1))))
    assert ("c" in _rotation_overridden(rig)) == (min(followed) < 15.0), followed


def test_a_driver_counts_on_the_channel_of_the_bones_rotation_mode(bpy_blank):
    rig = build_armature(CHAIN_ROWS)
    fc = rig.pose.bones["b"].driver_add("rotation_euler", 0)
    fc.driver.type = "SCRIPTED"
    fc.driver.expression = "0.5"
    assert _rotation_overridden(rig) == {}  # the bone turns by its quaternion
    rig.pose.bones["b"].rotation_mode = "XYZ"
    assert _rotation_overridden(rig) == {"b": "a driver on its rotation_euler"}
    fc.mute = True
    assert _rotation_overridden(rig) == {}


def test_writing_constrained_bones_is_refused_before_anything_is_written(bpy_blank):
    from gesture_pose.blender.write_pose import apply_pose
    from gesture_pose.core.skeleton import Pose

    rig = build_armature(CHAIN_ROWS)
    constrain(rig, "c", "DAMPED_TRACK", target=add_empty())
    data = read_armature(rig)
    turn = np.array(Quaternion((1.0, 0.0, 0.0), 0.4).to_matrix())
    rotations = np.array(data.pose.rotations)
    rotations[[1, 2]] = turn
    pose = Pose(rotations, np.array(data.pose.translations))
    before = [tuple(pb.rotation_quaternion) for pb in rig.pose.bones]
    with pytest.raises(InputError, match=r"Nothing was written: 'c' \(its constraint "
                                         r"'Damped Track'\) is posed by constraints"):
        apply_pose(rig, data, pose)
    assert [tuple(pb.rotation_quaternion) for pb in rig.pose.bones] == before
    assert rig.animation_data is None or rig.animation_data.action is None
    # Only what is written counts: the free bone 'b' alone is written and keyed.
    assert apply_pose(rig, data, pose, bones=["b"]) == ["b"]


def test_a_bone_renamed_since_the_read_stops_the_write_before_it_starts(bpy_blank):
    from gesture_pose.blender.write_pose import apply_pose
    from gesture_pose.core.skeleton import Pose

    rig = build_armature(CHAIN_ROWS)
    data = read_armature(rig)
    rotations = np.array(data.pose.rotations)
    rotations[[1, 2]] = np.array(Quaternion((1.0, 0.0, 0.0), 0.4).to_matrix())
    rig.data.bones["c"].name = "c2"
    with pytest.raises(InputError, match="Bone 'c' no longer exists in 'Rig'"):
        apply_pose(rig, data, Pose(rotations, np.array(data.pose.translations)))
    assert tuple(rig.pose.bones["b"].rotation_quaternion) == (1.0, 0.0, 0.0, 0.0)
    assert rig.animation_data is None or rig.animation_data.action is None


def test_a_generated_rigify_rig_is_named_in_the_refusal(bpy_blank):
    """Rigify's DEF- bones along the spine and limbs copy its tweak controls: they are
    refused, and the message says the rig is a generated Rigify rig."""
    import addon_utils

    from gesture_pose.blender.constraints import check_writable

    addon_utils.enable("rigify", default_set=True)
    try:
        import rigify

        rigify.register_rig_parameters()  # the module's enable leaves them out
        bpy.ops.object.armature_basic_human_metarig_add()
        bpy.ops.pose.rigify_generate()
        rig = bpy.context.active_object
        # The spine's and the limbs' deform bones (shoulders, pelvis sides and breasts
        # hang from ORG bones unconstrained: keys on them show).
        deform = [b.name for b in rig.data.bones if b.use_deform
                  and any(k in b.name for k in ("spine", "thigh", "shin", "upper_arm",
                                                "forearm", "hand", "foot"))]
        found = _rotation_overridden(rig)
        assert len(deform) >= 20 and all(n in found for n in deform)
        with pytest.raises(InputError, match=r"generated Rigify rig.*'DEF-spine' \(its "
                                             r"constraint 'Copy Transforms'\)"):
            check_writable(rig, deform)
        free = [n for n in ("upper_arm_fk.L", "forearm_fk.L") if n in rig.pose.bones]
        assert free and not any(n in found for n in free)
        check_writable(rig, free)  # its FK controls are not posed by constraints
    finally:
        addon_utils.disable("rigify", default_set=True)
