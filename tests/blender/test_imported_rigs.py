"""Imported rigs whose bones have token lengths (as glTF imports), headless.

The rig is the sample humanoid made to look like a glTF import: every bone disconnected
and shortened to 1 cm along a direction unrelated to its children, heads, rolls aside, and
skin weights kept. The reader must see the head-to-child-head skeleton of the proper
humanoid, write poses back in the real bones' frames, and the gesture operators must work
on it as they do on the proper humanoid.
"""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.blender.operators import fit_drawing as fit_op
from gesture_pose.blender.operators import pose_drawing
from gesture_pose.blender.read_armature import read_armature
from gesture_pose.blender.read_mesh import read_skinned_meshes
from gesture_pose.blender.read_view import camera_from_object
from gesture_pose.blender.write_pose import apply_pose, keyed_frames, rotation_channel
from gesture_pose.core.gesture.embedding import posed_joints

bpy = pytest.importorskip("bpy")
builders = pytest.importorskip("sample_scenes.builders")

#: Bones of the humanoid without a child: their joint-skeleton tails come from the mesh.
ENDS = ("head", "fingers.L", "fingers.R", "toe.L", "toe.R")


def token_humanoid(name: str = "Imported", seed: int = 0):
    """The sample humanoid with 1 cm unconnected bones in random directions.

    Returns:
        ``(armature object, mesh object)``.
    """
    arm, mesh = builders.build_humanoid(name)
    rng = np.random.default_rng(seed)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    bones = arm.data.edit_bones
    for eb in bones:
        eb.use_connect = False
    for eb in bones:
        d = rng.normal(size=3)
        eb.tail = np.array(eb.head) + 0.01 * d / np.linalg.norm(d)
        eb.roll = float(rng.uniform(-np.pi, np.pi))
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.context.view_layer.update()
    return arm, mesh


def _world_matrices(arm) -> np.ndarray:
    bpy.context.view_layer.update()
    w = np.array(arm.matrix_world)
    return np.array([w @ np.array(pb.matrix) for pb in arm.pose.bones])


def _deformed(arm) -> np.ndarray:
    bpy.context.view_layer.update()
    return read_skinned_meshes(arm, read_armature(arm, joints=False).skeleton).deformed_vertices


def test_reader_gives_the_head_to_child_head_skeleton(bpy_blank):
    proper, _ = builders.build_humanoid("Proper")
    token, _ = token_humanoid()
    p, t = read_armature(proper), read_armature(token)
    assert p.frame_change is None  # proper rigs are read exactly as before
    assert t.frame_change is not None and t.names == p.names
    raw = read_armature(token, joints=False).skeleton
    assert raw.lengths.max() < 0.011  # the token rig really has token bones
    np.testing.assert_allclose(t.skeleton.rest_heads, p.skeleton.rest_heads, atol=1e-6)
    inner = [i for i, n in enumerate(p.names) if n not in ENDS]
    np.testing.assert_allclose(t.skeleton.rest_tails[inner], p.skeleton.rest_tails[inner],
                               atol=1e-6)
    # End bones run along their part of the mesh: within 25 degrees of the proper bones,
    # and of a comparable length (the head's mesh reaches past the proper head bone).
    ends = [p.skeleton.index(n) for n in ENDS]
    dt = t.skeleton.rest_tails[ends] - t.skeleton.rest_heads[ends]
    dp = p.skeleton.rest_tails[ends] - p.skeleton.rest_heads[ends]
    cos = np.sum(dt * dp, axis=1) / np.linalg.norm(dt, axis=1) / np.linalg.norm(dp, axis=1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 25.0
    ratio = np.linalg.norm(dt, axis=1) / np.linalg.norm(dp, axis=1)
    assert np.all((ratio > 0.6) & (ratio < 1.6)), dict(zip(ENDS, ratio.round(2), strict=True))
    # +Y of every new rest frame runs along its bone; frames are the real ones turned by C.
    seg = t.skeleton.rest_tails - t.skeleton.rest_heads
    np.testing.assert_allclose(t.skeleton.rest_frames[:, :, 1],
                               seg / np.linalg.norm(seg, axis=1)[:, None], atol=1e-9)
    np.testing.assert_allclose(raw.rest_frames @ t.frame_change, t.skeleton.rest_frames,
                               atol=1e-9)


def test_written_pose_matches_posing_the_rig_directly(bpy_blank):
    proper, _ = builders.build_humanoid("Proper")
    token, _ = token_humanoid()
    rest = read_armature(token)
    rotations = builders.HUMANOID_POSES["wave"]
    builders.apply_rotations(token, rotations)
    builders.apply_rotations(proper, rotations)
    direct = _world_matrices(token)
    posed = read_armature(token)
    # The joint skeleton's posed bones are the proper humanoid's (same heads and tails).
    state = posed.skeleton.forward(posed.pose)
    ps = read_armature(proper)
    pstate = ps.skeleton.forward(ps.pose)
    np.testing.assert_allclose(state.heads, pstate.heads, atol=1e-5)
    inner = [i for i, n in enumerate(ps.names) if n not in ENDS]
    np.testing.assert_allclose(state.tails[inner], pstate.tails[inner], atol=1e-5)
    # Write the read pose back from rest through the conversion: same matrices, same mesh.
    builders.reset_pose(token)
    bpy.context.view_layer.update()
    written = apply_pose(token, rest, posed.pose, insert_keys=True, frame=3)
    assert set(written) == set(rotations)
    np.testing.assert_allclose(_world_matrices(token), direct, atol=1e-5)
    np.testing.assert_allclose(_deformed(token), _deformed(proper), atol=1e-5)
    for pb in token.pose.bones:  # keys on the written bones only
        frames = keyed_frames(token, pb.name, rotation_channel(pb.rotation_mode))
        assert frames == ([3.0] if pb.name in written else [])
    # Reading again gives the written pose, in the joint skeleton's frames.
    np.testing.assert_allclose(read_armature(token).pose.rotations, posed.pose.rotations,
                               atol=1e-5)
    # The abstraction mode's evaluator writes pose bones itself: same conversion.
    from gesture_pose.blender.abstraction_io import set_rig_pose
    from gesture_pose.core.abstraction import RigPose

    builders.reset_pose(token)
    set_rig_pose(token, rest.names, RigPose.from_pose(posed.pose), np.arange(len(rest.names)),
                 rest.object_scale, rest.frame_change)
    np.testing.assert_allclose(_world_matrices(token), direct, atol=1e-5)


def _traced_pair(pose_name: str):
    """Both humanoids posed alike, a front camera, and the token rig's traced drawing.

    Returns:
        ``(proper, token, core camera, sketch of the token rig's contours)``; both rigs are
        left posed.
    """
    proper, _ = builders.build_humanoid("Proper")
    token, _ = token_humanoid()
    cam = builders.add_camera(proper, resolution=(800, 800))
    for arm in (proper, token):
        builders.pose_humanoid(arm, pose_name)
    bpy.context.view_layer.update()
    camera = camera_from_object(cam, bpy.context.scene)
    traced = fit_op.trace_character(token, camera)
    return proper, token, camera, fit_op.write_traced("Drawing", traced, camera)


def _fit_errors(arm, camera, sketch) -> tuple[np.ndarray, float]:
    """Fitted joint errors (% projected height) and coverage of the fit of ``sketch``."""
    emb, _ = fit_op.fit_scene_drawing(arm, sketch, camera)
    data = read_armature(arm)
    truth = camera.project(posed_joints(emb.solving, data.skeleton, data.pose))
    err = np.linalg.norm(emb.joints2d - truth, axis=1) / np.ptp(truth[:, 1]) * 100.0
    return err, emb.coverage


#: The proper humanoid's solving bones (its automatic choice).
SOLVING = ("pelvis", "spine", "spine.001", "chest", "neck", "head", "shoulder.L",
           "upper_arm.L", "forearm.L", "hand.L", "shoulder.R", "upper_arm.R", "forearm.R",
           "hand.R", "thigh.L", "shin.L", "foot.L", "thigh.R", "shin.R", "foot.R")


# Measured on these drawings (clean traced contours, front view), % of projected height,
# with the 2D fit of this commit (the perspective range of the length term, the crossing
# test of the consistency term; the previous fit's figures in brackets):
#
#   pose            rig     solving bones       median       mean         joints within 4%
#   step            proper  proper's            0.71 (0.99)  1.03 (1.78)  96% (88%)
#   step            token   automatic           2.25 (1.79)  2.61 (2.05)  68% (84%)
#   step            token   proper's (Gesture)  1.15 (1.72)  1.57 (2.06)  96% (84%)
#   raise_left_arm  proper  proper's            1.11 (0.98)  1.49 (3.23)  100% (92%)
#   raise_left_arm  token   automatic           1.45 (1.56)  2.23 (2.26)  80% (84%)
#   raise_left_arm  token   proper's (Gesture)  1.68 (0.88)  3.37 (3.32)  80% (88%)
#
# The automatic choice differs on the token rig: its head bone runs to the top of the head
# mesh (the proper one stops 8 cm lower), which widens the rest bounding box and so the
# shortest kept bone, and the hands (9.01 cm, 2 steps are 9.0 cm on the proper rig) drop
# out while the mesh-long toes come in. With the same bones the fits agree on the step;
# on the raised arm the proper rig's fit found the raised forearm and hand this time and
# the token rig's did not (its joint radii differ slightly), so that comparison is an
# expected failure. Limits: the measurements plus a few tenths of a percent; the share
# within 4% one joint below the lower measured one (68%: 0.64).
@pytest.mark.parametrize("pose_name", ["step", "raise_left_arm"])
def test_fit_drawing_on_the_token_rig(registered, pose_name):
    _, token, camera, sketch = _traced_pair(pose_name)
    err_t, _ = _fit_errors(token, camera, sketch)
    assert len(err_t) == 25
    assert np.median(err_t) < 2.4, err_t.round(1)
    assert np.mean(err_t <= 4.0) >= 0.64, err_t.round(1)
    with bpy.context.temp_override(active_object=token, object=token):
        assert bpy.ops.gesture_pose.fit_drawing(armature=token.name,
                                                sketch=sketch.name) == {"FINISHED"}
    assert len(sketch.data.layers[fit_op.FIT_LAYER].current_frame().drawing.strokes) > 10


# The raised arm was an expected failure (the token rig's raised forearm and hand not
# found: mean 3.37 against 1.49% on the proper rig) until the limb re-solves
# (docs/gesture.md) unfolded that forearm.
@pytest.mark.parametrize("pose_name", ["step", "raise_left_arm"])
def test_fit_drawing_on_the_token_rig_matches_the_proper_rig(registered, pose_name):
    proper, token, camera, sketch = _traced_pair(pose_name)
    # With the same solving bones, the token rig fits like the proper one.
    for arm in (proper, token):
        coll = arm.data.collections.new("Gesture")
        for name in SOLVING:
            coll.assign(arm.data.bones[name])
    err_p, cov_p = _fit_errors(proper, camera, sketch)
    err_t, cov_t = _fit_errors(token, camera, sketch)
    assert err_t.mean() < err_p.mean() + 0.6, (err_p.round(1), err_t.round(1))
    assert np.mean(err_t <= 4.0) >= np.mean(err_p <= 4.0) - 0.1
    assert abs(cov_t - cov_p) < 0.05


def test_pose_drawing_keys_the_real_bones(registered):
    proper, token, camera, sketch = _traced_pair("raise_left_arm")
    truth = read_armature(token)
    truth_joints = truth.skeleton.forward(truth.pose).heads
    for arm in (proper, token):
        builders.reset_pose(arm)
    bpy.context.scene.frame_set(4)
    bpy.context.view_layer.update()
    before = read_armature(token, joints=False)
    with bpy.context.temp_override(active_object=token, object=token):
        assert bpy.ops.gesture_pose.pose_drawing(armature=token.name, sketch=sketch.name,
                                                 show_fit=False) == {"FINISHED"}
    after = read_armature(token, joints=False)
    changed = np.flatnonzero(np.abs(after.pose.rotations - before.pose.rotations)
                             .max(axis=(1, 2)) > 1e-6)
    assert len(changed) >= 8
    for i in range(len(after.names)):  # keys on the changed bones only, at this frame
        channel = rotation_channel(after.rotation_modes[i])
        assert keyed_frames(token, after.names[i], channel) == ([4.0] if i in changed else [])
    # The posed heads are near the drawn pose's (3D, root aligned, % of the height), as
    # the whole Pose gets them on the proper humanoid (below 12%).
    got = read_armature(token)
    heads = got.skeleton.forward(got.pose).heads
    major = [got.skeleton.index(n) for n in ("upper_arm.L", "forearm.L", "hand.L",
                                             "upper_arm.R", "forearm.R", "hand.R", "thigh.L",
                                             "shin.L", "foot.L", "neck", "head")]
    err = np.linalg.norm((heads - heads[0]) - (truth_joints - truth_joints[0]), axis=1)
    assert 100.0 * err[major].mean() / 1.8 < 12.0, (err[major] * 100 / 1.8).round(1)
    rep = pose_drawing.pose_from_drawing(proper, sketch, camera, insert_keys=False,
                                         show_fit=False)
    bpy.context.view_layer.update()
    p = read_armature(proper)
    pheads = p.skeleton.forward(p.pose).heads
    perr = np.linalg.norm((pheads - pheads[0]) - (truth_joints - truth_joints[0]), axis=1)
    assert rep.written
    assert err[major].mean() < perr[major].mean() + 0.03


def test_pose_stroke_on_the_token_rig(registered):
    token, _ = token_humanoid()
    cam = builders.add_camera(token)
    proper, _ = builders.build_humanoid("Proper")
    bpy.context.scene.frame_set(5)
    chain = ["upper_arm.L", "forearm.L", "hand.L", "fingers.L"]
    stroke = builders.chain_stroke(proper, cam, chain, builders.HUMANOID_POSES["raise_left_arm"])
    gp = builders.add_grease_pencil("Sketch", [stroke])
    before = read_armature(token, joints=False)
    assert bpy.ops.gesture_pose.pose_stroke(armature=token.name, sketch=gp.name) == {"FINISHED"}
    after = read_armature(token, joints=False)
    changed = {after.names[i] for i in np.flatnonzero(
        np.abs(after.pose.rotations - before.pose.rotations).max(axis=(1, 2)) > 1e-7)}
    assert {"upper_arm.L", "forearm.L"} <= changed <= set(chain)
    for name in after.names:
        frames = keyed_frames(token, name, "rotation_quaternion")
        assert frames == ([5.0] if name in changed else [])
    # The chain's joints (heads, and the end of the joint skeleton's last bone) lie on the
    # stroke in the view, as on the proper humanoid.
    from gesture_pose.core.stroke import distance_to_polyline

    data = read_armature(token)
    state = data.skeleton.forward(data.pose)
    idx = [data.skeleton.index(n) for n in chain]
    pts = np.concatenate([state.heads[idx[1:]], state.tails[idx[-1:]]])
    px = builders.project_to_pixels(pts, cam)
    drawn = builders.project_to_pixels(stroke, cam)
    assert distance_to_polyline(px, drawn).max() < 6.0


def test_locks_that_do_not_fall_on_the_joint_axes_are_reported(bpy_blank):
    """A rotation lock on a re-aimed bone cannot be kept per axis: the reader says so."""
    token, _ = token_humanoid()
    token.pose.bones["forearm.L"].lock_rotation = (True, False, False)
    bpy.context.view_layer.update()
    data = read_armature(token)
    assert len(data.warnings) == 1
    assert "forearm.L" in data.warnings[0] and "ignore" in data.warnings[0]
    assert not data.lock_rotation[data.skeleton.index("forearm.L")].any()
    token.pose.bones["forearm.L"].lock_rotation = (False, False, False)
    assert read_armature(token).warnings == ()


def test_pose_keeps_ik_limits_about_the_real_bones_axes(registered, monkeypatch):
    """IK limits set on an imported rig's bone restrict Pose about that bone's own axes,
    which the joint skeleton's frames do not share."""
    from gesture_pose.core.gesture.depth.synthetic import project_embedding
    from gesture_pose.core.gesture.solving import solving_skeleton
    from gesture_pose.core.rotations import log_map

    token, _ = token_humanoid()
    camera = camera_from_object(builders.add_camera(token), bpy.context.scene)
    builders.apply_rotations(token, builders.HUMANOID_POSES["raise_left_arm"])
    bpy.context.view_layer.update()
    truth = read_armature(token)
    builders.reset_pose(token)
    bpy.context.view_layer.update()

    def oracle_fit(arm_obj, sketch_obj, camera, frame=None, params=None, facing="auto",
                   body_up="up"):
        sk = read_armature(arm_obj).skeleton
        return project_embedding(sk, solving_skeleton(sk), truth.pose, camera, 0.06,
                                 "auto"), 1

    monkeypatch.setattr(pose_drawing, "fit_scene_drawing", oracle_fit)
    sketch = builders.add_grease_pencil("Sketch", [np.array([[0.0, -1.0, 0.0],
                                                             [0.1, -1.0, 0.5]])])
    i = truth.skeleton.index("forearm.L")

    def real_rotvec() -> np.ndarray:
        bpy.context.view_layer.update()
        return log_map(read_armature(token, joints=False).pose.rotations[i][None])[0]

    pose_drawing.pose_from_drawing(token, sketch, camera, insert_keys=False, show_fit=False)
    # The free solve turns the forearm well beyond the limit of 0.1 set below: measured
    # 0.27 rad with the 3D step's view rays (0.37 before; the pose's mean joint error
    # 0.56 -> 0.24 % of the height); the known pose twists it by 25 degrees (0.44 rad).
    assert np.abs(real_rotvec()).max() > 0.25
    builders.reset_pose(token)
    pb = token.pose.bones["forearm.L"]
    for ax in "xyz":
        setattr(pb, f"use_ik_limit_{ax}", True)
        setattr(pb, f"ik_min_{ax}", -0.1)
        setattr(pb, f"ik_max_{ax}", 0.1)
    assert read_armature(token).axis_settings()[2] is not None
    pose_drawing.pose_from_drawing(token, sketch, camera, insert_keys=False, show_fit=False)
    assert np.abs(real_rotvec()).max() <= 0.1 + 2e-3
