"""A generated Rigify rig: read as its metarig's bones, posed through its FK controls."""

from __future__ import annotations

import bpy
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gesture_pose.blender.read_armature import read_armature
from gesture_pose.blender.rigify import IK_FK
from gesture_pose.blender.write_pose import apply_pose, keyed_frames
from gesture_pose.core.exceptions import InputError
from gesture_pose.core.skeleton import Pose
from sample_scenes import builders

ARM_L = ("ORG-upper_arm.L", "ORG-forearm.L", "ORG-hand.L")


def _generated(metarig_add):
    """A Rigify rig generated headless from a metarig (the add-on enabled meanwhile)."""
    import addon_utils

    addon_utils.enable("rigify", default_set=True)
    try:
        import rigify

        rigify.register_rig_parameters()  # the module's enable leaves them out
        metarig_add()
        bpy.ops.pose.rigify_generate()
        obj = bpy.context.active_object
        bpy.context.view_layer.update()
        yield obj
    finally:
        addon_utils.disable("rigify", default_set=True)


@pytest.fixture
def rig(bpy_blank):
    """Rigify's basic human (no fingers, no face)."""
    yield from _generated(lambda: bpy.ops.object.armature_basic_human_metarig_add())


@pytest.fixture
def full_rig(bpy_blank):
    """Rigify's human: fingers, palms and a face (about 5 s to generate)."""
    yield from _generated(lambda: bpy.ops.object.armature_human_metarig_add())


def _turned(data, turns: dict[str, np.ndarray], shift=(0.0, 0.0, 0.0)) -> Pose:
    rot = np.array(data.pose.rotations)
    for name, rotvec in turns.items():
        rot[data.skeleton.index(name)] = Rotation.from_rotvec(rotvec).as_matrix()
    trans = np.array(data.pose.translations)
    trans[0] += shift
    return Pose(rot, trans)


def _evaluated(rig, name: str) -> np.ndarray:
    return np.array(rig.matrix_world @ rig.pose.bones[name].matrix, dtype=float)


def test_the_rig_is_read_as_its_metarig_bones(rig):
    """One reading bone per metarig bone, with the metarig's parents and the rest pose;
    the split deform segments weigh with the bone they split."""
    from gesture_pose.blender.rigify import rigify_map

    data = read_armature(rig)
    sk = data.skeleton
    parent = {n: sk.names[p] if p >= 0 else None for n, p in zip(sk.names, sk.parents,
                                                                  strict=True)}
    assert sk.names[0] == "DEF-spine" and parent["DEF-spine"] is None
    assert parent["DEF-spine.001"] == "DEF-spine"  # through the torso, by the rest joint
    assert parent["neck"] == "DEF-spine.003" and parent["ORG-spine.006"] == "neck"
    assert parent["ORG-upper_arm.L"] == "ORG-shoulder.L"
    assert parent["ORG-thigh.R"] == "DEF-spine"
    assert not any(n.startswith(("MCH-", "tweak_")) for n in sk.names)
    assert np.abs(data.pose.rotations - np.eye(3)).max() < 1e-5
    assert np.abs(data.pose.translations).max() < 1e-5
    assert not sk.deform[sk.index("ORG-heel.02.L")] and sk.deform[sk.index("neck")]
    groups = rigify_map(rig).groups
    assert groups["DEF-upper_arm.L.001"] == "ORG-upper_arm.L"
    assert groups["DEF-spine.005"] == "neck"


def test_a_pose_is_written_through_the_controls_and_keyed(rig):
    """Arm, spine, neck, head, a leg and the root's place: Blender's evaluation of the
    reading bones gives the solved pose back (the middle of the spine up to its twist);
    the arm and leg written are switched to FK with the switch keyed; the left leg and
    right arm, left in IK, keep their planted foot and hand; only the controls are
    keyed, at one frame."""
    bpy.context.scene.frame_set(7)
    data = read_armature(rig)
    rng = np.random.default_rng(3)
    names = (*ARM_L, "DEF-spine", "DEF-spine.001", "DEF-spine.002", "DEF-spine.003",
             "neck", "ORG-spine.006", "ORG-thigh.R", "ORG-shin.R", "ORG-foot.R")
    new = _turned(data, {n: rng.normal(0.0, 0.35, 3) for n in names}, (0.05, 0.02, -0.1))
    foot = _evaluated(rig, "ORG-foot.L")[:3, 3]
    hand = _evaluated(rig, "ORG-hand.R")[:3, 3]
    written = apply_pose(rig, data, new, location_bones=[0], frame=7)

    assert {"upper_arm_fk.L", "forearm_fk.L", "hand_fk.L", "spine_fk.002", "neck", "head",
            "thigh_fk.R", "torso", "upper_arm_parent.L", "thigh_parent.R"} <= set(written)
    assert not [n for n in written if n.startswith(("DEF-", "ORG-", "MCH-"))]
    assert rig.pose.bones["upper_arm_parent.L"][IK_FK] == 1.0
    assert rig.pose.bones["thigh_parent.R"][IK_FK] == 1.0
    assert rig.pose.bones["thigh_parent.L"][IK_FK] == 0.0  # untouched: still IK
    assert rig.pose.bones["upper_arm_parent.R"][IK_FK] == 0.0
    # The switch holds at frame 7 only: its old value keyed either side, constant.
    assert keyed_frames(rig, "upper_arm_parent.L", f'["{IK_FK}"]') == [6.0, 7.0, 8.0]
    assert keyed_frames(rig, "upper_arm_fk.L", "rotation_quaternion") == [7.0]
    assert keyed_frames(rig, "torso", "location") == [7.0]
    assert keyed_frames(rig, "thigh_parent.L", f'["{IK_FK}"]') == []
    assert np.abs(_evaluated(rig, "ORG-foot.L")[:3, 3] - foot).max() < 1e-3  # IK: 0.2 mm
    assert np.abs(_evaluated(rig, "ORG-hand.R")[:3, 3] - hand).max() < 1e-3

    state = data.skeleton.forward(new)
    in_ik = {"ORG-thigh.L", "ORG-shin.L", "ORG-foot.L", "ORG-toe.L", "ORG-heel.02.L",
             "ORG-upper_arm.R", "ORG-forearm.R", "ORG-hand.R"}
    for i, name in enumerate(data.skeleton.names):
        if name in in_ik:
            continue
        got = _evaluated(rig, name)
        rot = got[:3, :3] / np.linalg.norm(got[:3, :3], axis=0)
        assert np.linalg.norm(got[:3, 3] - state.heads[i]) < 1e-4, name
        if name in ("DEF-spine.001", "DEF-spine.002"):  # the twist is the rig's
            assert rot[:, 1] @ state.frames[i][:, 1] > np.cos(np.radians(0.1)), name
        else:
            assert np.abs(rot - state.frames[i]).max() < 2e-3, name
    back = read_armature(rig)
    for name in ARM_L + ("ORG-thigh.R", "ORG-shin.R", "ORG-foot.R", "DEF-spine", "neck"):
        i = data.skeleton.index(name)
        assert np.abs(back.pose.rotations[i] - new.rotations[i]).max() < 2e-3, name
    for frame, value in ((6, 0.0), (7, 1.0), (8, 0.0), (30, 0.0)):
        bpy.context.scene.frame_set(frame)
        assert rig.pose.bones["upper_arm_parent.L"][IK_FK] == value, frame


def test_only_the_bones_allowed_are_written_and_the_root_stays(rig):
    """``bones`` limits the write to the left arm and no location is asked for: the
    spine's controls and the torso are not touched though the pose turns the chest and
    moves the root."""
    data = read_armature(rig)
    new = _turned(data, {"ORG-upper_arm.L": np.array([0.0, -0.8, 0.3]),
                         "DEF-spine.003": np.array([0.0, 0.3, 0.0])}, (0.0, 0.0, 0.2))
    chest = _evaluated(rig, "DEF-spine.003")
    written = apply_pose(rig, data, new, bones=list(ARM_L))
    assert "upper_arm_fk.L" in written
    assert not {"spine_fk.003", "torso", "neck", "head"} & set(written)
    assert np.abs(_evaluated(rig, "DEF-spine.003") - chest).max() < 1e-5
    assert tuple(rig.pose.bones["torso"].location) == (0.0, 0.0, 0.0)


def test_a_locked_control_is_not_changed(rig):
    """The FK upper arm locked about its x axis: a pose turning it there is refused,
    with the control and the lock named; nothing changes."""
    rig.pose.bones["upper_arm_fk.L"].lock_rotation[0] = True
    data = read_armature(rig)
    new = _turned(data, {"ORG-upper_arm.L": np.array([0.7, 0.0, 0.0])})
    with pytest.raises(InputError, match=r"'upper_arm_fk.L'.*locked rotation"):
        apply_pose(rig, data, new)
    assert tuple(rig.pose.bones["upper_arm_fk.L"].rotation_quaternion) == (1, 0, 0, 0)
    assert rig.pose.bones["upper_arm_parent.L"][IK_FK] == 0.0


def test_controls_name_their_limb_and_deform_groups_weigh_with_it(rig):
    """Flip Depth given the FK control of the upper arm flips the arm, and given the
    thigh's a leg (its locked heel following the foot); a mesh weighted to the arm's
    second deform segment weighs with the upper arm's reading bone; the abstraction
    tools refuse the rig."""
    from gesture_pose.blender.operators.abstraction_job import read_rig_job
    from gesture_pose.blender.operators.pose_drawing import flip_limb_depth
    from gesture_pose.blender.read_mesh import read_skinned_meshes
    from gesture_pose.blender.read_view import camera_from_object

    data = read_armature(rig)
    apply_pose(rig, data, _turned(data, {"ORG-upper_arm.L": np.array([0.9, 0.0, 0.0])}),
               insert_keys=False)
    cam = builders.add_camera(rig)
    elbow = _evaluated(rig, "ORG-forearm.L")[:3, 3]
    written = flip_limb_depth(rig, "upper_arm_fk.L",
                              camera_from_object(cam, bpy.context.scene), insert_keys=False)
    assert "upper_arm_fk.L" in written
    flipped = _evaluated(rig, "ORG-forearm.L")[:3, 3]
    shoulder = _evaluated(rig, "ORG-upper_arm.L")[:3, 3]
    assert abs(elbow[1] - shoulder[1]) > 0.05  # the camera looks along +Y
    # Mirrored along the eye rays (perspective): the depth's sign turns, its size stays.
    assert (flipped[1] - shoulder[1]) / (shoulder[1] - elbow[1]) == pytest.approx(1.0,
                                                                                   abs=0.15)

    # A leg, whose locked heel keeps its rotation and follows the foot.
    apply_pose(rig, data, _turned(read_armature(rig), {
        "ORG-thigh.R": np.array([0.5, 0.0, 0.0])}), insert_keys=False)
    knee = _evaluated(rig, "ORG-shin.R")[:3, 3]
    hip = _evaluated(rig, "ORG-thigh.R")[:3, 3]
    assert "thigh_fk.R" in flip_limb_depth(rig, "thigh_fk.R",
                                           camera_from_object(cam, bpy.context.scene),
                                           insert_keys=False)
    flipped = _evaluated(rig, "ORG-shin.R")[:3, 3]
    assert (flipped[1] - hip[1]) / (hip[1] - knee[1]) == pytest.approx(1.0, abs=0.15)

    mesh = bpy.data.meshes.new("Arm")
    mesh.from_pydata([(0.4, 0.0, 1.4), (0.5, 0.0, 1.4), (0.45, 0.05, 1.45)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("Arm", mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.modifiers.new("Armature", "ARMATURE").object = rig
    obj.vertex_groups.new(name="DEF-upper_arm.L.001").add([0, 1, 2], 1.0, "REPLACE")
    weights = read_skinned_meshes(rig, read_armature(rig).skeleton).weights
    assert np.all(weights[:, data.skeleton.index("ORG-upper_arm.L")] == 1.0)
    with pytest.raises(InputError, match="abstraction tools do not pose it"):
        read_rig_job(None, bpy.context, rig)


def test_a_pose_the_controls_cannot_give_is_refused_and_nothing_changes(rig):
    """A Limit Rotation on the FK upper arm clips it: the write is refused with the bone
    and its control named, every channel and the IK/FK switch are put back, no key."""
    limit = rig.pose.bones["upper_arm_fk.L"].constraints.new("LIMIT_ROTATION")
    limit.use_limit_x = limit.use_limit_y = limit.use_limit_z = True
    limit.owner_space = "LOCAL"
    bpy.context.view_layer.update()
    data = read_armature(rig)
    before = {pb.name: tuple(pb.rotation_quaternion) for pb in rig.pose.bones}
    new = _turned(data, {"ORG-upper_arm.L": np.array([0.0, 0.0, 0.8])})
    with pytest.raises(InputError, match=r"'ORG-upper_arm.L'.*'upper_arm_fk.L'"):
        apply_pose(rig, data, new)
    assert {pb.name: tuple(pb.rotation_quaternion) for pb in rig.pose.bones} == before
    assert rig.pose.bones["upper_arm_parent.L"][IK_FK] == 0.0
    assert rig.animation_data is None or rig.animation_data.action is None


def test_pose_stroke_poses_a_rigify_arm(registered, rig):
    """Pose Stroke on the rig's left arm, drawn where a raised arm goes: the arm's
    joints land on the stroke, through its FK controls, keyed at the frame."""
    from gesture_pose.core.stroke import distance_to_polyline

    bpy.context.scene.frame_set(4)
    data = read_armature(rig)
    cam = builders.add_camera(rig)
    target = _turned(data, {"ORG-upper_arm.L": np.array([0.0, -0.9, 0.0]),
                            "ORG-forearm.L": np.array([0.5, 0.0, 0.0])})
    state = data.skeleton.forward(target)
    idx = [data.skeleton.index(n) for n in ARM_L]
    joints = np.concatenate([state.heads[idx], state.tails[idx[-1:]]])
    t = np.linspace(0.0, 1.0, 12)[:, None]
    stroke = np.concatenate([a + t * (b - a) for a, b in zip(joints[:-1], joints[1:],
                                                             strict=True)])
    gp = builders.add_grease_pencil("Sketch", [stroke])
    assert bpy.ops.gesture_pose.pose_stroke(armature=rig.name, sketch=gp.name) == {"FINISHED"}
    assert rig.pose.bones["upper_arm_parent.L"][IK_FK] == 1.0
    assert keyed_frames(rig, "upper_arm_fk.L", "rotation_quaternion") == [4.0]
    assert keyed_frames(rig, "upper_arm_fk.R", "rotation_quaternion") == []
    after = read_armature(rig)
    posed = after.skeleton.forward(after.pose)
    pts = np.concatenate([posed.heads[idx[1:]], posed.tails[idx[-1:]]])
    px = builders.project_to_pixels(pts, cam)
    assert distance_to_polyline(px, builders.project_to_pixels(stroke, cam)).max() < 6.0


def test_pose_on_a_rigify_rig(registered, rig, monkeypatch):
    """Pose with the 2D fit replaced by the exact embedding of a known pose of the rig
    (an arm raised, a knee bent, the chest turned): Blender's evaluation of the rig
    takes the solved pose through its controls, near the known pose, keyed at the
    frame on the FK controls of the switched limbs."""
    from gesture_pose.core.gesture.depth.evaluation import joints_of
    from gesture_pose.core.gesture.solving import solving_skeleton
    from tests.blender.test_operator_inputs import _exact_fit

    data = read_armature(rig)
    known = _turned(data, {"ORG-upper_arm.L": np.array([0.0, -0.8, 0.3]),
                           "ORG-forearm.L": np.array([0.6, 0.0, 0.0]),
                           "ORG-thigh.R": np.array([0.7, 0.0, 0.0]),
                           "ORG-shin.R": np.array([-0.9, 0.0, 0.0]),
                           "DEF-spine.003": np.array([0.0, 0.25, 0.0])})
    apply_pose(rig, data, known, insert_keys=False)
    builders.add_camera(rig)
    bpy.context.scene.frame_set(6)
    sketch, truth, solving = _exact_fit(rig, monkeypatch)
    assert bpy.ops.gesture_pose.pose_drawing(armature=rig.name,
                                             sketch=sketch.name) == {"FINISHED"}
    after = read_armature(rig)
    s = solving_skeleton(after.skeleton)
    got = joints_of(s, after.skeleton, after.pose)
    want = joints_of(s, truth.skeleton, truth.pose)
    height = float(np.ptp(after.skeleton.rest_heads[:, 2]))
    err = np.linalg.norm(got - got[0] - want + want[0], axis=1) / height
    assert err.mean() < 0.05
    for name in ("upper_arm_fk.L", "forearm_fk.L", "thigh_fk.R", "shin_fk.R"):
        assert keyed_frames(rig, name, "rotation_quaternion") == [6.0], name


def test_partial_copies_have_no_control_and_locked_bones_are_refused(full_rig):
    """The human's palms .02 and .03 copy the palm control at a third and two thirds:
    only palm .04, its whole copy, is posed through it (the two others follow part-way,
    as the rig has them); a pose turning palm .02 or palm .01, locked deform bones, is
    refused with the lock named, and nothing changes."""
    data = read_armature(full_rig)
    rig_map = data.rigify
    assert rig_map.controls.get("ORG-palm.04.L") == "palm.L"
    assert "DEF-palm.02.L" not in rig_map.controls
    assert rig_map.controls.get("DEF-palm.01.L") == "DEF-palm.01.L"
    before = {pb.name: tuple(pb.rotation_quaternion) for pb in full_rig.pose.bones}
    assert "DEF-palm.02.L" in rig_map.partial
    for name in ("DEF-palm.02.L", "DEF-palm.01.L"):
        new = _turned(data, {name: np.array([0.0, 0.0, 0.2])})
        with pytest.raises(InputError, match=rf"'{name}'.*locked"):
            apply_pose(full_rig, data, new)
    assert {pb.name: tuple(pb.rotation_quaternion) for pb in full_rig.pose.bones} == before
    new = _turned(data, {"ORG-palm.04.L": np.array([0.0, 0.0, 0.2])})
    assert "palm.L" in apply_pose(full_rig, data, new)
    want = data.skeleton.forward(new).frames[data.skeleton.index("ORG-palm.04.L")]
    got = _evaluated(full_rig, "ORG-palm.04.L")[:3, :3]
    assert np.abs(got / np.linalg.norm(got, axis=0) - want).max() < 2e-3


def test_fingers_and_face_of_the_full_human(full_rig):
    """On Rigify's human: palms hang from the hands, each finger is read as its FK
    control; turning the neck, head, left arm and a finger of the right hand (its arm in
    IK: the finger is posed from the hand the solver saw, so the arm is switched to FK)
    gives the solved pose back on every reading bone, the face following the head."""
    rig = full_rig
    data = read_armature(rig)
    sk = data.skeleton
    parent = {n: sk.names[p] if p >= 0 else None for n, p in zip(sk.names, sk.parents,
                                                                  strict=True)}
    assert parent["DEF-palm.01.L"] == "ORG-hand.L"
    assert parent["f_index.01.L"] == "DEF-palm.01.L" and parent["f_index.02.L"] == "f_index.01.L"
    rng = np.random.default_rng(5)
    new = _turned(data, {n: rng.normal(0.0, 0.35, 3) for n in (
        "neck", "ORG-spine.006", *ARM_L, "f_index.01.R", "f_index.02.R", "thumb.01.R")})
    written = apply_pose(rig, data, new, frame=2)
    assert {"f_index.01.R", "thumb.01.R", "upper_arm_parent.R", "upper_arm_parent.L",
            "neck", "head"} <= set(written)
    assert rig.pose.bones["upper_arm_parent.R"][IK_FK] == 1.0
    assert rig.pose.bones["thigh_parent.L"][IK_FK] == 0.0
    assert keyed_frames(rig, "f_index.02.R", "rotation_quaternion") == [2.0]
    state = sk.forward(new)
    for i, name in enumerate(sk.names):
        got = _evaluated(rig, name)
        rot = got[:3, :3] / np.linalg.norm(got[:3, :3], axis=0)
        assert np.linalg.norm(got[:3, 3] - state.heads[i]) < 1e-4, name
        if name not in ("DEF-spine.001", "DEF-spine.002"):
            assert np.abs(rot - state.frames[i]).max() < 2e-3, name


def test_pose_stick_figure_on_a_rigify_rig(registered, rig):
    """A stick figure drawn over the rig (the projection of a known pose: an arm
    raised, a knee bent): the metarig's spine gives the pelvis and the head control the
    head; Blender's evaluation of the rig gives the first suggestion back, which lies on
    the drawing; the figure's place is keyed on the torso."""
    import json

    from gesture_pose.blender.read_view import camera_from_object
    from gesture_pose.core.stick.figure import character_figure

    data = read_armature(rig)
    figure, humanoid = character_figure(data.skeleton, data.ik_limits, data.roles)
    assert humanoid
    known = _turned(data, {"ORG-upper_arm.L": np.array([0.0, -0.8, 0.3]),
                           "ORG-thigh.R": np.array([0.6, 0.0, 0.0]),
                           "ORG-shin.R": np.array([-0.9, 0.0, 0.0])})
    state = data.skeleton.forward(known)
    joints = figure.joint_positions(state.heads, state.tails)
    cam_obj = builders.add_camera(rig, direction=(0.5, -1.0, 0.2))
    cam = camera_from_object(cam_obj, bpy.context.scene)
    px = cam.project(joints)
    depth = 0.5 * float(cam.depth(joints[:1])[0])
    strokes = [cam.unproject_at_depth(np.linspace(px[p], px[j], 8), depth)
               for j, p in enumerate(figure.joint_parents) if p >= 0 and not figure.optional[j]]
    gp = builders.add_grease_pencil("Sketch", strokes)
    bpy.context.scene.frame_set(9)
    assert bpy.ops.gesture_pose.pose_stick_figure(armature=rig.name, sketch=gp.name,
                                                  suggestions=1, seed=2) == {"FINISHED"}
    stored = json.loads(bpy.context.scene["gesture_pose_stick_suggestions"])
    first = data.skeleton.forward(Pose(np.array(stored["rotations"][0]),
                                       np.array(stored["translations"][0])))
    want = figure.joint_positions(first.heads, first.tails)
    after = read_armature(rig)
    posed = after.skeleton.forward(after.pose)
    got = figure.joint_positions(posed.heads, posed.tails)
    np.testing.assert_allclose(got, want, atol=2e-3)
    drawn = ~figure.optional
    assert np.linalg.norm(cam.project(got)[drawn] - px[drawn], axis=1).mean() < 4.0
    assert keyed_frames(rig, "torso", "location") == [9.0]
    assert keyed_frames(rig, "upper_arm_fk.L", "rotation_quaternion") == [9.0]


def _arm_matrices(rig, frames, arm=ARM_L) -> dict:
    out = {}
    for frame in frames:
        bpy.context.scene.frame_set(frame)
        out[frame] = np.array([_evaluated(rig, n) for n in arm])
    return out


def test_the_switch_keeps_the_other_frames_and_refuses_when_it_cannot(rig):
    """The arm's IK hand keyed at frames 1 and 20: writing the arm at frame 10 switches
    it to FK there only, every other frame shows what it did. Solver noise does not
    switch a limb; with Insert Keys off on an animated rig, or with the switch itself
    animated around the frame, the write is refused and nothing changes."""
    hand = rig.pose.bones["hand_ik.L"]
    for frame, x in ((1, 0.0), (20, 0.25)):
        hand.location = (x, 0.0, 0.0)
        hand.keyframe_insert("location", frame=frame)
    frames = (1, 5, 9, 11, 15, 20)
    before = _arm_matrices(rig, frames)
    bpy.context.scene.frame_set(10)
    data = read_armature(rig)
    assert apply_pose(rig, data, _turned(data, {"ORG-upper_arm.R": np.full(3, 1e-5)})) == []
    assert rig.pose.bones["upper_arm_parent.R"][IK_FK] == 0.0
    new = _turned(data, {"ORG-forearm.L": np.array([0.9, 0.0, 0.0])})
    with pytest.raises(InputError, match=r"'upper_arm_parent.L'.*Insert Keys"):
        apply_pose(rig, data, new, insert_keys=False)
    assert rig.pose.bones["upper_arm_parent.L"][IK_FK] == 0.0
    apply_pose(rig, data, new, frame=10)
    after = _arm_matrices(rig, frames)
    for frame in frames:
        np.testing.assert_allclose(after[frame], before[frame], atol=1e-6, err_msg=frame)
    bpy.context.scene.frame_set(10)
    elbow = data.skeleton.forward(new).frames[data.skeleton.index("ORG-forearm.L")]
    got = _evaluated(rig, "ORG-forearm.L")[:3, :3]
    assert np.abs(got / np.linalg.norm(got, axis=0) - elbow).max() < 2e-3

    # Blocking: the right arm posed at frame 10, then again at frame 14 where the torso
    # is lowered, so that its IK stretches the arm: frame 10 keeps its FK pose (the FK
    # controls' scale, first keyed at 14, is keyed at 10 too as it was).
    right = ("ORG-upper_arm.R", "ORG-forearm.R", "ORG-hand.R")
    data = read_armature(rig)
    apply_pose(rig, data, _turned(data, {"ORG-forearm.R": np.array([0.6, 0.0, 0.0])}))
    assert keyed_frames(rig, "upper_arm_fk.R", "scale") == []
    torso = rig.pose.bones["torso"]
    for frame, z in ((10, 0.0), (14, -0.12)):
        torso.location = (0.0, 0.0, z)
        torso.keyframe_insert("location", frame=frame)
    at_10 = _arm_matrices(rig, (10,), right)[10]
    bpy.context.scene.frame_set(14)
    data = read_armature(rig)
    written = apply_pose(rig, data, _turned(data, {
        "ORG-upper_arm.R": np.array([0.0, 0.7, 0.0]),
        "ORG-forearm.R": np.array([0.3, 0.0, 0.0])}))
    assert "upper_arm_parent.R" in written
    assert keyed_frames(rig, "upper_arm_parent.R", f'["{IK_FK}"]') == [9.0, 10.0, 11.0,
                                                                          13.0, 14.0, 15.0]
    assert keyed_frames(rig, "upper_arm_fk.R", "scale") == [10.0, 14.0]
    np.testing.assert_allclose(_arm_matrices(rig, (10,), right)[10], at_10, atol=1e-6)
    # And at the very next frame: both stay FK, each with its own pose.
    at_14 = _arm_matrices(rig, (14,), right)[14]
    bpy.context.scene.frame_set(15)
    data = read_armature(rig)
    apply_pose(rig, data, _turned(data, {"ORG-forearm.R": np.array([1.0, 0.0, 0.0])}))
    assert keyed_frames(rig, "upper_arm_parent.R", f'["{IK_FK}"]') == [9.0, 10.0, 11.0,
                                                                          13.0, 14.0, 15.0,
                                                                          16.0]
    np.testing.assert_allclose(_arm_matrices(rig, (14,), right)[14], at_14, atol=1e-6)
    np.testing.assert_allclose(_arm_matrices(rig, (10,), right)[10], at_10, atol=1e-6)

    holder = rig.pose.bones["thigh_parent.L"]
    for frame, value in ((1, 0.0), (20, 1.0)):  # a blend from IK to FK over the shot
        holder[IK_FK] = value
        holder.keyframe_insert(f'["{IK_FK}"]', frame=frame)
    bpy.context.scene.frame_set(10)
    data = read_armature(rig)
    with pytest.raises(InputError, match=r"'thigh_parent.L' is animated or blends"):
        apply_pose(rig, data, _turned(data, {"ORG-shin.L": np.array([0.9, 0.0, 0.0])}))
    assert keyed_frames(rig, "thigh_parent.L", f'["{IK_FK}"]') == [1.0, 20.0]


def test_a_leg_its_ik_squashes_is_switched_as_it_shows(rig):
    """The torso lowered 10 cm squashes the IK legs (Rigify's IK stretches): turning the
    right thigh switches the leg to FK with the squash its IK showed (the FK controls
    scaled as Rigify's own snap does), and Blender gives the solved leg back."""
    rig.pose.bones["torso"].location = (0.0, 0.0, -0.1)
    bpy.context.view_layer.update()
    data = read_armature(rig)
    new = _turned(data, {"ORG-thigh.R": np.array([0.3, 0.0, 0.0])})
    written = apply_pose(rig, data, new)
    assert "thigh_fk.R" in written
    assert np.linalg.norm(rig.pose.bones["thigh_fk.R"].scale) < np.sqrt(3.0) - 1e-3
    state = data.skeleton.forward(new)
    for name in ("ORG-thigh.R", "ORG-shin.R", "ORG-foot.R"):
        i = data.skeleton.index(name)
        got = _evaluated(rig, name)
        assert np.linalg.norm(got[:3, 3] - state.heads[i]) < 1e-4, name
        rot = got[:3, :3] / np.linalg.norm(got[:3, :3], axis=0)
        assert np.abs(rot - state.frames[i]).max() < 2e-3, name
