"""Pose Stroke end to end in headless Blender: scenes built in code, keys read back."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.blender.operators.pose_stroke import GESTUREPOSE_OT_pose_stroke
from gesture_pose.blender.read_armature import read_armature
from gesture_pose.blender.read_view import camera_from_object
from gesture_pose.blender.write_pose import keyed_frames
from gesture_pose.core.stroke import distance_to_polyline
from sample_scenes import builders

bpy = pytest.importorskip("bpy")

ARM_CHAIN = ["upper_arm.L", "forearm.L", "hand.L", "fingers.L"]


@pytest.fixture
def scene(registered):
    """Humanoid, front camera and an empty Grease Pencil object, at frame 5."""
    arm, mesh = builders.build_humanoid()
    cam = builders.add_camera(arm)
    bpy.context.scene.frame_set(5)
    gp = builders.add_grease_pencil("Sketch", [])
    return arm, mesh, cam, gp


def pose_stroke(**kw):
    return bpy.ops.gesture_pose.pose_stroke(**kw)


def rotations(arm) -> np.ndarray:
    return read_armature(arm).pose.rotations.copy()


def projected_chain(arm, cam, chain) -> np.ndarray:
    bpy.context.view_layer.update()
    joints = builders.joint_positions(arm)
    pts = np.array([joints[b][0] for b in chain] + [joints[chain[-1]][1]])
    return builders.project_to_pixels(pts, cam)


def test_arm_follows_stroke_and_only_chain_is_keyed(scene) -> None:
    arm, _, cam, gp = scene
    stroke = builders.chain_stroke(arm, cam, ARM_CHAIN,
                                   builders.HUMANOID_POSES["raise_left_arm"])
    builders.add_strokes(gp, [stroke])
    before = rotations(arm)
    assert pose_stroke(armature=arm.name, sketch=gp.name) == {"FINISHED"}
    after = rotations(arm)
    names = read_armature(arm).names
    changed = {names[i] for i in np.flatnonzero(np.abs(after - before).max(axis=(1, 2)) > 1e-7)}
    assert changed and changed <= set(ARM_CHAIN)
    assert "upper_arm.L" in changed and "forearm.L" in changed
    # The posed joints project onto the drawn stroke.
    px = projected_chain(arm, cam, ARM_CHAIN)
    drawn = builders.project_to_pixels(stroke, cam)
    assert distance_to_polyline(px[1:], drawn).max() < 3.0
    # Keys: at frame 5 on exactly the changed bones, in their rotation channel.
    for name in names:
        frames = keyed_frames(arm, name, "rotation_quaternion")
        assert frames == ([5.0] if name in changed else [])


def test_keys_on_other_frames_and_bones_are_untouched(scene) -> None:
    arm, _, cam, gp = scene
    pb = arm.pose.bones["forearm.L"]
    pb.keyframe_insert("rotation_quaternion", frame=1)
    arm.pose.bones["head"].keyframe_insert("rotation_quaternion", frame=5)
    arm.pose.bones["head"].keyframe_insert("location", frame=9)
    builders.add_strokes(gp, [builders.chain_stroke(
        arm, cam, ARM_CHAIN, builders.HUMANOID_POSES["raise_left_arm"])])
    assert pose_stroke(armature=arm.name, sketch=gp.name) == {"FINISHED"}
    assert keyed_frames(arm, "forearm.L", "rotation_quaternion") == [1.0, 5.0]
    assert keyed_frames(arm, "head", "rotation_quaternion") == [5.0]
    assert keyed_frames(arm, "head", "location") == [9.0]
    assert keyed_frames(arm, "forearm.L", "location") == []


def test_euler_and_axis_angle_bones_are_keyed_in_their_mode(scene) -> None:
    arm, _, cam, gp = scene
    builders.set_rotation_modes(arm, {"upper_arm.L": "ZXY", "forearm.L": "AXIS_ANGLE"})
    builders.add_strokes(gp, [builders.chain_stroke(
        arm, cam, ARM_CHAIN, builders.HUMANOID_POSES["raise_left_arm"])])
    assert pose_stroke(armature=arm.name, sketch=gp.name) == {"FINISHED"}
    assert keyed_frames(arm, "upper_arm.L", "rotation_euler") == [5.0]
    assert keyed_frames(arm, "upper_arm.L", "rotation_quaternion") == []
    assert keyed_frames(arm, "forearm.L", "rotation_axis_angle") == [5.0]
    px = projected_chain(arm, cam, ARM_CHAIN)
    drawn = builders.project_to_pixels(builders.read_strokes(gp)[0], cam)
    assert distance_to_polyline(px[1:3], drawn).max() < 3.0


def test_redrawing_a_leg_changes_only_the_leg(scene) -> None:
    arm, _, cam, gp = scene
    strokes = builders.example_strokes_humanoid(arm, cam)
    builders.add_strokes(gp, strokes[:1])
    pose_stroke(armature=arm.name, sketch=gp.name)
    after_arm = rotations(arm)
    builders.add_strokes(gp, strokes[1:])
    assert pose_stroke(armature=arm.name, sketch=gp.name) == {"FINISHED"}  # newest stroke
    after_leg = rotations(arm)
    names = read_armature(arm).names
    moved = {names[i] for i in np.flatnonzero(np.abs(after_leg - after_arm).max(axis=(1, 2))
                                              > 1e-7)}
    assert moved and moved <= {"thigh.R", "shin.R", "foot.R", "toe.R"}


def test_all_strokes_and_remove_used_strokes(scene) -> None:
    arm, _, cam, gp = scene
    builders.add_strokes(gp, builders.example_strokes_humanoid(arm, cam))
    assert pose_stroke(armature=arm.name, sketch=gp.name, all_strokes=True,
                       remove_used_strokes=True) == {"FINISHED"}
    for name in ("upper_arm.L", "thigh.R"):
        assert keyed_frames(arm, name, "rotation_quaternion") == [5.0]
    assert builders.read_strokes(gp) == []


def test_undo_restores_the_pose(scene) -> None:
    arm, _, cam, gp = scene
    builders.add_strokes(gp, [builders.chain_stroke(
        arm, cam, ARM_CHAIN, builders.HUMANOID_POSES["raise_left_arm"])])
    before, name = rotations(arm), arm.name
    # The operator is registered as undoable; headless (background) operator calls do not
    # push their own undo steps, so the test pushes around it as the UI would.
    assert "UNDO" in GESTUREPOSE_OT_pose_stroke.bl_options
    bpy.ops.ed.undo_push(message="before pose stroke")
    pose_stroke(armature=arm.name, sketch=gp.name)
    bpy.ops.ed.undo_push(message="Pose Stroke")
    assert np.abs(rotations(bpy.data.objects[name]) - before).max() > 0.1
    assert bpy.ops.ed.undo() == {"FINISHED"}  # undo replaces the Python objects
    np.testing.assert_allclose(rotations(bpy.data.objects[name]), before, atol=1e-9)


def _assert_refused(match: str, **kw) -> None:
    with pytest.raises(RuntimeError, match=match):
        pose_stroke(**kw)


def _unchanged(arm, before) -> None:
    np.testing.assert_allclose(rotations(arm), before, atol=0)
    assert arm.animation_data is None or arm.animation_data.action is None


def test_bad_inputs_report_and_change_nothing(scene) -> None:
    arm, _, cam, gp = scene
    before = rotations(arm)
    _assert_refused("no strokes", armature=arm.name, sketch=gp.name)
    _unchanged(arm, before)
    # A stroke far from every joint.
    corner = builders.strokes_through([np.array([[3.0, 0, 3.0], [3.2, 0, 3.2]])], cam,
                                      (0.0, 0.0, 1.0))
    builders.add_strokes(gp, corner)
    _assert_refused("farther than the pick radius", armature=arm.name, sketch=gp.name)
    _unchanged(arm, before)
    # NaN points.
    builders.add_strokes(gp, [np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.2]])])
    _assert_refused("NaN", armature=arm.name, sketch=gp.name)
    _unchanged(arm, before)
    # Unknown start bone.
    _assert_refused("no bone named 'wing'", armature=arm.name, sketch=gp.name, stroke_index=0,
                    start_bone="wing")
    _unchanged(arm, before)


def test_missing_armature_is_reported(registered) -> None:
    builders.add_grease_pencil("Sketch", [np.array([[0.0, 0, 0], [1.0, 0, 0]])])
    with pytest.raises(RuntimeError, match="No armature"):
        pose_stroke()


def test_chain_along_view_axis_is_reported(registered) -> None:
    arm, _ = builders.build_humanoid()
    cam = builders.add_camera(arm)
    # Point the left arm straight at the camera, then draw from its shoulder.
    data = read_armature(arm)
    camera = camera_from_object(cam, bpy.context.scene)
    st = data.skeleton.forward(data.pose)
    i = data.skeleton.index("upper_arm.L")
    to_cam = -camera.forward
    q = data.skeleton.aim_local(i, to_cam, st, data.pose.rotations[i])
    j = data.skeleton.index("forearm.L")
    from gesture_pose.blender.write_pose import apply_pose

    apply_pose(arm, data, data.pose.with_rotations([i], q[None]), insert_keys=False)
    bpy.context.view_layer.update()
    head = builders.joint_positions(arm)["upper_arm.L"][0]
    stroke = builders.strokes_through([np.array([head, head + [0.0, 0.0, -0.5]])], cam, head)
    gp = builders.add_grease_pencil("Sketch", stroke)
    assert j > i
    before = rotations(arm)
    with pytest.raises(RuntimeError, match="along the view axis"):
        pose_stroke(armature=arm.name, sketch=gp.name, end_bone="upper_arm.L",
                    start_bone="upper_arm.L")
    _unchanged(arm, before)
    assert len(builders.read_strokes(gp)) == 1


@pytest.mark.parametrize("pins", [("hand.L",), ("hand.L", "fingers.L")])
def test_pinned_bones_keep_their_world_position(scene, pins) -> None:
    arm, _, cam, gp = scene
    collection = arm.data.collections.new("Pinned")
    for name in pins:
        collection.assign(arm.data.bones[name])
    before = builders.joint_positions(arm)
    builders.add_strokes(gp, [builders.chain_stroke(
        arm, cam, ["upper_arm.L", "forearm.L"], builders.HUMANOID_POSES["raise_left_arm"])])
    assert pose_stroke(armature=arm.name, sketch=gp.name) == {"FINISHED"}
    bpy.context.view_layer.update()
    after = builders.joint_positions(arm)
    for name in pins:
        np.testing.assert_allclose(after[name][0], before[name][0], atol=2e-6)
        np.testing.assert_allclose(after[name][1], before[name][1], atol=2e-6)
    # The arm did move: the pins were restored, not the stroke ignored.
    assert np.linalg.norm(after["forearm.L"][0] - before["forearm.L"][0]) > 0.02


def test_too_short_stroke_is_reported(scene) -> None:
    arm, _, cam, gp = scene
    head = builders.joint_positions(arm)["upper_arm.L"][0]
    builders.add_strokes(gp, builders.strokes_through(
        [np.array([head, head + [0.004, 0.0, 0.0]])], cam, head))
    before = rotations(arm)
    _assert_refused("px long: draw a longer stroke", armature=arm.name, sketch=gp.name)
    _unchanged(arm, before)


def test_plane_mode_lays_the_arm_flat_to_the_view(scene) -> None:
    arm, _, cam, gp = scene
    builders.add_strokes(gp, [builders.chain_stroke(
        arm, cam, ARM_CHAIN, builders.HUMANOID_POSES["raise_left_arm"])])
    assert pose_stroke(armature=arm.name, sketch=gp.name, mode="PLANE") == {"FINISHED"}
    bpy.context.view_layer.update()
    forward = camera_from_object(cam, bpy.context.scene).forward
    joints = builders.joint_positions(arm)
    for name in ("upper_arm.L", "forearm.L"):
        head, tail = joints[name]
        d = (tail - head) / np.linalg.norm(tail - head)
        assert abs(float(d @ forward)) < 1e-4


def test_shape_tracking_follows_a_stroke_drawn_too_big(scene) -> None:
    # The raised-arm stroke drawn at twice its size from the shoulder: position tracking
    # lands the joints on the big stroke; shape tracking keeps the stroke's shape at the
    # arm's size, so the arm points where the (scaled) stroke's first part points.
    arm, _, cam, gp = scene
    stroke = builders.chain_stroke(arm, cam, ARM_CHAIN, builders.HUMANOID_POSES["raise_left_arm"])
    big = stroke[0] + 2.0 * (stroke - stroke[0])
    builders.add_strokes(gp, [big])
    assert pose_stroke(armature=arm.name, sketch=gp.name, tracking="SHAPE") == {"FINISHED"}
    px = projected_chain(arm, cam, ARM_CHAIN)
    small = builders.project_to_pixels(stroke, cam)
    drawn_big = builders.project_to_pixels(big, cam)
    assert distance_to_polyline(px[1:3], small).max() < 6.0
    assert distance_to_polyline(px[2:3], drawn_big).max() > 20.0


def test_stroke_index_and_remove_used_strokes(scene) -> None:
    arm, _, cam, gp = scene
    strokes = builders.example_strokes_humanoid(arm, cam)
    builders.add_strokes(gp, strokes)
    assert pose_stroke(armature=arm.name, sketch=gp.name, stroke_index=0,
                       remove_used_strokes=True) == {"FINISHED"}
    assert keyed_frames(arm, "upper_arm.L", "rotation_quaternion") == [5.0]
    assert keyed_frames(arm, "thigh.R", "rotation_quaternion") == []
    left = builders.read_strokes(gp)
    assert len(left) == 1
    np.testing.assert_allclose(left[0], strokes[1], atol=1e-5)


LEG_CHAIN = ["thigh.R", "shin.R", "foot.R", "toe.R"]


def test_a_leg_rigged_with_ik_follows_the_stroke_through_its_controls(scene) -> None:
    """The leg's IK target and pole are moved (and keyed) so that Blender's IK gives
    the solved leg back: the same joints as the rig without IK posed by the same
    stroke."""
    arm, _, cam, gp = scene
    stroke = builders.chain_stroke(arm, cam, LEG_CHAIN,
                                   builders.HUMANOID_POSES["kick_right_leg"])
    builders.add_strokes(gp, [stroke])
    assert pose_stroke(armature=arm.name, sketch=gp.name, insert_keys=False) == {"FINISHED"}
    plain = projected_chain(arm, cam, LEG_CHAIN)
    builders.reset_pose(arm)
    builders.add_ik_leg(arm, "R")
    assert pose_stroke(armature=arm.name, sketch=gp.name) == {"FINISHED"}
    rigged = projected_chain(arm, cam, LEG_CHAIN)  # as Blender evaluates it, IK included
    assert np.abs(rigged - plain).max() < 1.0  # pixels
    assert keyed_frames(arm, "foot_ik.R", "location") == [5.0]
    assert keyed_frames(arm, "knee_pole.R", "location") == [5.0]
    for name in ("thigh.R", "shin.R", "foot.R"):  # holding the pose shown
        assert keyed_frames(arm, name, "rotation_quaternion") == [5.0]
