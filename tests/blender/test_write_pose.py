"""Writing poses back: world frames, rotation modes, continuity, keys, errors and undo."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.exceptions import InputError
from gesture_pose.core.rotations import exp_map
from gesture_pose.core.skeleton import Pose

from .test_readers import MODES, blender_world, random_pose

bpy = pytest.importorskip("bpy")
from mathutils import Euler, Quaternion  # noqa: E402

from gesture_pose.blender.read_armature import read_armature  # noqa: E402
from gesture_pose.blender.write_pose import apply_pose, keyed_frames  # noqa: E402

pytestmark = pytest.mark.blender


def random_rotations(rng, n, scale=1.0):
    return exp_map(rng.normal(scale=scale, size=(n, 3)))


def values(obj, name, channel):
    return tuple(getattr(obj.pose.bones[name], channel))


@pytest.mark.parametrize("seed", [0, 1])
def test_written_pose_matches_forward_kinematics_in_every_mode(two_root_rig, seed):
    rng = np.random.default_rng(seed + 20)
    modes = MODES[4 * seed:] + MODES[:4 * seed]
    random_pose(two_root_rig, rng, modes)
    data = read_armature(two_root_rig)
    n = data.skeleton.n_bones
    moved = data.pose.translations + rng.normal(size=(n, 3))
    new = Pose(random_rotations(rng, n), moved)
    written = apply_pose(two_root_rig, data, new, insert_keys=False, location_bones=[0])
    # Only bone 0's location is written; the other bones keep their translations.
    new = Pose(new.rotations, np.r_[moved[:1], data.pose.translations[1:]])
    assert written == list(data.names)
    bpy.context.view_layer.update()
    expect = data.skeleton.forward(new)
    heads, tails, frames = blender_world(two_root_rig)
    for i, name in enumerate(data.names):
        np.testing.assert_allclose(frames[name], expect.frames[i], atol=1e-5)
        np.testing.assert_allclose(heads[name], expect.heads[i], atol=1e-5)
        np.testing.assert_allclose(tails[name], expect.tails[i], atol=1e-5)
    again = read_armature(two_root_rig)
    assert again.rotation_modes == data.rotation_modes
    np.testing.assert_allclose(again.pose.rotations, new.rotations, atol=1e-5)
    assert two_root_rig.animation_data is None


def test_keys_only_changed_bones_at_the_current_frame(two_root_rig):
    rig = two_root_rig
    for name, frame in (("hip", 1), ("prop", 3)):
        rig.pose.bones[name].rotation_quaternion = Quaternion((0.0, 0.0, 1.0), 0.2 * frame)
        rig.pose.bones[name].keyframe_insert("rotation_quaternion", frame=frame)
    rig.pose.bones["prop"].keyframe_insert("location", frame=3)
    bpy.context.scene.frame_set(7)
    before = {name: values(rig, name, "rotation_quaternion") for name in ("hip", "prop")}
    data = read_armature(rig)
    rot = data.pose.rotations.copy()
    arm, fore, spine = (data.names.index(b) for b in ("arm", "fore", "spine"))
    rot[[arm, fore, spine]] = exp_map(np.array([[0.3, 0.0, 0.1], [0.0, 0.5, 0.0],
                                                [0.2, 0.2, 0.2]]))
    new = Pose(rot, data.pose.translations + 1.0)
    written = apply_pose(rig, data, new, bones=["arm", "fore", "hip"])
    assert written == ["arm", "fore"]
    assert keyed_frames(rig, "arm", "rotation_quaternion") == [7.0]
    assert keyed_frames(rig, "fore", "rotation_quaternion") == [7.0]
    assert keyed_frames(rig, "spine", "rotation_quaternion") == []
    assert keyed_frames(rig, "arm", "location") == []
    assert keyed_frames(rig, "hip", "rotation_quaternion") == [1.0]
    assert keyed_frames(rig, "prop", "rotation_quaternion") == [3.0]
    assert keyed_frames(rig, "prop", "location") == [3.0]
    bpy.context.scene.frame_set(1)
    assert values(rig, "hip", "rotation_quaternion") == pytest.approx(before["hip"])
    np.testing.assert_allclose(values(rig, "spine", "rotation_quaternion"), (1, 0, 0, 0))
    np.testing.assert_allclose(values(rig, "arm", "location"), (0, 0, 0))
    from bpy_extras.anim_utils import action_get_channelbag_for_slot

    bag = action_get_channelbag_for_slot(rig.animation_data.action,
                                         rig.animation_data.action_slot)
    groups = {fc.data_path.split('"')[1]: fc.group.name for fc in bag.fcurves}
    assert groups["arm"] == "arm" and groups["fore"] == "fore"


def test_continuity_with_current_values(two_root_rig):
    rig = two_root_rig
    hip, spine, arm = (rig.pose.bones[n] for n in ("hip", "spine", "arm"))
    hip.rotation_quaternion = (-0.9, 0.1, -0.3, 0.2)
    spine.rotation_mode, spine.rotation_euler = "ZXY", (0.1, -0.2, 2 * np.pi + 0.3)
    arm.rotation_mode, arm.rotation_axis_angle = "AXIS_ANGLE", (-0.4, 0.0, 0.0, -1.0)
    bpy.context.view_layer.update()
    data = read_armature(rig)
    i_hip, i_spine, i_arm = (data.names.index(b) for b in ("hip", "spine", "arm"))
    nudge = exp_map(np.array([0.01, 0.02, -0.01]))
    rot = data.pose.rotations.copy()
    rot[[i_hip, i_spine, i_arm]] = rot[[i_hip, i_spine, i_arm]] @ nudge
    apply_pose(rig, data, Pose(rot, data.pose.translations), insert_keys=False)
    q = Quaternion(values(rig, "hip", "rotation_quaternion"))
    assert q.dot(Quaternion((-0.9, 0.1, -0.3, 0.2)).normalized()) > 0.99
    e = values(rig, "spine", "rotation_euler")
    assert e[2] == pytest.approx(2 * np.pi + 0.3, abs=0.05)
    angle, *axis = values(rig, "arm", "rotation_axis_angle")
    assert axis[2] < -0.9 and angle == pytest.approx(-0.4, abs=0.05)
    np.testing.assert_allclose(read_armature(rig).pose.rotations, rot, atol=1e-5)


def test_location_bones_divide_by_object_scale(two_root_rig):
    rig = two_root_rig
    data = read_armature(rig)
    t = data.pose.translations.copy()
    t[:] = [0.17, -0.34, 0.51]
    apply_pose(rig, data, Pose(data.pose.rotations, t), location_bones=["prop"])
    np.testing.assert_allclose(values(rig, "prop", "location"), np.array([0.1, -0.2, 0.3]),
                               atol=1e-6)
    np.testing.assert_allclose(values(rig, "hip", "location"), (0, 0, 0))
    assert keyed_frames(rig, "prop", "location") == [1.0]
    assert keyed_frames(rig, "prop", "rotation_quaternion") == []


def test_bad_poses_write_nothing(two_root_rig):
    rig = two_root_rig
    data = read_armature(rig)
    rot = data.pose.rotations.copy()
    rot[0] = exp_map(np.array([0.5, 0.0, 0.0]))
    rot[-1, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        apply_pose(rig, data, Pose(rot, data.pose.translations))
    with pytest.raises(InputError, match="has 2 bones"):
        apply_pose(rig, data, Pose.identity(2))
    with pytest.raises(InputError, match="out of range"):
        apply_pose(rig, data, Pose(data.pose.rotations, data.pose.translations), bones=[9])
    assert rig.animation_data is None
    np.testing.assert_allclose(read_armature(rig).pose.rotations, data.pose.rotations)


def test_undo_restores_the_previous_pose(two_root_rig):
    # Undo works headless with the bpy module once a step has been pushed.
    bpy.ops.ed.undo_push(message="before")
    data = read_armature(two_root_rig)
    n = data.skeleton.n_bones
    new = Pose(random_rotations(np.random.default_rng(5), n), data.pose.translations)
    assert len(apply_pose(two_root_rig, data, new)) == n
    bpy.ops.ed.undo_push(message="posed")
    assert bpy.ops.ed.undo() == {"FINISHED"}
    rig = bpy.data.objects["Rig"]  # undo replaces the Python objects
    assert rig.animation_data is None
    np.testing.assert_allclose(read_armature(rig).pose.rotations, data.pose.rotations,
                               atol=1e-6)
    assert bpy.ops.ed.redo() == {"FINISHED"}
    rig = bpy.data.objects["Rig"]
    np.testing.assert_allclose(read_armature(rig).pose.rotations, new.rotations, atol=1e-5)
    assert keyed_frames(rig, data.names[0], "rotation_quaternion") == [1.0]


def test_euler_mode_keys_rotation_euler(two_root_rig):
    rig = two_root_rig
    rig.pose.bones["fore"].rotation_mode = "YZX"
    data = read_armature(rig)
    i = data.names.index("fore")
    rot = data.pose.rotations.copy()
    rot[i] = Euler((0.2, -0.4, 0.6), "YZX").to_matrix()
    assert apply_pose(rig, data, Pose(rot, data.pose.translations), frame=12) == ["fore"]
    assert keyed_frames(rig, "fore", "rotation_euler") == [12.0]
    assert keyed_frames(rig, "fore", "rotation_quaternion") == []
    np.testing.assert_allclose(values(rig, "fore", "rotation_euler"), (0.2, -0.4, 0.6),
                               atol=1e-6)


# -- constrained bones posed through their controls -------------------------------------

#: A leg (deforming bones) and its two controls: the foot's IK control, shaped like the
#: foot, and a pole in front of the knee. The rig faces -Y.
LEG_ROWS = [
    ("hips", (0.0, 0.0, 1.0), (0.0, 0.0, 1.2), None, False, 0.0),
    ("thigh.L", (0.1, 0.0, 1.0), (0.1, -0.03, 0.55), "hips", False, 0.0),
    ("shin.L", (0.1, -0.03, 0.55), (0.1, 0.0, 0.1), "thigh.L", True, 0.0),
    ("foot.L", (0.1, 0.0, 0.1), (0.1, -0.15, 0.02), "shin.L", True, 0.0),
    ("foot_ik.L", (0.1, 0.0, 0.1), (0.1, -0.15, 0.02), None, False, 0.0),
    ("knee_pole.L", (0.1, -0.6, 0.55), (0.1, -0.7, 0.55), None, False, 0.0)]
#: A step: the thigh forward, the knee bent, the foot pointed (local x turns, degrees).
STEP = {"thigh.L": -40.0, "shin.L": 65.0, "foot.L": -25.0}


@pytest.fixture
def ik_leg(bpy_blank):
    """The leg with an IK chain (shin, thigh) aimed at ``foot_ik.L`` with its pole, and
    the foot copying the control's rotation; the pole angle that keeps the rest pose."""
    from sample_scenes import builders

    from .conftest import build_armature

    rig = build_armature(LEG_ROWS)
    for name in ("foot_ik.L", "knee_pole.L"):
        rig.data.bones[name].use_deform = False
    builders.constrain_ik_leg(rig, "L")
    return rig


def _step(data) -> Pose:
    rotations = np.array(data.pose.rotations)
    for name, deg in STEP.items():
        rotations[data.skeleton.index(name)] = np.array(
            Quaternion((1.0, 0.0, 0.0), np.radians(deg)).to_matrix())
    return Pose(rotations, np.array(data.pose.translations))


def _assert_shown_as_solved(rig, data, pose, names) -> None:
    """Blender's evaluation of ``names`` (constraints included) is the solved pose's."""
    bpy.context.view_layer.update()
    state = data.skeleton.forward(pose)
    for name in names:
        i = data.skeleton.index(name)
        got = np.array(rig.matrix_world @ rig.pose.bones[name].matrix)
        np.testing.assert_allclose(got[:3, 3], state.heads[i], atol=2e-3, err_msg=name)
        np.testing.assert_allclose(got[:3, :3], state.frames[i], atol=2e-3, err_msg=name)


def test_an_ik_leg_is_posed_through_its_target_pole_and_foot_control(ik_leg):
    data = read_armature(ik_leg)
    pose = _step(data)
    bpy.context.scene.frame_set(3)
    written = apply_pose(ik_leg, data, pose)
    assert sorted(written) == ["foot.L", "foot_ik.L", "knee_pole.L", "shin.L", "thigh.L"]
    _assert_shown_as_solved(ik_leg, data, pose, ("thigh.L", "shin.L", "foot.L"))
    # The controls are keyed at the current frame (the pole's location only), and so
    # are the leg's own channels, which hold the pose shown: a new read starts from it.
    assert keyed_frames(ik_leg, "foot_ik.L", "location") == [3.0]
    assert keyed_frames(ik_leg, "foot_ik.L", "rotation_quaternion") == [3.0]
    assert keyed_frames(ik_leg, "knee_pole.L", "location") == [3.0]
    assert keyed_frames(ik_leg, "knee_pole.L", "rotation_quaternion") == []
    again = read_armature(ik_leg)
    for name in STEP:
        assert keyed_frames(ik_leg, name, "rotation_quaternion") == [3.0]
        i = data.skeleton.index(name)
        np.testing.assert_allclose(again.pose.rotations[i], pose.rotations[i], atol=1e-6)


def _controls(rig) -> dict:
    return {n: (values(rig, n, "location"), values(rig, n, "rotation_quaternion"))
            for n in ("foot_ik.L", "knee_pole.L")}


def test_an_ik_chain_not_wholly_allowed_to_change_is_refused(ik_leg):
    """Moving the target moves the whole chain: with the shin left out of the bones the
    write may change, the leg is refused as before."""
    data = read_armature(ik_leg)
    before = _controls(ik_leg)
    with pytest.raises(InputError, match=r"'thigh.L' \(the IK constraint 'IK' on "
                                         r"'shin.L'\) is posed by constraints"):
        apply_pose(ik_leg, data, _step(data), bones=["thigh.L", "foot.L"])
    assert _controls(ik_leg) == before
    assert ik_leg.animation_data is None or ik_leg.animation_data.action is None


def test_controls_that_do_not_give_the_pose_back_are_put_back(ik_leg):
    """The knee locked for IK (``lock_ik_x/y/z``): the moved target cannot bend it,
    Blender's evaluation says so, and everything written, a free bone too, is put
    back."""
    shin = ik_leg.pose.bones["shin.L"]
    shin.lock_ik_x = shin.lock_ik_y = shin.lock_ik_z = True
    data = read_armature(ik_leg)
    before = _controls(ik_leg)
    pose = _step(data)
    rotations = np.array(pose.rotations)
    rotations[0] = np.array(Quaternion((0.0, 0.0, 1.0), 0.3).to_matrix())  # the hips
    with pytest.raises(InputError, match=r"could not be posed through the IK target "
                                         r"'foot_ik.L'.*Nothing was written"):
        apply_pose(ik_leg, data, Pose(rotations, pose.translations))
    assert _controls(ik_leg) == before
    assert values(ik_leg, "hips", "rotation_quaternion") == (1.0, 0.0, 0.0, 0.0)
    assert ik_leg.animation_data is None or ik_leg.animation_data.action is None


def test_a_knee_bent_backwards_is_reached_from_the_chains_own_channels(ik_leg):
    """Blender's IK starts from the chain's own channels, which hold the solved pose:
    a knee bent backwards (against its pole) comes out as solved, twist included."""
    data = read_armature(ik_leg)
    rotations = np.array(data.pose.rotations)
    for name, deg in {"thigh.L": 40.0, "shin.L": -65.0}.items():
        rotations[data.skeleton.index(name)] = np.array(
            Quaternion((1.0, 0.0, 0.0), np.radians(deg)).to_matrix())
    pose = Pose(rotations, data.pose.translations)
    apply_pose(ik_leg, data, pose, insert_keys=False)
    _assert_shown_as_solved(ik_leg, data, pose, ("thigh.L", "shin.L", "foot.L"))


def test_a_free_foot_below_an_ik_chain_keeps_its_solved_rotation(ik_leg):
    """Without the foot's Copy Rotation the foot hangs freely from the shin: given its
    solved pose after the chain is posed through its target, also when its own local
    rotation does not change."""
    ik_leg.pose.bones["foot.L"].constraints.remove(
        ik_leg.pose.bones["foot.L"].constraints["Copy Rotation"])
    data = read_armature(ik_leg)
    rotations = np.array(data.pose.rotations)
    for name, deg in {"hips": 20.0, "thigh.L": -40.0, "shin.L": 65.0}.items():
        rotations[data.skeleton.index(name)] = np.array(
            Quaternion((1.0, 0.0, 0.0), np.radians(deg)).to_matrix())
    pose = Pose(rotations, data.pose.translations)
    apply_pose(ik_leg, data, pose, bones=["hips", "thigh.L", "shin.L", "foot.L"])
    bpy.context.view_layer.update()
    state = data.skeleton.forward(pose)
    i = data.skeleton.index("foot.L")
    got = np.array(ik_leg.matrix_world @ ik_leg.pose.bones["foot.L"].matrix)
    np.testing.assert_allclose(got[:3, :3], state.frames[i], atol=2e-3)
    np.testing.assert_allclose(got[:3, 3], state.heads[i], atol=2e-3)


def test_a_pinned_control_is_not_moved(ik_leg):
    """A control in the Pinned collection stays where it is: the chain it poses is
    refused like any constrained bone."""
    pinned = ik_leg.data.collections.new("Pinned")
    pinned.assign(ik_leg.data.bones["foot_ik.L"])
    data = read_armature(ik_leg)
    before = _controls(ik_leg)
    with pytest.raises(InputError, match=r"'thigh.L' \(the IK constraint 'IK' on "
                                         r"'shin.L'\).*'foot.L' \(its constraint "
                                         r"'Copy Rotation'\)"):
        apply_pose(ik_leg, data, _step(data))
    assert _controls(ik_leg) == before


def test_a_control_keeps_its_quaternion_side_and_euler_turns(ik_leg):
    """Controls are written through their channels continuously: the foot control keyed
    at frame 1 with its quaternion on the negative side stays on that side at frame 3
    (no flip through zero between the keys)."""
    ctl = ik_leg.pose.bones["foot_ik.L"]
    ctl.rotation_quaternion = (-1.0, 0.0, 0.0, 0.0)
    ctl.keyframe_insert("rotation_quaternion", frame=1)
    bpy.context.scene.frame_set(3)
    data = read_armature(ik_leg)
    apply_pose(ik_leg, data, _step(data))
    assert np.dot(values(ik_leg, "foot_ik.L", "rotation_quaternion"), (-1, 0, 0, 0)) > 0.5


@pytest.fixture
def ik_humanoid(bpy_blank):
    """The sample humanoid with its right leg rigged with IK, the foot control raised
    25 cm so that the IK bends the knee (the leg's channels stay at rest)."""
    from sample_scenes import builders

    arm, _ = builders.build_humanoid()
    builders.add_ik_leg(arm, "R")
    arm.pose.bones["foot_ik.R"].location = (0.0, 0.25, 0.0)  # along the bone: up
    bpy.context.view_layer.update()
    return arm


def _shown(arm, names) -> dict[str, np.ndarray]:
    return {n: np.array(arm.pose.bones[n].matrix) for n in names}


def test_an_ik_leg_the_write_does_not_touch_keeps_the_pose_its_controls_give(
        ik_humanoid):
    """Only the left upper arm turns: the right leg, bent by its raised IK control, is
    not reset to its channels (at rest), and no control is moved or keyed; a Damped
    Track on the head and a Limit Rotation holding the spine elsewhere in the rig do
    not stop the write."""
    arm = ik_humanoid
    aim = bpy.data.objects.new("Aim", None)
    bpy.context.scene.collection.objects.link(aim)
    aim.location = (1.0, -1.0, 2.5)
    arm.pose.bones["head"].constraints.new("DAMPED_TRACK").target = aim
    limit = arm.pose.bones["spine"].constraints.new("LIMIT_ROTATION")
    limit.use_limit_x, limit.owner_space, limit.max_x = True, "LOCAL", 0.0
    arm.pose.bones["spine"].rotation_quaternion = Quaternion((1.0, 0.0, 0.0), 0.3)
    bpy.context.view_layer.update()
    legs = ["thigh.R", "shin.R", "foot.R", "foot_ik.R", "knee_pole.R", "head", "spine"]
    before = _shown(arm, legs)
    data = read_armature(arm)
    rotations = np.array(data.pose.rotations)
    i = data.skeleton.index("upper_arm.L")
    rotations[i] = np.array(Quaternion((0.0, 1.0, 0.0), 0.8).to_matrix()) @ rotations[i]
    assert apply_pose(arm, data, Pose(rotations, data.pose.translations),
                      frame=5) == ["upper_arm.L"]
    bpy.context.view_layer.update()
    for name, m in before.items():
        np.testing.assert_allclose(np.array(arm.pose.bones[name].matrix), m, atol=1e-5,
                                   err_msg=name)
    for name in ("foot_ik.R", "knee_pole.R", "thigh.R"):
        assert keyed_frames(arm, name, "location") == []
        assert keyed_frames(arm, name, "rotation_quaternion") == []


def test_a_leg_below_a_turned_hip_is_posed_through_its_controls(ik_humanoid):
    """The pelvis turns: the IK leg below it (its channels at rest) is posed as its
    channels say, through its target and pole, and the toe below the foot follows;
    the Damped Track head elsewhere is not checked."""
    arm = ik_humanoid
    arm.pose.bones["foot_ik.R"].location = (0.0, 0.0, 0.0)
    bpy.context.view_layer.update()
    data = read_armature(arm)
    rotations = np.array(data.pose.rotations)
    rotations[data.skeleton.index("pelvis")] = np.array(
        Quaternion((0.0, 0.0, 1.0), 0.4).to_matrix())
    pose = Pose(rotations, data.pose.translations)
    written = apply_pose(arm, data, pose, frame=5)
    assert {"pelvis", "foot_ik.R", "knee_pole.R"} <= set(written)
    bpy.context.view_layer.update()
    state = data.skeleton.forward(pose)
    for name in ("thigh.R", "shin.R", "foot.R", "toe.R"):
        k = data.skeleton.index(name)
        got = np.array(arm.matrix_world @ arm.pose.bones[name].matrix)
        np.testing.assert_allclose(got[:3, 3], state.heads[k], atol=2e-3, err_msg=name)
        np.testing.assert_allclose(got[:3, 1], state.frames[k][:, 1], atol=2e-3,
                                   err_msg=name)


def test_a_control_whose_location_is_written_is_not_moved_for_a_chain(ik_leg):
    """The foot control's own location is asked for (as a stick figure's root would
    be): it is not also moved to the chain's end, so the chain is refused."""
    data = read_armature(ik_leg)
    pose = _step(data)
    moved = np.array(pose.translations)
    moved[data.skeleton.index("foot_ik.L")] = (0.0, 0.0, 0.3)
    before = _controls(ik_leg)
    with pytest.raises(InputError, match=r"'thigh.L' \(the IK constraint 'IK' on "
                                         r"'shin.L'\)"):
        apply_pose(ik_leg, data, Pose(pose.rotations, moved), location_bones=["foot_ik.L"])
    assert _controls(ik_leg) == before


def test_without_redirects_a_constrained_leg_is_refused(ik_leg):
    """``redirect=False`` (a black-box solve, which went through the constraints): the
    IK leg is not posed through its controls, and its changed bones are refused."""
    data = read_armature(ik_leg)
    before = _controls(ik_leg)
    with pytest.raises(InputError, match=r"'thigh.L' \(the IK constraint 'IK' on "
                                         r"'shin.L'\)"):
        apply_pose(ik_leg, data, _step(data), redirect=False)
    assert _controls(ik_leg) == before
