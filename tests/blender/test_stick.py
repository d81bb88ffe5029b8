"""Stick figures in an environment, end to end in headless Blender.

Stick figures are made by projecting known sitting and standing poses of the sample
humanoid (1.5 px noise, hands and feet left out); the feet are pinned to the floor with
the Pin Joint operator and Pose Stick Figure reconstructs the pose.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from gesture_pose.blender.read_armature import read_armature
from gesture_pose.blender.read_mesh import read_skinned_meshes
from gesture_pose.blender.stick_io import read_pins
from gesture_pose.blender.write_pose import keyed_frames
from gesture_pose.core.stick.genetic import GAConfig
from sample_scenes import builders
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


def test_legs_rigged_with_ik_are_posed_through_their_controls(registered):
    """Both legs rigged with IK (foot controls and knee poles): Blender's evaluation of
    the rig gives the first suggestion's legs, near the drawn pose; the controls are
    keyed with the legs' own channels."""
    from gesture_pose.core.skeleton import Pose
    from gesture_pose.core.stick.figure import character_figure

    sc = sb.build_stick_scene("stand", noise_px=1.5, seed=1)
    arm = sc["armature"]
    sb.pose_stick_humanoid(arm, "stand")
    truth = sb.stick_joints(arm)
    sb.pose_stick_humanoid(arm, "rest")
    for side in ("L", "R"):
        builders.add_ik_leg(arm, side)
    bpy.context.scene.frame_set(3)
    with _ops(arm):
        for joint in ("ankle.L", "ankle.R"):
            assert bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch="Sketch",
                                                  joint=joint, candidate=0) == {"FINISHED"}
        assert bpy.ops.gesture_pose.pose_stick_figure(
            armature=arm.name, sketch="Sketch", suggestions=2, seed=1) == {"FINISHED"}
    stored = json.loads(bpy.context.scene["gesture_pose_stick_suggestions"])
    data = read_armature(arm)
    state = data.skeleton.forward(Pose(np.array(stored["rotations"][0]),
                                       np.array(stored["translations"][0])))
    figure, _ = character_figure(data.skeleton, data.ik_limits)
    want = dict(zip(figure.joint_names, figure.joint_positions(state.heads, state.tails),
                    strict=True))
    got = sb.stick_joints(arm)  # as Blender evaluates the rig, IK included
    legs = ("pelvis", "knee.L", "knee.R", "ankle.L", "ankle.R")
    for name in legs:
        np.testing.assert_allclose(got[name], want[name], atol=2e-3, err_msg=name)
    assert np.mean([np.linalg.norm(got[n] - truth[n]) for n in legs]) < 0.08
    assert abs(got["ankle.L"][2] - got["ankle.R"][2]) < 1e-3
    for side in ("L", "R"):
        assert keyed_frames(arm, f"foot_ik.{side}", "location") == [3.0]
        assert keyed_frames(arm, f"thigh.{side}", "rotation_quaternion") == [3.0]


def test_lying_pose_at_a_seed_the_search_used_to_miss(registered):
    # The lying figure with the noise and search seed 200 (its pins as in the bench):
    # the search ended with the left forearm and the right arm flipped in depth (5.8 %
    # of the height, a plausibility score 0.0114 against 0.0070 for the refined truth).
    # The limb-flip move finds the drawn pose: 2.6 % (bench_stick, seeds 200-202).
    pose, seed = "lie", 200
    sc = sb.build_stick_scene(pose, noise_px=1.5, seed=seed)
    arm, sketch = sc["armature"], sc["sketch"]
    sb.pose_stick_humanoid(arm, pose)
    truth = sb.stick_joints(arm)
    sb.pose_stick_humanoid(arm, "rest")
    with _ops(arm):
        for joint in sb.STICK_PINS[pose]:
            assert bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch=sketch.name,
                                                  joint=joint, candidate=0) == {"FINISHED"}
        assert bpy.ops.gesture_pose.pose_stick_figure(
            armature=arm.name, sketch=sketch.name, seed=seed) == {"FINISHED"}
    err, _ = _errors(arm, truth)
    assert err.mean() < 0.03 * 1.8  # the target: 3 % of the height


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


def test_facing_option_reaches_the_solve(registered, monkeypatch):
    # The Facing option labels the drawn sides and decides which way the search starts
    # the body facing: the operator passes it to the solve.
    import gesture_pose.blender.stick_io as stick_io

    sc = sb.build_stick_scene("stand")
    arm, sketch = sc["armature"], sc["sketch"]
    seen = []
    real = stick_io.solve_stick

    def spy(inp):
        seen.append(inp.facing)
        return real(dataclasses.replace(inp, ga=GAConfig(population=64, max_generations=1)))

    monkeypatch.setattr(stick_io, "solve_stick", spy)
    for facing in ("back", "front"):
        with _ops(arm):
            assert bpy.ops.gesture_pose.pose_stick_figure(
                armature=arm.name, sketch=sketch.name, suggestions=1, facing=facing,
                insert_keys=False) == {"FINISHED"}
    assert seen == ["back", "front"]


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


class _Settings:
    """The solve settings the operators hold (their defaults, no keys unless asked)."""

    snap_radius, facing, environment, seed = 20.0, "front", "", 0
    suggestions, use_contact, insert_keys = 1, False, True


def _session(pose="stand"):
    from gesture_pose.blender.stick_io import StickDragSession

    sc = sb.build_stick_scene(pose)
    arm, sketch = sc["armature"], sc["sketch"]
    bpy.context.scene.frame_set(5)
    return sc, StickDragSession(bpy.context, _Settings(), arm, sketch)


def test_drag_session_short_drag_moves_one_joint_and_release_poses(registered):
    from gesture_pose.blender.stick_io import read_stick_scene

    sc, session = _session()
    arm, sketch = sc["armature"], sc["sketch"]
    before = session.stick.points.copy()
    wrist = session.stick.joint_names.index("wrist.L")
    # A press far from every joint picks none; moves then do nothing.
    assert session.press(before[wrist] + [300.0, 300.0]) is None
    assert not session.move(before[wrist]) and session.release() is None
    # The operator's events: press near the wrist, two moves (25 px < the global radius).
    assert session.handle("LEFTMOUSE", "PRESS", before[wrist] + [3.0, -2.0]) == "RUNNING_MODAL"
    assert session.joint == wrist
    assert session.handle("MOUSEMOVE", "NOTHING", before[wrist] + [10.0, 5.0]) == "RUNNING_MODAL"
    assert session.handle("MOUSEMOVE", "NOTHING", before[wrist] + [20.0, 15.0]) == "RUNNING_MODAL"
    drawn = read_stick_scene(bpy.context, arm, sketch).stick
    moved = np.linalg.norm(drawn.points - before, axis=1)
    present = drawn.present
    assert abs(moved[wrist] - 25.0) < 1.0
    assert np.all(moved[present & (np.arange(len(moved)) != wrist)] < 0.5)
    assert not arm.animation_data or not arm.animation_data.action
    assert session.handle("LEFTMOUSE", "RELEASE", before[wrist] + [20.0, 15.0]) == "RUNNING_MODAL"
    assert not session.dragging
    # Posed from the edited drawing and keyed at the current frame only.
    assert keyed_frames(arm, "pelvis", "location") == [5.0]
    assert keyed_frames(arm, "upper_arm.L", "rotation_quaternion") == [5.0]
    got = session.camera.project(sb.stick_joints(arm)["wrist.L"][None])[0]
    assert np.linalg.norm(got - drawn.points[wrist]) < np.linalg.norm(got - before[wrist])


def test_drag_session_far_drag_moves_the_chain(registered):
    from gesture_pose.blender.stick_io import read_stick_scene
    from gesture_pose.core.stick.edit import laplacian_chain

    sc, session = _session()
    arm, sketch = sc["armature"], sc["sketch"]
    st = session.stick
    before = st.points.copy()
    names = st.joint_names
    j = {n: names.index(n) for n in ("pelvis", "neck", "elbow.L", "wrist.L", "head",
                                     "elbow.R", "knee.L")}
    target = before[j["wrist.L"]] + [120.0, 90.0]
    session.press(before[j["wrist.L"]])
    session.move(target)
    drawn = read_stick_scene(bpy.context, arm, sketch).stick
    chain = [j["pelvis"], j["neck"], j["elbow.L"], j["wrist.L"]]
    # The chain from the pelvis bends (Laplacian solve), the rest follows rigidly.
    assert np.allclose(drawn.points[chain], laplacian_chain(before[chain], target), atol=0.5)
    assert np.linalg.norm(drawn.points[j["elbow.L"]] - before[j["elbow.L"]]) > 20.0
    shift = drawn.points[j["neck"]] - before[j["neck"]]
    assert np.linalg.norm(shift) > 5.0
    for n in ("head", "elbow.R"):
        assert np.allclose(drawn.points[j[n]] - before[j[n]], shift, atol=0.5)
    assert np.allclose(drawn.points[j["knee.L"]], before[j["knee.L"]], atol=0.5)
    assert session.cancel()


def test_drag_session_cancel_restores_the_drawing(registered):
    from gesture_pose.blender.read_strokes import read_sketch

    sc, session = _session()
    arm, sketch = sc["armature"], sc["sketch"]
    original = read_sketch(sketch)
    start = session.stick.points.copy()
    knee = session.stick.joint_names.index("knee.R")
    # The operator's events, as the modal passes them: a far (global) drag, then Esc.
    assert session.handle("LEFTMOUSE", "PRESS", start[knee]) == "RUNNING_MODAL"
    assert session.handle("MOUSEMOVE", "NOTHING", start[knee] + [80.0, 0.0]) == "RUNNING_MODAL"
    assert session.handle("MOUSEMOVE", "NOTHING", start[knee] + [90.0, 30.0]) == "RUNNING_MODAL"
    edited = [s.points_world for s in read_sketch(sketch)]
    assert len(edited) != len(original) or not all(
        np.allclose(a, b.points_world, atol=1e-3) for a, b in zip(edited, original, strict=True))
    assert session.handle("ESC", "PRESS", start[knee]) == "RUNNING_MODAL"  # cancels the drag
    assert not session.dragging
    # Exactly as before: the same strokes, points and radii, and the same drawing.
    restored = read_sketch(sketch)
    assert len(restored) == len(original)
    for a, b in zip(restored, original, strict=True):
        assert np.array_equal(a.points_world, b.points_world)
        assert np.array_equal(a.radius, b.radius)
    assert np.array_equal(session.stick.points, start, equal_nan=True)
    assert session.release() is None  # nothing left to pose
    assert not arm.animation_data or not arm.animation_data.action
    assert not session.cancel()
    # Not dragging: Esc ends the editing; other events pass through to the viewport.
    assert session.handle("WHEELUPMOUSE", "PRESS", start[knee]) == "PASS_THROUGH"
    assert session.handle("MOUSEMOVE", "NOTHING", start[knee]) == "PASS_THROUGH"
    assert session.handle("ESC", "PRESS", start[knee]) == "FINISHED"


def test_drag_session_right_mouse_restores_a_figure_on_another_layer(registered):
    """The figure drawn on a layer that is not the active one: a drag draws it once (in the
    active layer), and right mouse during the drag puts every layer back and ends."""
    from gesture_pose.blender.read_strokes import read_sketch

    sc, session = _session()
    arm, sketch = sc["armature"], sc["sketch"]
    figure_layer = sketch.data.layers.active.name
    sketch.data.layers.new("Notes", set_active=True)  # active, empty
    original = read_sketch(sketch)
    assert {s.layer_name for s in original} == {figure_layer}
    start = session.stick.points.copy()
    knee = session.stick.joint_names.index("knee.R")
    session.handle("LEFTMOUSE", "PRESS", start[knee])
    session.handle("MOUSEMOVE", "NOTHING", start[knee] + [30.0, 10.0])
    edited = read_sketch(sketch)
    assert {s.layer_name for s in edited} == {"Notes"}  # drawn once, not twice
    assert session.handle("RIGHTMOUSE", "PRESS", start[knee]) == "FINISHED"
    restored = read_sketch(sketch)
    assert [s.layer_name for s in restored] == [s.layer_name for s in original]
    for a, b in zip(restored, original, strict=True):
        assert np.array_equal(a.points_world, b.points_world)
        assert np.array_equal(a.radius, b.radius)
    assert not arm.animation_data or not arm.animation_data.action


def test_edit_operator_needs_a_view_headless(registered):
    from gesture_pose.blender.operators.stick import GESTUREPOSE_OT_edit_stick_figure

    # The modal editor needs a 3D View: headless, its poll says so (its logic is the
    # session tested above).
    assert not GESTUREPOSE_OT_edit_stick_figure.poll(bpy.context)


def test_quadruped_ranges_from_the_rig_and_its_ik_limits(registered):
    from gesture_pose.core.stick.figure import character_figure
    from sample_scenes import builders

    arm, _ = builders.build_quadruped()
    pb = arm.pose.bones["shin.L"]
    pb.use_ik_limit_x, pb.ik_min_x, pb.ik_max_x = True, np.radians(-5.0), np.radians(80.0)
    pb.use_ik_limit_z, pb.ik_min_z, pb.ik_max_z = True, np.radians(-2.0), np.radians(2.0)
    data = read_armature(arm)
    fig, humanoid = character_figure(data.skeleton, data.ik_limits)
    assert not humanoid
    groups = {g.name: g for g in fig.groups}
    # The rig's IK limits take precedence (local x, y, z; y unlimited gets +-120).
    assert np.allclose(np.degrees(groups["shin.L"].bounds), [[-5, 80], [-120, 120], [-2, 2]])
    assert groups["shin.L"].comfort is None
    # Elsewhere the defaults read from the rig: the other hind knee a sagittal hinge
    # flexing the way it bends at rest, the tail's six segments sharing 180 degrees.
    shin = groups["shin.R"]
    axis = data.skeleton.rest_frames[shin.bones[0]] @ shin.bases[0][:, 0]
    assert shin.bounds.shape == (1, 2) and abs(axis[0]) > 0.99
    tail = sum(np.degrees(groups[f"tail.{i:03d}"].bounds[0, 1]) for i in range(6))
    assert np.isclose(tail, 180.0)


def test_quadruped_is_posed_by_topology_with_its_default_ranges(registered):
    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.stick.figure import character_figure
    from gesture_pose.core.stick.kinematics import PoseModel
    from sample_scenes import builders

    arm, mesh = builders.build_quadruped()
    cam_obj = builders.add_camera(mesh, direction=(1.0, -1.0, 0.6))
    scene = bpy.context.scene
    data = read_armature(arm)
    sk = data.skeleton
    fig, humanoid = character_figure(sk, data.ik_limits)
    assert not humanoid
    # A pose inside the default ranges: tail swept up, neck lowered, left front leg
    # reaching forward with its elbow bent, left hind knee bent further.
    model = PoseModel(sk, fig, data.pose)
    group = {g.name: g for g in fig.groups}
    x = np.zeros(model.n_genes)
    for i in range(6):
        name = f"tail.{i:03d}"
        x[model.genes_of(name)[0]] = 0.8 * group[name].bounds[0, 0]
    for name in ("neck", "neck.001"):
        x[model.genes_of(name)[0]] = 0.6 * group[name].bounds[0, 1]
    x[model.genes_of("upper_arm.L")[0]] = np.radians(-40.0)
    x[model.genes_of("forearm.L")[0]] = np.radians(60.0)
    x[model.genes_of("shin.L")[0]] = np.radians(35.0)
    lo, hi = model.bounds(np.zeros(3), 0.0).T
    assert np.all((x >= lo) & (x <= hi))
    heads, tails, _ = model.forward(x[None])
    truth = fig.joint_positions(heads, tails)[0]
    cam = camera_from_object(cam_obj, scene)
    px = cam.project(truth)
    depth = 0.5 * float(cam.depth(truth[:1])[0])
    strokes = [cam.unproject_at_depth(np.linspace(px[p], px[c], 8), depth)
               for c, p in enumerate(fig.joint_parents) if p >= 0]
    sketch = builders.add_grease_pencil("Sketch", strokes)
    with _ops(arm):
        assert bpy.ops.gesture_pose.pose_stick_figure(
            armature=arm.name, sketch=sketch.name, suggestions=2, seed=0) == {"FINISHED"}
    posed = read_armature(arm)
    state = sk.forward(posed.pose)
    got = cam.project(fig.joint_positions(state.heads, state.tails))
    # Every joint lands on the drawing (left and right legs may be exchanged: a mirrored
    # leg lands on the other drawn leg).
    # Measured: worst 9.4 px, mean 3.8 px, 1.4% and 0.6% of the drawing's 686 px size (the
    # free root's depth is only known from the drawing's scale); limits with a margin.
    near = np.linalg.norm(got[:, None] - px[None], axis=-1).min(1)
    size = float(np.linalg.norm(np.ptp(px, axis=0)))
    assert near.max() < 0.015 * size and near.mean() < 0.007 * size
    # The knees, hocks and front elbows stay hinges: their rotation's axis is the hinge's.
    for name in ("forearm.L", "forearm.R", "shin.L", "shin.R", "hind_foot.L", "hind_foot.R"):
        b = sk.index(name)
        g = group[name]
        R = posed.pose.rotations[b]
        axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        if np.linalg.norm(axis) > 1e-3:
            assert abs(axis @ g.bases[0][:, 0]) / np.linalg.norm(axis) > 0.999, name


def test_pin_joint_offers_and_checks_the_characters_own_joints(registered, monkeypatch):
    from gesture_pose.blender.operators.stick import _search_joints, figure_edges
    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.stick.figure import character_figure
    from sample_scenes import builders

    arm, mesh = builders.build_quadruped()
    cam = camera_from_object(builders.add_camera(mesh, direction=(1.0, -1.0, 0.6)),
                             bpy.context.scene)
    data = read_armature(arm)
    fig, _ = character_figure(data.skeleton, data.ik_limits)
    names, edges = figure_edges(bpy.context, arm.name)
    assert names == fig.joint_names and "ankle.L" not in names
    assert len(edges) == len(names) - 1
    # The search offers the quadruped's joints, filtered by what was typed.
    op_like = type("Op", (), {"armature": arm.name})()
    typed = names[-1][:3]
    offered = _search_joints(op_like, bpy.context, typed)
    assert names[-1] in offered and all(typed.lower() in o.lower() for o in offered)
    # Typing again does not read the armature again; changing its bones does.
    from gesture_pose.blender.operators import stick as stick_op

    reads = []
    real_read = stick_op.read_armature
    monkeypatch.setattr(stick_op, "read_armature",
                        lambda obj: reads.append(obj.name) or real_read(obj))
    assert _search_joints(op_like, bpy.context, typed) == offered
    assert reads == []
    for dz in (0.01, -0.01):  # a bone edited, then put back
        bpy.context.view_layer.objects.active = arm
        bpy.ops.object.mode_set(mode="EDIT")
        arm.data.edit_bones[-1].tail.z += dz
        bpy.ops.object.mode_set(mode="OBJECT")
        assert figure_edges(bpy.context, arm.name)[0] == names
    assert reads == [arm.name, arm.name]
    # Its stick figure, drawn at rest.
    state = data.skeleton.forward(data.pose)
    px = cam.project(fig.joint_positions(state.heads[None], state.tails[None])[0])
    depth = 0.5 * float(cam.depth(state.heads[:1])[0])
    strokes = [cam.unproject_at_depth(np.linspace(px[p], px[c], 8), depth)
               for c, p in enumerate(fig.joint_parents) if p >= 0]
    sketch = builders.add_grease_pencil("Sketch", strokes)
    joint, limb = names[-1], next(e for e in edges if names[-1] not in e.split(","))
    with _ops(arm):
        assert bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch=sketch.name,
                                              joint=joint, target="LIMB",
                                              limb=limb) == {"FINISHED"}
    _, limb_pins = read_pins(bpy.context.scene)
    assert [(p.joint, ",".join(p.limb)) for p in limb_pins] == [(joint, limb)]
    # A humanoid joint name, or a pair that is no edge, is refused and nothing changes.
    for kwargs, message in (({"joint": "ankle.L"}, "not a joint of this character"),
                            ({"joint": joint, "limb": f"{names[0]},{joint}"}, "not an edge")):
        with _ops(arm), pytest.raises(RuntimeError, match=message):
            bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch=sketch.name,
                                           target="LIMB", **{"limb": limb, **kwargs})
    assert read_pins(bpy.context.scene)[1] == limb_pins
