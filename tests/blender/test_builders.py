"""The sample-scene builders build what they promise (headless bpy)."""

from __future__ import annotations

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from sample_scenes import builders, make_scenes  # noqa: E402

pytestmark = pytest.mark.blender

BUILDERS = {
    "humanoid": builders.build_humanoid,
    "tentacle": builders.build_tentacle,
    "quadruped": builders.build_quadruped,
}
EXAMPLES = {
    "humanoid": builders.example_strokes_humanoid,
    "tentacle": builders.example_strokes_tentacle,
    "quadruped": builders.example_strokes_quadruped,
}
# First bone of each example stroke's chain, in order.
EXAMPLE_STARTS = {
    "humanoid": ["upper_arm.L", "thigh.R"],
    "tentacle": ["tentacle.000"],
    "quadruped": ["tail.000", "upper_arm.L"],
}


def chain_depth(bone) -> int:
    """Number of bones from ``bone`` up to its root, inclusive."""
    depth = 0
    while bone is not None:
        depth, bone = depth + 1, bone.parent
    return depth


def vertex_weights(mesh_obj) -> np.ndarray:
    """Dense (n_vertices, n_groups) weight matrix."""
    w = np.zeros((len(mesh_obj.data.vertices), len(mesh_obj.vertex_groups)))
    for v in mesh_obj.data.vertices:
        for g in v.groups:
            w[v.index, g.group] = g.weight
    return w


def roll_of(bone) -> float:
    """Bone roll in radians."""
    return bpy.types.Bone.AxisRollFromMatrix(bone.matrix_local.to_3x3())[1]


def test_humanoid_bones(blank_blender):
    arm, mesh = builders.build_humanoid()
    bones = arm.data.bones
    assert 22 <= len(bones) <= 26
    assert all(b.use_deform for b in bones)
    for side in ("L", "R"):
        for name in ("shoulder", "upper_arm", "forearm", "hand", "thigh", "shin", "foot",
                     "toe"):
            assert f"{name}.{side}" in bones
        assert bones[f"forearm.{side}"].use_connect
        assert bones[f"shin.{side}"].use_connect
        assert not bones[f"shoulder.{side}"].use_connect
        assert not bones[f"thigh.{side}"].use_connect
    for name in ("pelvis", "spine", "spine.001", "chest", "neck", "head"):
        assert name in bones
    assert bones["pelvis"].parent is None
    assert bones["chest"].use_connect and bones["head"].use_connect
    # Left is +X and mirrored on the right; rolls mirror too.
    assert bones["hand.L"].head_local.x > 0.4
    assert bones["hand.R"].head_local.x == pytest.approx(-bones["hand.L"].head_local.x)
    assert roll_of(bones["upper_arm.R"]) == pytest.approx(-roll_of(bones["upper_arm.L"]))
    # Rolls are not zero for most bones (code ignoring roll must break).
    assert sum(abs(roll_of(b)) > 0.3 for b in bones) >= 18
    # Standing on z=0, about 1.8 m tall, toes pointing at -Y (the front).
    zs = np.array([v.co.z for v in mesh.data.vertices])
    assert zs.min() == pytest.approx(0.0, abs=0.03)
    assert zs.max() == pytest.approx(1.8, abs=0.05)
    assert bones["toe.L"].tail_local.y < bones["toe.L"].head_local.y < 0.0


def test_humanoid_location(blank_blender):
    arm, mesh = builders.build_humanoid(name="Other", location=(2.0, 1.0, 0.5))
    assert arm.name == "Other" and mesh.name == "Other_Mesh"
    joints = builders.joint_positions(arm)
    assert np.allclose(joints["pelvis"][0], (2.0, 1.0, 1.43), atol=1e-5)


def test_tentacle_chain(blank_blender):
    arm, mesh = builders.build_tentacle()
    bones = arm.data.bones
    assert len(bones) == 48
    assert max(chain_depth(b) for b in bones) >= 45
    assert bones["tentacle.000"].parent.name == "body"
    lengths = [bones[f"tentacle.{i:03d}"].length for i in range(47)]
    assert lengths[-1] < lengths[0]  # tapering
    assert len({round(roll_of(b), 3) for b in bones}) > 20  # twisting rolls
    arm2, _ = builders.build_tentacle(name="Short", n_joints=20)
    assert len(arm2.data.bones) == 20


def test_quadruped_bones(blank_blender):
    arm, mesh = builders.build_quadruped()
    bones = arm.data.bones
    assert 22 <= len(bones) <= 32
    assert {"hips", "spine", "chest", "neck", "head", "tail.000", "tail.005"} <= set(bones.keys())
    # Four legs: chains of 3-4 bones hanging below the body, ending near the ground.
    leg_roots = [b for b in bones if b.parent and b.parent.name in ("chest", "hips")
                 and b.tail_local.z < b.head_local.z - 0.1]
    assert len(leg_roots) == 4
    for root in leg_roots:
        chain = [root]
        while chain[-1].children:
            chain.append(chain[-1].children[0])
        assert 3 <= len(chain) <= 4
        assert chain[-1].tail_local.z < 0.05
    assert chain_depth(bones["tail.005"]) == 7


@pytest.mark.parametrize("kind", sorted(BUILDERS))
def test_skin_weights(blank_blender, kind):
    arm, mesh = BUILDERS[kind]()
    assert mesh.parent == arm
    mods = [m for m in mesh.modifiers if m.type == 'ARMATURE']
    assert len(mods) == 1 and mods[0].object == arm
    assert 3000 <= len(mesh.data.vertices) <= 8000
    deform = {b.name for b in arm.data.bones if b.use_deform}
    assert {g.name for g in mesh.vertex_groups} == deform
    w = vertex_weights(mesh)
    assert np.allclose(w.sum(axis=1), 1.0, atol=1e-4)
    assert (w > 0.99).sum(axis=0).min() > 0  # every bone owns some vertices outright
    assert ((w > 0.05) & (w < 0.95)).any(axis=1).sum() > 0.1 * len(w)  # smooth joints


def test_skin_follows_pose(blank_blender):
    arm, mesh = builders.build_humanoid()
    group = mesh.vertex_groups["hand.R"].index
    hand = [v.index for v in mesh.data.vertices
            if any(g.group == group and g.weight > 0.99 for g in v.groups)]
    builders.pose_humanoid(arm, "wave")
    deps = bpy.context.evaluated_depsgraph_get()
    posed = mesh.evaluated_get(deps).to_mesh()
    zs = np.array([posed.vertices[i].co.z for i in hand])
    mesh.evaluated_get(deps).to_mesh_clear()
    head_top = builders.joint_positions(arm)["head"][1][2]
    assert zs.mean() > head_top  # the waving hand is above the head


def test_camera_frames_character(blank_blender):
    arm, _ = builders.build_humanoid()
    cam = builders.add_camera(arm, resolution=(640, 480), lens=35.0)
    scene = bpy.context.scene
    assert scene.camera == cam
    assert (scene.render.resolution_x, scene.render.resolution_y) == (640, 480)
    assert cam.matrix_world.col[3].y < -1.0  # front view: camera at -Y
    joints = np.array([p for hv in builders.joint_positions(arm).values() for p in hv])
    px = builders.project_to_pixels(joints, cam)
    assert (px > 0).all() and (px[:, 0] < 640).all() and (px[:, 1] < 480).all()
    assert np.ptp(px[:, 1]) > 0.6 * 480  # fills most of the frame height


def test_ortho_camera_and_point_target(blank_blender):
    arm, _ = builders.build_quadruped()
    cam = builders.add_camera(arm, direction=(1.0, 0.0, 0.0), ortho=True)
    assert cam.data.type == 'ORTHO'
    px = builders.project_to_pixels(np.array([b.head_local for b in arm.data.bones]), cam)
    assert (px > 0).all() and (px < 960).all()
    cam2 = builders.add_camera((0.0, 0.0, 1.0), direction=(0.0, 0.0, 1.0), distance=4.0,
                               name="Top")
    assert bpy.context.scene.camera == cam2
    assert np.allclose(cam2.matrix_world.col[3][:3], (0.0, 0.0, 5.0))
    assert np.allclose(builders.project_to_pixels(np.array([[0.0, 0.0, 1.0]]), cam2),
                       [[480.0, 480.0]], atol=1e-3)


@pytest.mark.parametrize("ortho", [False, True])
def test_strokes_through_keeps_pixels(blank_blender, ortho):
    arm, _ = builders.build_humanoid()
    cam = builders.add_camera(arm, direction=(0.3, -1.0, 0.2), ortho=ortho)
    rng = np.random.default_rng(0)
    lines = [rng.uniform((-0.5, -0.5, 0.2), (0.5, 0.5, 1.6), size=(n, 3)) for n in (5, 9)]
    depth_point = np.array([0.1, 0.2, 1.0])
    moved = builders.strokes_through(lines, cam, depth_point)
    axis = -np.array(cam.matrix_world.col[2][:3])
    for a, b in zip(lines, moved, strict=True):
        assert b.shape == a.shape
        assert np.allclose(builders.project_to_pixels(a, cam),
                           builders.project_to_pixels(b, cam), atol=1e-3)
        assert np.allclose((b - depth_point) @ axis, 0.0, atol=1e-6)


def test_grease_pencil_holds_strokes(blank_blender):
    bpy.context.scene.frame_current = 7
    strokes = [np.column_stack([np.linspace(0, 1, n), np.zeros(n), np.full(n, 0.5)])
               for n in (4, 11)]
    gp = builders.add_grease_pencil("Sketch", strokes, layer="Ink")
    assert gp.type == 'GREASEPENCIL' and gp.name in bpy.context.scene.objects
    layer = gp.data.layers.active
    assert layer.name == "Ink"
    frame = layer.current_frame()
    assert frame.frame_number == 7
    drawing = frame.drawing
    assert len(drawing.strokes) == 2
    assert [len(s.points) for s in drawing.strokes] == [4, 11]
    radius = np.empty(15, dtype=np.float32)
    drawing.attributes["radius"].data.foreach_get("value", radius)
    assert np.allclose(radius, 0.01)
    opacity = np.empty(15, dtype=np.float32)
    drawing.attributes["opacity"].data.foreach_get("value", opacity)
    assert np.allclose(opacity, 1.0)
    got = builders.read_strokes(gp)
    assert all(np.allclose(a, b, atol=1e-6) for a, b in zip(got, strokes, strict=True))

    # Appending keeps the old strokes and attributes, even with a moved object.
    gp.location = (1.0, 2.0, 3.0)
    bpy.context.view_layer.update()
    extra = [np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.0, 1.0]])]
    builders.add_strokes(gp, extra, radius=0.02)
    drawing = gp.data.layers.active.current_frame().drawing
    assert [len(s.points) for s in drawing.strokes] == [4, 11, 3]
    radius = np.empty(18, dtype=np.float32)
    drawing.attributes["radius"].data.foreach_get("value", radius)
    assert np.allclose(radius[:15], 0.01) and np.allclose(radius[15:], 0.02)
    got = builders.read_strokes(gp)
    assert np.allclose(got[2], extra[0], atol=1e-6)
    assert np.allclose(got[0], strokes[0] + (1.0, 2.0, 3.0), atol=1e-6)


@pytest.mark.parametrize("kind", sorted(BUILDERS))
def test_example_strokes_start_at_chain(blank_blender, kind):
    arm, _ = BUILDERS[kind]()
    direction = (1.0, -0.35, 0.15) if kind == "quadruped" else (0.0, -1.0, 0.0)
    cam = builders.add_camera(arm, direction=direction, margin=1.5)
    rest = builders.joint_positions(arm)
    strokes = EXAMPLES[kind](arm, cam)
    assert len(strokes) == len(EXAMPLE_STARTS[kind])
    # The pose is back at rest.
    after = builders.joint_positions(arm)
    assert all(np.allclose(after[n][1], rest[n][1], atol=1e-6) for n in rest)
    axis = -np.array(cam.matrix_world.col[2][:3])
    for stroke, bone in zip(strokes, EXAMPLE_STARTS[kind], strict=True):
        px = builders.project_to_pixels(stroke, cam)
        start = builders.project_to_pixels(rest[bone][0][None], cam)[0]
        assert np.linalg.norm(px[0] - start) < 3.0
        steps = np.linalg.norm(np.diff(px, axis=0), axis=1)
        assert len(stroke) > 30 and steps.max() < 4.0
        assert np.ptp(px, axis=0).max() > 100.0  # a real gesture, not a dot
        assert (px >= 0).all() and (px[:, 0] <= 960).all() and (px[:, 1] <= 960).all()
        # On the plane through the chain's start joint, facing the camera.
        assert np.allclose((stroke - rest[bone][0]) @ axis, 0.0, atol=1e-6)


def test_tentacle_stroke_curls(blank_blender):
    arm, _ = builders.build_tentacle()
    cam = builders.add_camera(arm, margin=1.6)
    (stroke,) = builders.example_strokes_tentacle(arm, cam)
    px = builders.project_to_pixels(stroke, cam)
    d = np.diff(px, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    turn = np.diff(heading)
    assert (turn > 0.01).any() and (turn < -0.01).any()  # bends both ways: an S
    assert abs(heading.max() - heading.min()) > math.pi  # and it curls


@pytest.mark.parametrize("pose", sorted(builders.HUMANOID_POSES))
def test_pose_humanoid(blank_blender, pose):
    arm, _ = builders.build_humanoid()
    rest = builders.joint_positions(arm)
    builders.pose_humanoid(arm, pose)
    posed = builders.joint_positions(arm)
    moved = [n for n in rest if not np.allclose(rest[n][1], posed[n][1], atol=1e-4)]
    assert moved
    for name in builders.HUMANOID_POSES[pose]:
        pb = arm.pose.bones[name]
        assert pb.rotation_mode == 'QUATERNION'
        assert abs(pb.rotation_quaternion.w) < 0.9999
    # Bone lengths are preserved.
    for n in rest:
        assert np.linalg.norm(posed[n][1] - posed[n][0]) == pytest.approx(
            np.linalg.norm(rest[n][1] - rest[n][0]), abs=1e-5)
    builders.pose_humanoid(arm, "rest")
    back = builders.joint_positions(arm)
    assert all(np.allclose(back[n][1], rest[n][1], atol=1e-6) for n in rest)


def test_named_poses_do_what_they_say(blank_blender):
    arm, _ = builders.build_humanoid()
    rest = builders.joint_positions(arm)
    builders.pose_humanoid(arm, "wave")
    j = builders.joint_positions(arm)
    assert j["hand.R"][0][2] > rest["head"][1][2] - 0.1
    assert np.allclose(j["hand.L"][0], rest["hand.L"][0], atol=1e-6)
    builders.pose_humanoid(arm, "step")
    j = builders.joint_positions(arm)
    assert j["shin.L"][0][1] < rest["shin.L"][0][1] - 0.15  # left knee forward (-Y)
    builders.pose_humanoid(arm, "crouch")
    j = builders.joint_positions(arm)
    assert j["pelvis"][0][2] < rest["pelvis"][0][2] - 0.3
    assert j["shin.L"][1][2] == pytest.approx(rest["shin.L"][1][2], abs=0.05)  # feet down
    builders.pose_humanoid(arm, "reach")
    j = builders.joint_positions(arm)
    assert j["hand.L"][0][1] < -0.35 and j["hand.R"][0][1] < -0.35
    with pytest.raises(KeyError):
        builders.pose_humanoid(arm, "moonwalk")


@pytest.mark.parametrize("mode", ["XYZ", "ZXY", "AXIS_ANGLE"])
def test_set_rotation_modes_keeps_pose(blank_blender, mode):
    arm, _ = builders.build_humanoid()
    builders.pose_humanoid(arm, "wave")
    before = builders.joint_positions(arm)
    names = ["upper_arm.R", "forearm.R", "hand.R", "head"]
    builders.set_rotation_modes(arm, {n: mode for n in names})
    assert all(arm.pose.bones[n].rotation_mode == mode for n in names)
    after = builders.joint_positions(arm)
    assert all(np.allclose(before[n][1], after[n][1], atol=1e-5) for n in before)
    # Posing writes in each bone's current mode.
    builders.pose_humanoid(arm, "rest")
    builders.pose_humanoid(arm, "wave")
    again = builders.joint_positions(arm)
    assert all(np.allclose(before[n][1], again[n][1], atol=1e-5) for n in before)


@pytest.mark.parametrize("recipe", make_scenes.RECIPES, ids=lambda r: r.name)
def test_make_scenes_files(blank_blender, recipe, tmp_path):
    path = make_scenes.save_scene(recipe, tmp_path)
    assert path.stat().st_size < 2 * 1024 * 1024
    bpy.ops.wm.open_mainfile(filepath=str(path))
    scene = bpy.context.scene
    assert scene["gesture_pose_sample"] == recipe.name
    assert scene.camera is not None and scene.camera.type == 'CAMERA'
    assert scene.frame_current == 1
    assert {o.type for o in scene.objects} >= {'ARMATURE', 'MESH', 'LIGHT', 'CAMERA'}
    sketch = scene.objects["Sketch"]
    assert sketch.type == 'GREASEPENCIL'
    strokes = builders.read_strokes(sketch)
    assert len(strokes) == len(EXAMPLE_STARTS[recipe.name])
    arm = next(o for o in scene.objects if o.type == 'ARMATURE')
    joints = builders.joint_positions(arm)
    w, h = recipe.resolution
    for stroke, bone in zip(strokes, EXAMPLE_STARTS[recipe.name], strict=True):
        px = builders.project_to_pixels(stroke, scene.camera)
        assert (px > 0).all() and (px[:, 0] < w).all() and (px[:, 1] < h).all()
        start = builders.project_to_pixels(joints[bone][0][None], scene.camera)[0]
        assert np.linalg.norm(px[0] - start) < 3.0
