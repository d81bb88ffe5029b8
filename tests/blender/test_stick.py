"""Stick figures in an environment, end to end in headless Blender.

Stick figures are made by projecting known sitting and standing poses of the sample
humanoid (1.5 px noise, hands and feet left out); the feet are pinned to the floor with
the Pin Joint operator and Pose Stick Figure reconstructs the pose.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from gesture_pose.blender.read_armature import read_armature
from gesture_pose.blender.read_mesh import read_skinned_meshes
from gesture_pose.blender.stick_io import read_pins
from gesture_pose.blender.write_pose import keyed_frames
from sample_scenes import stick_builders as sb

bpy = pytest.importorskip("bpy")

DRAWN = [n for n in sb.STICK_JOINTS if n not in ("hand.L", "hand.R", "toe.L", "toe.R")]


def _ops(arm):
    return bpy.context.temp_override(active_object=arm, object=arm, selected_objects=[arm])


def _solve(pose, seed=0):
    sc = sb.build_stick_scene(pose, noise_px=1.5, seed=seed)
    arm, sketch = sc["armature"], sc["sketch"]
    sb.pose_stick_humanoid(arm, pose)
    truth = sb.stick_joints(arm)
    sb.pose_stick_humanoid(arm, "rest")
    bpy.context.scene.frame_set(3)
    with _ops(arm):
        for joint in ("ankle.L", "ankle.R"):
            assert bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch=sketch.name,
                                                  joint=joint, candidate=0) == {"FINISHED"}
        assert bpy.ops.gesture_pose.pose_stick_figure(
            armature=arm.name, sketch=sketch.name, suggestions=2, seed=seed) == {"FINISHED"}
    return sc, truth


def _errors(arm, truth):
    got = sb.stick_joints(arm)
    return np.array([np.linalg.norm(got[n] - truth[n]) for n in DRAWN]), got


def test_sitting_pose_on_the_chair(registered):
    sc, truth = _solve("sit")
    arm = sc["armature"]
    err, got = _errors(arm, truth)
    # Body and legs close to the drawn pose (1.8 m character); arms may take the other
    # depth (suggestions hold the alternatives).
    legs = [DRAWN.index(n) for n in ("pelvis", "knee.L", "knee.R", "ankle.L", "ankle.R")]
    assert err[legs].mean() < 0.06
    assert err.mean() < 0.15
    # Pins exact: both ankles on the floor at the same height, above their pins' eye rays.
    env, _ = read_pins(bpy.context.scene)
    assert [p.joint for p in env] == ["ankle.L", "ankle.R"]
    assert abs(got["ankle.L"][2] - got["ankle.R"][2]) < 1e-4
    # No intersection with the chair seat (1 cm tolerance).
    mesh = read_skinned_meshes(arm, read_armature(arm).skeleton)
    v = mesh.deformed_vertices
    (x0, x1), (y0, y1), top = sb.CHAIR_SEAT
    inside = ((v[:, 0] > x0 + 0.01) & (v[:, 0] < x1 - 0.01) & (v[:, 1] > y0 + 0.01)
              & (v[:, 1] < y1 - 0.01) & (v[:, 2] < top - 0.01) & (v[:, 2] > top - 0.05))
    assert not inside.any()
    # The pelvis location is keyed with the rotations, at the current frame.
    assert keyed_frames(arm, "pelvis", "location") == [3.0]
    assert keyed_frames(arm, "thigh.L", "rotation_quaternion") == [3.0]


def test_standing_pose_and_suggestions(registered):
    sc, truth = _solve("stand", seed=1)
    arm = sc["armature"]
    err, got = _errors(arm, truth)
    legs = [DRAWN.index(n) for n in ("pelvis", "knee.L", "knee.R", "ankle.L", "ankle.R")]
    assert err[legs].mean() < 0.08
    assert abs(got["ankle.L"][2] - got["ankle.R"][2]) < 1e-4
    stored = json.loads(bpy.context.scene["gesture_pose_stick_suggestions"])
    n = len(stored["rotations"])
    assert n >= 1
    first = read_armature(arm).pose.rotations.copy()
    with _ops(arm):
        assert bpy.ops.gesture_pose.next_suggestion() == {"FINISHED"}
    second = read_armature(arm).pose.rotations
    assert (np.abs(second - first).max() > 1e-3) == (n > 1)
    with _ops(arm):
        bpy.ops.gesture_pose.next_suggestion(step=-1)
    assert np.allclose(read_armature(arm).pose.rotations, first, atol=1e-6)


def test_swap_sides_exchanges_the_arms(registered):
    sc, _ = _solve("stand", seed=1)
    arm, sketch = sc["armature"], sc["sketch"]
    before = sb.stick_joints(arm)
    with _ops(arm):
        assert bpy.ops.gesture_pose.swap_sides(armature=arm.name, sketch=sketch.name,
                                               pair="arms", suggestions=1) == {"FINISHED"}
    after = sb.stick_joints(arm)
    # The left wrist now goes where the right one was drawn (and vice versa).
    cam = sc["camera"]
    from gesture_pose.blender.read_view import camera_from_object
    c = camera_from_object(cam, bpy.context.scene)
    px = c.project(np.array([before["wrist.R"], after["wrist.L"]]))
    assert np.linalg.norm(px[0] - px[1]) < 25.0
    assert json.loads(bpy.context.scene["gesture_pose_stick_swaps"]) == ["arms"]


def test_topology_mismatch_is_reported(registered):
    sc = sb.build_stick_scene("stand")
    arm, sketch = sc["armature"], sc["sketch"]
    layer = sketch.data.layers.active
    drawing = layer.current_frame().drawing
    drawing.remove_strokes(indices=[6, 7])  # both strokes of one leg
    with _ops(arm), pytest.raises(RuntimeError, match="does not match the character"):
        bpy.ops.gesture_pose.pose_stick_figure(armature=arm.name, sketch=sketch.name)
    assert not arm.animation_data or not arm.animation_data.action


def test_pin_to_limb_and_clear(registered):
    sc = sb.build_stick_scene("sit")
    arm, sketch = sc["armature"], sc["sketch"]
    with _ops(arm):
        bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch=sketch.name, joint="wrist.R",
                                       target="LIMB", limb="pelvis,knee.R")
        bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch=sketch.name, joint="ankle.L")
    env, limb = read_pins(bpy.context.scene)
    assert [p.joint for p in limb] == ["wrist.R"] and 0.0 <= limb[0].s <= 1.0
    assert env[0].object_name == "Floor"
    with _ops(arm):
        bpy.ops.gesture_pose.pin_joint(joint="wrist.R", target="CLEAR")
    env, limb = read_pins(bpy.context.scene)
    assert limb == () and len(env) == 1


def test_edited_stick_is_written_back_to_the_sketch(registered):
    from gesture_pose.blender.operators.stick import GESTUREPOSE_OT_edit_stick_figure
    from gesture_pose.blender.stick_io import read_stick_scene, write_stick
    from gesture_pose.core.stick.edit import drag_node

    sc = sb.build_stick_scene("stand")
    arm, sketch = sc["armature"], sc["sketch"]
    st = read_stick_scene(bpy.context, arm, sketch)
    wrist = st.stick.joint_names.index("wrist.L")
    edited = drag_node(st.stick, wrist, st.stick.points[wrist] + [90.0, 60.0])
    write_stick(sketch, edited, st.camera, st.sketch_depth, bpy.context.scene.frame_current)
    again = read_stick_scene(bpy.context, arm, sketch)
    drawn = again.stick.present
    assert np.allclose(again.stick.points[drawn], edited.points[drawn], atol=0.5)
    # The modal editor needs a 3D View: headless, its poll says so.
    assert not GESTUREPOSE_OT_edit_stick_figure.poll(bpy.context)
