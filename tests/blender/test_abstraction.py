"""Headless tests of Pose from Abstraction and Draw-over on the sample humanoid."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from gesture_pose.blender.read_view import camera_from_object  # noqa: E402
from gesture_pose.blender.write_pose import keyed_frames  # noqa: E402
from sample_scenes import abstraction_builders as ab  # noqa: E402
from sample_scenes import builders  # noqa: E402

pytestmark = pytest.mark.blender


def _bone_dirs(arm) -> dict[str, np.ndarray]:
    bpy.context.view_layer.update()
    out = {}
    for pb in arm.pose.bones:
        d = np.array(arm.matrix_world @ pb.tail) - np.array(arm.matrix_world @ pb.head)
        out[pb.name] = d / np.linalg.norm(d)
    return out


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def _mean_px_distance(polylines, strokes) -> float:
    """Mean distance (pixels) from the abstraction's points to the nearest stroke segment."""
    cam = camera_from_object(bpy.context.scene.camera, bpy.context.scene)
    dense = np.concatenate([np.linspace(s[:-1], s[1:], 20).reshape(-1, 3) for s in strokes])
    tgt = cam.project(dense)
    pts = cam.project(np.concatenate(polylines))
    d = np.linalg.norm(pts[:, None, :] - tgt[None], axis=2).min(axis=1)
    return float(d.mean())


@pytest.fixture
def humanoid(registered):
    arm, mesh = builders.build_humanoid()
    stick, outline = ab.add_abstractions(arm, mesh)
    builders.add_camera(arm, resolution=(960, 960), margin=1.5)
    return arm, mesh, stick, outline


def _run(op, arm, **kwargs):
    with bpy.context.temp_override(active_object=arm, object=arm, selected_objects=[arm]):
        return op(**kwargs)


def _image_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two world directions as seen by the scene camera, degrees."""
    cam = camera_from_object(bpy.context.scene.camera, bpy.context.scene)
    centre = np.array([0.0, 0.0, 1.0])
    da, db = (cam.project(np.stack([centre, centre + 0.1 * v]))[1] - cam.project(
        centre[None])[0] for v in (a, b))
    cos = da @ db / np.linalg.norm(da) / np.linalg.norm(db)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


@pytest.mark.parametrize("abstraction", ["Stick Figure", "Outline"])
def test_redraw_posing_recovers_known_pose(humanoid, abstraction: str) -> None:
    arm, _, stick, outline = humanoid
    obj = stick if abstraction == "Stick Figure" else outline
    builders.pose_humanoid(arm, "raise_left_arm")
    want = _bone_dirs(arm)
    rng = np.random.default_rng(0)
    strokes = [p + rng.normal(scale=0.002, size=p.shape) * [1, 0, 1]
               for p in ab.evaluated_polylines(obj)]
    builders.pose_humanoid(arm, "rest")
    builders.add_grease_pencil("Sketch", strokes)
    before = _mean_px_distance(ab.evaluated_polylines(obj), strokes)
    # Outline points blend several bones and slide along the curve: the documented
    # choice for them is in-order, then closest point.
    procedure = "IN_ORDER" if abstraction == "Stick Figure" else "IN_ORDER_CLOSEST"
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                  abstraction=abstraction, correspondence=procedure)
    assert result == {"FINISHED"}
    got = _bone_dirs(arm)
    after = _mean_px_distance(ab.evaluated_polylines(obj), strokes)
    assert before > 10.0 and after < 2.0
    for name in ("upper_arm.L", "forearm.L"):  # as drawn: depth is not in the strokes
        assert _image_angle(got[name], want[name]) < 4.0, name
    assert keyed_frames(arm, "upper_arm.L", "rotation_quaternion") or keyed_frames(
        arm, "upper_arm.L", "rotation_euler")


def test_closest_point_and_order_options(humanoid) -> None:
    arm, _, stick, _ = humanoid
    builders.apply_rotations(arm, {"forearm.L": ((0.0, 1.0, 0.0), -25.0)})
    strokes = ab.evaluated_polylines(stick)
    builders.pose_humanoid(arm, "rest")
    builders.add_grease_pencil("Sketch", strokes)
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                  abstraction="Stick Figure", correspondence="CLOSEST", assignment="ORDER",
                  insert_keys=False)
    assert result == {"FINISHED"}
    assert _mean_px_distance(ab.evaluated_polylines(stick), strokes) < 2.0
    assert not keyed_frames(arm, "upper_arm.L", "rotation_quaternion")


def _bone_line(arm, name: str) -> tuple[np.ndarray, np.ndarray]:
    """World rest head and tail of a bone."""
    m = np.array(arm.matrix_world)
    bone = arm.data.bones[name]
    return tuple(m[:3, :3] @ np.array(v) + m[:3, 3] for v in (bone.head_local,
                                                                bone.tail_local))


def _bone_motion(arm, name: str) -> np.ndarray:
    pb = arm.pose.bones[name]
    return np.array(arm.matrix_world @ pb.matrix @ pb.bone.matrix_local.inverted()
                    @ arm.matrix_world.inverted())


def test_drawover_moves_the_forearm(humanoid) -> None:
    arm, mesh, _, _ = humanoid
    head, tail = _bone_line(arm, "forearm.L")
    source = head + np.linspace(0.15, 0.9, 25)[:, None] * (tail - head) + [0, -0.2, 0]
    builders.apply_rotations(arm, {"forearm.L": ((0.0, 1.0, 0.0), -50.0)})
    bpy.context.view_layer.update()
    motion = _bone_motion(arm, "forearm.L")
    want = _bone_dirs(arm)["forearm.L"]
    target = source @ motion[:3, :3].T + motion[:3, 3]
    builders.pose_humanoid(arm, "rest")
    rest = _bone_dirs(arm)
    sketch = builders.add_grease_pencil("Sketch", [source, target])
    result = _run(bpy.ops.gesture_pose.drawover, arm, sketch="Sketch", keep_source=True)
    assert result == {"FINISHED"}
    got = _bone_dirs(arm)
    assert _image_angle(got["forearm.L"], want) < 5.0
    assert _angle(got["thigh.R"], rest["thigh.R"]) < 1.0
    carried = builders.read_strokes(sketch)
    assert len(carried) == 1  # the source, carried to the new pose
    # It lies on the posed forearm (on its surface: within the arm's radius of the bone)...
    pb = arm.pose.bones["forearm.L"]
    h, t = (np.array(arm.matrix_world @ v) for v in (pb.head, pb.tail))
    s = np.clip((carried[0] - h) @ (t - h) / ((t - h) @ (t - h)), 0.0, 1.0)
    off_bone = np.linalg.norm(carried[0] - (h + s[:, None] * (t - h)), axis=1)
    assert off_bone.max() < 0.06 and np.ptp(s) > 0.5
    # ...and is seen where the target was drawn.
    assert _mean_px_distance([carried[0]], [target]) < 3.0


def test_drawover_needs_a_stroke_on_the_character(humanoid) -> None:
    arm, _, _, _ = humanoid
    far = np.array([[5.0, 0.0, 5.0], [5.5, 0.0, 5.0]])
    builders.add_grease_pencil("Sketch", [far, far + [0, 0, 0.3]])
    with pytest.raises(RuntimeError, match="not over the character"):
        _run(bpy.ops.gesture_pose.drawover, arm, sketch="Sketch")


def _parent_to_bone(obj, arm, bone: str) -> None:
    world = obj.matrix_world.copy()
    obj.parent, obj.parent_type, obj.parent_bone = arm, "BONE", bone
    obj.matrix_world = world
    bpy.context.view_layer.update()


def test_curve_and_grease_pencil_abstractions_parented_to_bones(humanoid) -> None:
    arm, _, _, _ = humanoid
    coll = bpy.data.collections.new("Arm Lines")
    bpy.data.collections["Sketch Abstraction"].children.link(coll)
    lines = {}
    for bone_name in ("upper_arm.L", "forearm.L"):
        head, tail = _bone_line(arm, bone_name)
        lines[bone_name] = head + np.linspace(0.05, 0.95, 12)[:, None] * (tail - head)
    curve_data = bpy.data.curves.new("UpperLine", "CURVE")
    spline = curve_data.splines.new("POLY")
    spline.points.add(len(lines["upper_arm.L"]) - 1)
    for p, co in zip(spline.points, lines["upper_arm.L"], strict=True):
        p.co = (*co, 1.0)
    curve = bpy.data.objects.new("UpperLine", curve_data)
    coll.objects.link(curve)
    gp = builders.add_grease_pencil("ForeLine", [lines["forearm.L"]])
    bpy.context.scene.collection.objects.unlink(gp)
    coll.objects.link(gp)
    _parent_to_bone(curve, arm, "upper_arm.L")
    _parent_to_bone(gp, arm, "forearm.L")
    bpy.context.scene.gesture_pose_abstraction = coll
    builders.apply_rotations(arm, {"upper_arm.L": ((0.0, 1.0, 0.0), -40.0),
                                   "forearm.L": ((0.0, 1.0, 0.0), -30.0)})
    bpy.context.view_layer.update()
    want = _bone_dirs(arm)
    from gesture_pose.blender.abstraction_io import read_abstraction, resolve_abstraction
    from gesture_pose.blender.read_armature import read_armature

    objs = resolve_abstraction(bpy.context)
    assert [o.name for o in objs] == ["ForeLine", "UpperLine"]
    data = read_abstraction(objs, read_armature(arm), arm,
                            bpy.context.evaluated_depsgraph_get())
    strokes = [data.points[data.layout.curve(i)] for i in range(data.layout.n_curves)]
    builders.pose_humanoid(arm, "rest")
    builders.add_grease_pencil("Sketch", strokes)
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch")
    assert result == {"FINISHED"}
    got = _bone_dirs(arm)
    for name in ("upper_arm.L", "forearm.L"):
        assert _image_angle(got[name], want[name]) < 3.0, name


def test_sample_scene_saves_with_two_abstractions(registered, tmp_path) -> None:
    path = ab.save_abstraction_scene(tmp_path / "abstraction.blend")
    assert path.exists()
    bpy.ops.wm.open_mainfile(filepath=str(path))
    root = bpy.data.collections["Sketch Abstraction"]
    assert [c.name for c in root.children] == ["Stick Figure", "Outline"]
    assert len(bpy.data.objects["Sketch"].data.layers["Lines"].current_frame().drawing
               .strokes) == len(ab.STICK_CHAINS)
    arm = bpy.data.objects["Humanoid"]
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                  abstraction="Stick Figure", insert_keys=False)
    assert result == {"FINISHED"}


def test_ik_limits_bound_the_solution(humanoid) -> None:
    from gesture_pose.core.rotations import log_map

    arm, _, stick, _ = humanoid
    builders.apply_rotations(arm, {"forearm.L": ((0.0, 1.0, 0.0), -60.0)})
    bpy.context.view_layer.update()
    strokes = ab.evaluated_polylines(stick)
    builders.pose_humanoid(arm, "rest")
    pb = arm.pose.bones["forearm.L"]
    for axis in "xyz":
        setattr(pb, f"use_ik_limit_{axis}", True)
        setattr(pb, f"ik_min_{axis}", -0.3)
        setattr(pb, f"ik_max_{axis}", 0.3)
    builders.add_grease_pencil("Sketch", strokes)
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                  abstraction="Stick Figure", insert_keys=False)
    assert result == {"FINISHED"}
    theta = log_map(np.array(pb.matrix_basis.to_3x3()))
    assert np.abs(theta).max() <= 0.3 + 1e-4
    assert np.abs(theta).max() > 0.25  # pressed against the limit by the drawing


def test_free_scale_collection_scales_only_its_bones(humanoid) -> None:
    arm, _, stick, _ = humanoid
    coll = arm.data.collections.new("Free Scale")
    coll.assign(arm.data.bones["forearm.L"])
    arm.pose.bones["forearm.L"].scale = (1.3, 1.3, 1.3)
    bpy.context.view_layer.update()
    strokes = ab.evaluated_polylines(stick)
    arm.pose.bones["forearm.L"].scale = (1.0, 1.0, 1.0)
    builders.add_grease_pencil("Sketch", strokes)
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                  abstraction="Stick Figure", free_scales=True)
    assert result == {"FINISHED"}
    scales = {pb.name: pb.scale[0] for pb in arm.pose.bones}
    assert abs(scales["forearm.L"] - 1.3) < 0.02
    assert all(abs(v - 1.0) < 1e-6 for k, v in scales.items() if k != "forearm.L")
    assert keyed_frames(arm, "forearm.L", "scale")


def test_drawover_black_box_path(humanoid) -> None:
    arm, _, _, _ = humanoid
    pinned = arm.data.collections.new("Pinned")
    for b in arm.data.bones:
        if b.name not in ("upper_arm.L", "forearm.L"):
            pinned.assign(b)
    head, tail = _bone_line(arm, "forearm.L")
    source = head + np.linspace(0.15, 0.9, 20)[:, None] * (tail - head) + [0, -0.2, 0]
    builders.apply_rotations(arm, {"forearm.L": ((0.0, 1.0, 0.0), -40.0)})
    bpy.context.view_layer.update()
    motion = _bone_motion(arm, "forearm.L")
    want = _bone_dirs(arm)["forearm.L"]
    target = source @ motion[:3, :3].T + motion[:3, 3]
    builders.pose_humanoid(arm, "rest")
    sketch = builders.add_grease_pencil("Sketch", [source, target])
    result = _run(bpy.ops.gesture_pose.drawover, arm, sketch="Sketch", black_box=True,
                  representatives=60, max_iterations=15)
    assert result == {"FINISHED"}
    assert _image_angle(_bone_dirs(arm)["forearm.L"], want) < 5.0
    # By default the user's strokes are left as drawn.
    drawn = builders.read_strokes(sketch)
    assert len(drawn) == 2
    np.testing.assert_allclose(drawn[0], source, atol=1e-5)


def _snapshot(arm, sketch) -> tuple[dict, bool, list[np.ndarray]]:
    """Local pose of every bone, whether anything is keyed, and the sketch's strokes."""
    pose = {pb.name: np.array(pb.matrix_basis) for pb in arm.pose.bones}
    keyed = arm.animation_data is not None and arm.animation_data.action is not None
    return pose, keyed, builders.read_strokes(sketch)


def _assert_unchanged(arm, sketch, before) -> None:
    pose, keyed, strokes = _snapshot(arm, sketch)
    for name, m in before[0].items():
        np.testing.assert_allclose(pose[name], m, atol=1e-9, err_msg=name)
    assert keyed == before[1]
    assert len(strokes) == len(before[2])
    for a, b in zip(strokes, before[2], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)


def test_strokes_far_from_the_character_are_refused(humanoid) -> None:
    arm, _, stick, _ = humanoid
    builders.pose_humanoid(arm, "raise_left_arm")
    good = ab.evaluated_polylines(stick)
    builders.pose_humanoid(arm, "rest")
    far = [p + [5.0, 0.0, 0.0] for p in good]
    sketch = builders.add_grease_pencil("Sketch", far)
    before = _snapshot(arm, sketch)
    with pytest.raises(RuntimeError, match="far from the character"):
        _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
             abstraction="Stick Figure")
    _assert_unchanged(arm, sketch, before)
    # Good strokes and one far stroke drawn last: the far one is named, nothing changes.
    bpy.data.objects.remove(sketch)
    sketch = builders.add_grease_pencil("Sketch", good + [far[1]])
    before = _snapshot(arm, sketch)
    with pytest.raises(RuntimeError, match=r"stroke 6 of 6 \(the newest\)"):
        _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
             abstraction="Stick Figure", remove_used_strokes=True)
    _assert_unchanged(arm, sketch, before)


def test_drawover_target_far_from_the_character_is_refused(humanoid) -> None:
    arm, _, _, _ = humanoid
    head, tail = _bone_line(arm, "forearm.L")
    source = head + np.linspace(0.15, 0.9, 25)[:, None] * (tail - head) + [0, -0.2, 0]
    sketch = builders.add_grease_pencil("Sketch", [source, source + [5.0, 0.0, 0.0]])
    before = _snapshot(arm, sketch)
    with pytest.raises(RuntimeError, match="far from the character.*target stroke"):
        _run(bpy.ops.gesture_pose.drawover, arm, sketch="Sketch", keep_source=True)
    _assert_unchanged(arm, sketch, before)


UNTOUCHED = ("pelvis", "spine", "spine.001", "chest", "neck", "head", "shoulder.R",
             "upper_arm.R", "forearm.R", "hand.R", "thigh.L", "shin.L", "foot.L", "thigh.R",
             "shin.R", "foot.R")


def _keyed(arm, name: str) -> bool:
    return bool(keyed_frames(arm, name, "rotation_quaternion")
                or keyed_frames(arm, name, "rotation_euler"))


@pytest.mark.parametrize("abstraction", ["Stick Figure", "Outline"])
def test_redrawing_one_arm_leaves_the_rest_of_the_rig(humanoid, abstraction: str) -> None:
    arm, _, stick, outline = humanoid
    obj = stick if abstraction == "Stick Figure" else outline
    rest_lines = ab.evaluated_polylines(obj)
    builders.pose_humanoid(arm, "raise_left_arm")
    want = _bone_dirs(arm)
    lines = ab.evaluated_polylines(obj)
    builders.pose_humanoid(arm, "rest")
    rest = _bone_dirs(arm)
    moved = int(np.argmax([np.abs(a - b).max() for a, b in zip(lines, rest_lines,
                                                               strict=True)]))
    builders.add_grease_pencil("Sketch", [lines[moved]])  # only the left arm is redrawn
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                  abstraction=abstraction)
    assert result == {"FINISHED"}
    got = _bone_dirs(arm)
    for name in UNTOUCHED:
        assert _angle(got[name], rest[name]) < 1.0, name
        assert not _keyed(arm, name), name
    assert _keyed(arm, "upper_arm.L") and _keyed(arm, "forearm.L")
    # The raise is in the image plane, so it is reachable in 3D.
    for name in ("upper_arm.L", "forearm.L", "hand.L", "fingers.L"):
        assert _angle(got[name], want[name]) < 2.0, name


def test_black_box_path_recovers_the_constrained_rotation(humanoid, capfd) -> None:
    arm, _, stick, _ = humanoid
    pinned = arm.data.collections.new("Pinned")
    for b in arm.data.bones:
        if b.name not in ("upper_arm.L", "forearm.L"):
            pinned.assign(b)
    con = arm.pose.bones["forearm.L"].constraints.new("COPY_ROTATION")
    con.target, con.subtarget = arm, "upper_arm.L"
    con.mix_mode, con.owner_space, con.target_space = "ADD", "LOCAL", "LOCAL"
    builders.apply_rotations(arm, {"upper_arm.L": ((0.0, 1.0, 0.0), -30.0),
                                   "forearm.L": ((0.0, 1.0, 0.0), -20.0)})
    bpy.context.view_layer.update()
    want = _bone_dirs(arm)["forearm.L"]  # as evaluated, with the constraint
    strokes = ab.evaluated_polylines(stick)
    errors = {}
    for black_box in (False, True):
        builders.pose_humanoid(arm, "rest")
        sketch = builders.add_grease_pencil("Sketch", strokes)
        capfd.readouterr()
        result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                      abstraction="Stick Figure", black_box=black_box, representatives=60,
                      insert_keys=False)
        assert result == {"FINISHED"}
        out = capfd.readouterr().out
        assert ("black box" in out) == black_box
        got = _bone_dirs(arm)["forearm.L"]
        errors[black_box] = (_angle(got, want), _image_angle(got, want))
        bpy.data.objects.remove(sketch)
    # The constraint is part of the evaluated rig: exact as drawn, a few degrees in depth.
    assert errors[True][1] < 1.5 and errors[True][0] < 5.0
    assert errors[False][1] > 15.0  # LBS does not know it: the forearm is turned twice


def test_forearm_pointing_at_the_view_is_reported(humanoid, capfd) -> None:
    arm, _, stick, _ = humanoid
    bone = arm.data.bones["forearm.L"]
    d = np.array(bone.tail_local - bone.head_local)
    d /= np.linalg.norm(d)
    axis = np.cross(d, [0.0, -1.0, 0.0])  # the camera looks along +Y from -Y
    angle = float(np.degrees(np.arccos(np.clip(d @ [0.0, -1.0, 0.0], -1, 1))))
    builders.apply_rotations(arm, {"forearm.L": (tuple(axis), angle),
                                   "upper_arm.L": ((0.0, 1.0, 0.0), -20.0)})
    bpy.context.view_layer.update()
    lines = ab.evaluated_polylines(stick)
    builders.apply_rotations(arm, {"forearm.L": (tuple(axis), angle)})
    builders.add_grease_pencil("Sketch", [lines[1]])
    capfd.readouterr()
    result = _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
                  abstraction="Stick Figure", insert_keys=False)
    assert result == {"FINISHED"}
    out = capfd.readouterr().out
    assert "forearm.L" in out and "along the view axis" in out


def test_drawover_source_seen_as_a_dot_is_refused(humanoid) -> None:
    arm, _, _, _ = humanoid
    mid = 0.5 * sum(_bone_line(arm, "forearm.L"))
    dot = mid + np.array([[0.0, -0.2, 0.0], [0.002, -0.2, 0.0]])
    sketch = builders.add_grease_pencil("Sketch", [dot, dot + [0.0, 0.0, 0.3]])
    before = _snapshot(arm, sketch)
    with pytest.raises(RuntimeError, match="source stroke is only"):
        _run(bpy.ops.gesture_pose.drawover, arm, sketch="Sketch")
    _assert_unchanged(arm, sketch, before)


def test_lbs_path_warns_about_a_rig_that_is_not_lbs(humanoid, capfd) -> None:
    arm, _, stick, _ = humanoid
    con = arm.pose.bones["forearm.L"].constraints.new("COPY_ROTATION")
    con.target, con.subtarget = arm, "upper_arm.L"
    con.mix_mode, con.owner_space, con.target_space = "ADD", "LOCAL", "LOCAL"
    builders.apply_rotations(arm, {"upper_arm.L": ((0.0, 1.0, 0.0), -30.0)})
    builders.add_grease_pencil("Sketch", ab.evaluated_polylines(stick))
    capfd.readouterr()
    _run(bpy.ops.gesture_pose.pose_abstraction, arm, sketch="Sketch",
         abstraction="Stick Figure", insert_keys=False)
    assert "Black-Box Rig" in capfd.readouterr().out
