"""Every operator's bad-input paths and its keys, in headless Blender.

The project's rule: bad input (no armature, an empty drawing, a stroke far from the
character, NaNs, a bone along the view axis) gets a clear message naming the problem and
changes nothing; a successful run keys only the bones it changed, only at the current
frame, and leaves keys on other frames, other bones and the user's strokes alone. The
cases here are those the mode's own test files do not already check (see each test).

A refusal is checked three ways: the operator's ``execute`` returned ``{'CANCELLED'}``
(spied on :class:`GesturePoseOperatorMixin`), Blender raised the ERROR report with the
message, and a snapshot of the scene (every pose bone's ``matrix_basis``, every key of the
armature's action, every Grease Pencil stroke of every layer and frame, the objects and
the stick mode's stored pins, swaps and suggestions) is identical before and after.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from gesture_pose.blender import operator_utils
from gesture_pose.blender.operators import pose_drawing
from gesture_pose.blender.read_armature import read_armature
from gesture_pose.blender.stick_io import (
    PINS_PROPERTY,
    SUGGESTIONS_PROPERTY,
    SWAPS_PROPERTY,
    base_pose,
    read_pins,
    read_suggestions,
    store_suggestions,
)
from gesture_pose.blender.write_pose import rotation_channel
from gesture_pose.core.gesture.depth.synthetic import project_embedding
from gesture_pose.core.gesture.solving import solving_skeleton
from gesture_pose.core.stick.figure import character_figure
from sample_scenes import abstraction_builders as ab
from sample_scenes import builders
from sample_scenes import stick_builders as sb

from .conftest import add_empty, build_armature, constrain

bpy = pytest.importorskip("bpy")

#: The current frame of every scene here; keys preset on OTHER_FRAME must survive.
FRAME = 5
OTHER_FRAME = 2
_BONE = re.compile(r'pose\.bones\["(.+?)"\]')


# -- snapshots ---------------------------------------------------------------------------


def _keys(arm) -> dict[tuple[str, int], np.ndarray]:
    """Every key of the armature's action: ``{(data path, index): (k, 2) frame, value}``."""
    from bpy_extras.anim_utils import action_get_channelbag_for_slot

    anim = arm.animation_data
    if anim is None or anim.action is None:
        return {}
    bag = action_get_channelbag_for_slot(anim.action, anim.action_slot)
    out = {}
    for fc in bag.fcurves if bag is not None else ():
        co = np.empty(2 * len(fc.keyframe_points))
        fc.keyframe_points.foreach_get("co", co)
        out[(fc.data_path, fc.array_index)] = co.reshape(-1, 2)
    return out


def _strokes() -> dict[tuple[str, str, int], np.ndarray]:
    """Every Grease Pencil point position: ``{(object, layer, frame): (n, 3)}``."""
    out = {}
    for obj in bpy.data.objects:
        if obj.type != "GREASEPENCIL":
            continue
        for layer in obj.data.layers:
            for fr in layer.frames:
                pos = fr.drawing.attributes.get("position")
                n = 0 if pos is None else len(pos.data)
                flat = np.empty(3 * n, dtype=np.float32)
                if n:
                    pos.data.foreach_get("vector", flat)
                out[(obj.name, layer.name, fr.frame_number)] = flat.reshape(-1, 3)
    return out


def _snapshot(arm=None) -> dict:
    """What no refused operator may change (see the module docstring)."""
    scene = bpy.context.scene
    return {
        "pose": {} if arm is None else {pb.name: np.array(pb.matrix_basis)
                                        for pb in arm.pose.bones},
        "keys": {} if arm is None else _keys(arm),
        "strokes": _strokes(),
        "objects": sorted(bpy.data.objects.keys()),
        "stored": [scene.get(p) for p in (PINS_PROPERTY, SWAPS_PROPERTY,
                                          SUGGESTIONS_PROPERTY)],
    }


def _assert_same(before: dict, after: dict) -> None:
    assert after["objects"] == before["objects"]
    assert after["stored"] == before["stored"]
    for part in ("pose", "keys", "strokes"):
        assert after[part].keys() == before[part].keys(), part
        for k, v in before[part].items():
            np.testing.assert_array_equal(after[part][k], v, err_msg=f"{part} {k}")


def _keyed_bones(arm, before: dict[tuple[str, int], np.ndarray], frame: int) -> set[str]:
    """Bones whose keys changed since ``before``; fails if any key off ``frame`` changed."""
    after = _keys(arm)
    assert set(before) <= set(after), "an F-curve was removed"
    changed = set()
    for path, co in after.items():
        old = before.get(path, np.empty((0, 2)))
        np.testing.assert_array_equal(co[co[:, 0] != frame], old[old[:, 0] != frame],
                                      err_msg=f"keys off frame {frame} of {path}")
        if co.shape != old.shape or not np.array_equal(co, old):
            changed.add(_BONE.match(path[0]).group(1))
    return changed


# -- running operators -------------------------------------------------------------------


@pytest.fixture
def returned(monkeypatch) -> list[set[str]]:
    """What each Gesture Pose operator's ``execute`` returned, in call order."""
    seen: list[set[str]] = []
    real = operator_utils.GesturePoseOperatorMixin.execute

    def spy(self, context):
        out = real(self, context)
        seen.append(set(out))
        return out

    monkeypatch.setattr(operator_utils.GesturePoseOperatorMixin, "execute", spy)
    return seen


def _override(arm):
    if arm is None:
        return bpy.context.temp_override(active_object=None, object=None,
                                         selected_objects=[])
    return bpy.context.temp_override(active_object=arm, object=arm, selected_objects=[arm])


def _refused(returned: list, name: str, message: str, arm=None, **kwargs) -> None:
    """Run ``gesture_pose.<name>``: it must report ``message`` as an error and cancel."""
    before = _snapshot(arm)
    n = len(returned)
    with _override(arm), pytest.raises(RuntimeError, match=message):
        getattr(bpy.ops.gesture_pose, name)(**kwargs)
    assert returned[n:] == [{"CANCELLED"}]
    _assert_same(before, _snapshot(arm))


def _run(name: str, arm, **kwargs) -> set[str]:
    with _override(arm):
        return getattr(bpy.ops.gesture_pose, name)(**kwargs)


def _stick_scene(pose: str = "stand") -> dict:
    """The stick mode's sample scene (humanoid, furniture, camera, drawn figure) at FRAME."""
    bpy.context.scene.frame_set(FRAME)  # the figure is drawn in a key at FRAME
    return sb.build_stick_scene(pose)


def _nan_stroke() -> np.ndarray:
    return np.array([[0.0, -0.5, 1.0], [np.nan, -0.5, 1.2], [0.1, -0.5, 1.4]])


# -- no armature -------------------------------------------------------------------------

# Covered elsewhere: pose_stroke (test_pose_stroke.test_missing_armature_is_reported) and
# pose_drawing with a wrong name (test_pose_drawing). Here: nothing selected or picked.
NO_ARMATURE_OPS = ("pose_drawing", "fit_drawing", "trace_contours", "flip_depth",
                   "pose_stick_figure", "swap_sides", "pin_joint", "pose_abstraction",
                   "drawover")


@pytest.mark.parametrize("name", NO_ARMATURE_OPS)
def test_no_armature_is_refused(registered, returned, name) -> None:
    arm, mesh = builders.build_humanoid()
    bpy.data.objects.remove(arm)  # the mesh is left, unskinned
    builders.add_camera(mesh)
    bpy.context.scene.frame_set(FRAME)
    builders.add_grease_pencil("Sketch", [np.array([[0.0, -0.5, 1.0], [0.2, -0.5, 1.4]]),
                                          np.array([[0.0, -0.5, 0.5], [0.2, -0.5, 0.9]])])
    _refused(returned, name, "No armature: select the character's armature")


# -- an empty drawing --------------------------------------------------------------------

# Covered elsewhere: pose_stroke, pose_drawing, fit_drawing's reader (not the operator).
@pytest.mark.parametrize(("name", "kwargs", "message"), [
    ("fit_drawing", {}, "'Empty' has no strokes at frame 5"),
    ("pose_stick_figure", {}, "'Empty' has no strokes at this frame: draw a stick figure"),
    ("swap_sides", {"pair": "legs"}, "'Empty' has no strokes at this frame"),
    ("pin_joint", {"joint": "ankle.R"}, "'Empty' has no strokes at this frame"),
    ("pose_abstraction", {"abstraction": "Stick Figure"}, "no strokes at this frame"),
    ("drawover", {}, "Draw-over needs two strokes"),
])
def test_empty_drawing_is_refused(registered, returned, name, kwargs, message) -> None:
    sc = _stick_scene()
    arm = sc["armature"]
    if name == "pose_abstraction":
        ab.add_abstractions(arm, sc["mesh"])
    with _override(arm):  # a stored pin and swap: a refusal must keep them
        assert bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch="Sketch",
                                              joint="ankle.L") == {"FINISHED"}
    bpy.context.scene[SWAPS_PROPERTY] = '["arms"]'
    empty = builders.add_grease_pencil("Empty", [])
    if name == "drawover":  # one stroke only
        builders.add_strokes(empty, [np.array([[0.2, -0.5, 1.4], [0.5, -0.5, 1.2]])])
    _refused(returned, name, message, arm, armature=arm.name, sketch=empty.name, **kwargs)
    assert [p.joint for p in read_pins(bpy.context.scene)[0]] == ["ankle.L"]


# -- NaN coordinates ---------------------------------------------------------------------

# Covered elsewhere: pose_stroke. The stroke with a NaN point is drawn last, after a whole
# drawing (the stick scene's figure), and must be named.
@pytest.mark.parametrize(("name", "kwargs"), [
    ("fit_drawing", {}),
    ("pose_drawing", {}),
    ("pose_stick_figure", {}),
    ("pin_joint", {"joint": "ankle.L"}),
    ("pose_abstraction", {"abstraction": "Stick Figure"}),
    ("drawover", {}),
])
def test_nan_stroke_is_refused_and_named(registered, returned, name, kwargs) -> None:
    sc = _stick_scene()
    arm, sketch = sc["armature"], sc["sketch"]
    if name == "pose_abstraction":
        ab.add_abstractions(arm, sc["mesh"])
    builders.add_strokes(sketch, [_nan_stroke()])
    index = len(builders.read_strokes(sketch)) - 1
    _refused(returned, name, rf"Stroke {index} of layer 'Lines' has NaN", arm,
             armature=arm.name, sketch=sketch.name, **kwargs)


# -- a drawing beside the character ------------------------------------------------------


def test_fit_drawing_beside_the_character_is_refused(registered, returned) -> None:
    """test_pose_drawing checks Pose on a drawing moved beside the character; Fit Drawing
    must refuse it too, and add no fit layer to the sketch."""
    arm, _ = _front_humanoid()
    side = [np.array([[x, -0.3, 0.0], [x + 0.1, -0.3, 0.9], [x, -0.3, 1.8]])
            for x in (2.0, 2.6)]  # two outlines as tall as the character, 2 m to its left
    sketch = builders.add_grease_pencil("Sketch", side)
    _refused(returned, "fit_drawing", r"The drawing lies \d+ px beside the character", arm,
             armature=arm.name, sketch=sketch.name)
    assert [layer.name for layer in sketch.data.layers] == ["Lines"]


# -- Flip Depth --------------------------------------------------------------------------


def _front_humanoid():
    """The humanoid at rest, an orthographic front camera, at FRAME."""
    arm, mesh = builders.build_humanoid()
    builders.add_camera(arm, ortho=True)
    bpy.context.scene.frame_set(FRAME)
    return arm, mesh


def _preset_keys(arm, changed: str, untouched: str) -> None:
    """Keys the run must keep: ``changed`` keyed at OTHER_FRAME, ``untouched`` at both."""
    pb = arm.pose.bones[changed]
    pb.keyframe_insert(rotation_channel(pb.rotation_mode), frame=OTHER_FRAME)
    other = arm.pose.bones[untouched]
    for f in (OTHER_FRAME, FRAME):
        other.keyframe_insert(rotation_channel(other.rotation_mode), frame=f)
        other.keyframe_insert("location", frame=f)


def test_flip_depth_refusals_change_nothing(registered, returned) -> None:
    arm, _ = _front_humanoid()
    _preset_keys(arm, "forearm.L", "head")
    arm.data.bones.active = None
    _refused(returned, "flip_depth", "no bone named 'wing'", arm, armature=arm.name,
             bone="wing")
    _refused(returned, "flip_depth", "No bone to flip: select the first bone", arm,
             armature=arm.name)


def test_flip_depth_of_a_limb_in_the_view_plane_does_nothing(registered, returned) -> None:
    # An arm lying in the plane y = 0, seen from the front by an orthographic camera.
    arm = build_armature([("body", (0, 0, 0), (0, 0, 1), None, False, 0.0),
                          ("arm", (0, 0, 1), (1, 0, 1), "body", True, 0.0),
                          ("fore", (1, 0, 1), (1.5, 0, 1.8), "arm", True, 0.3)])
    builders.add_camera((0.0, 0.0, 1.0), distance=6.0, ortho=True)
    bpy.context.scene.frame_set(FRAME)
    _preset_keys(arm, "fore", "body")
    before = _snapshot(arm)
    assert _run("flip_depth", arm, armature=arm.name, bone="arm") == {"CANCELLED"}
    assert returned[-1] == {"CANCELLED"}
    _assert_same(before, _snapshot(arm))


def test_flip_depth_keys_only_the_limb_at_the_current_frame(registered, returned) -> None:
    arm, _ = _front_humanoid()
    # The left forearm swung towards the camera, so it has depth to flip.
    builders.apply_rotations(arm, {"forearm.L": ((1.0, 0.0, 0.0), 50.0)})
    bpy.context.view_layer.update()
    _preset_keys(arm, "forearm.L", "head")
    before, keys = _snapshot(arm), _keys(arm)
    assert _run("flip_depth", arm, armature=arm.name, bone="forearm.L") == {"FINISHED"}
    changed = _keyed_bones(arm, keys, FRAME)
    assert "forearm.L" in changed and changed <= {"forearm.L", "hand.L", "fingers.L"}
    after = _snapshot(arm)
    for name, m in before["pose"].items():
        if name not in changed:
            np.testing.assert_array_equal(after["pose"][name], m, err_msg=name)


# -- Pose Stroke: a bad stroke among good ones -------------------------------------------


def test_pose_all_strokes_with_one_far_stroke_keeps_nothing(registered, returned) -> None:
    """The good stroke's chain is solved first; the far stroke then fails: nothing is
    written, keyed or removed (test_pose_stroke checks a far stroke alone)."""
    arm, _ = _front_humanoid()
    cam = bpy.context.scene.camera
    good = builders.chain_stroke(arm, cam, ["upper_arm.L", "forearm.L", "hand.L",
                                            "fingers.L"],
                                 builders.HUMANOID_POSES["raise_left_arm"])
    far = builders.strokes_through([np.array([[3.0, 0, 3.0], [3.2, 0, 3.2]])], cam,
                                   (0.0, 0.0, 1.0))
    sketch = builders.add_grease_pencil("Sketch", [good, *far])
    _preset_keys(arm, "upper_arm.L", "head")
    _refused(returned, "pose_stroke", "farther than the pick radius", arm,
             armature=arm.name, sketch=sketch.name, all_strokes=True,
             remove_used_strokes=True)


# -- Pose: keys after a successful run ---------------------------------------------------


def _exact_fit(arm, monkeypatch):
    """Make Pose fit the exact embedding of the armature's current pose (its 2D fit
    replaced; the 3D step and the writing are the operator's), then rest the armature.

    Returns:
        ``(sketch object to pass (its one stroke is not read), the armature as read in
        that pose, its solving skeleton)``.
    """
    truth = read_armature(arm)
    builders.reset_pose(arm)
    bpy.context.view_layer.update()
    solving = solving_skeleton(truth.skeleton)

    def oracle(arm_obj, sketch_obj, camera, frame=None, params=None, facing="auto",
               body_up="up"):
        skeleton = read_armature(arm_obj).skeleton
        return project_embedding(skeleton, solving, truth.pose, camera, 0.06, "auto"), 1

    monkeypatch.setattr(pose_drawing, "fit_scene_drawing", oracle)
    sketch = builders.add_grease_pencil("Sketch", [np.array([[0.0, -1.0, 0.0],
                                                             [0.1, -1.0, 0.5]])])
    return sketch, truth, solving


def test_pose_keys_only_changed_solving_bones_at_the_current_frame(registered, returned,
                                                                   monkeypatch) -> None:
    """The 2D fit is replaced by the exact embedding of a known pose (the 3D step and the
    writing are the operator's); test_pose_drawing checks the keys' frame on a fresh rig,
    here keys set before on other frames and on a bone outside the solve must survive."""
    arm, _ = _front_humanoid()
    builders.pose_humanoid(arm, "raise_left_arm")
    bpy.context.view_layer.update()
    sketch, truth, solving = _exact_fit(arm, monkeypatch)
    outside = [n for i, n in enumerate(truth.names) if i not in set(solving.bones.tolist())]
    assert outside
    builders.apply_rotations(arm, {outside[0]: ((1.0, 0.0, 0.0), 20.0)})
    bpy.context.view_layer.update()
    _preset_keys(arm, "upper_arm.L", outside[0])
    before, keys = _snapshot(arm), _keys(arm)
    assert _run("pose_drawing", arm, armature=arm.name, sketch=sketch.name) == {"FINISHED"}
    changed = _keyed_bones(arm, keys, FRAME)
    names = set(np.array(truth.names)[solving.bones])
    assert "upper_arm.L" in changed and changed <= names
    after = _snapshot(arm)
    np.testing.assert_array_equal(after["pose"][outside[0]], before["pose"][outside[0]])
    user = {k: v for k, v in after["strokes"].items() if k[1] != pose_drawing.FIT_LAYER}
    assert user.keys() == before["strokes"].keys()
    for k, v in before["strokes"].items():
        np.testing.assert_array_equal(user[k], v)


# -- the abstraction operators: keys after a successful run -----------------------------

LEFT_ARM = {"shoulder.L", "upper_arm.L", "forearm.L", "hand.L", "fingers.L"}


def _abstraction_humanoid():
    """The humanoid with its two abstractions and a front camera, at FRAME."""
    bpy.context.scene.frame_set(FRAME)
    arm, mesh = builders.build_humanoid()
    stick, _ = ab.add_abstractions(arm, mesh)
    builders.add_camera(arm, resolution=(960, 960), margin=1.5)
    return arm, stick


@pytest.mark.parametrize("name", ["pose_abstraction", "drawover"])
def test_abstraction_operators_key_only_changed_bones_at_the_current_frame(
        registered, returned, name) -> None:
    """test_abstraction checks that undrawn bones are not keyed; here keys set before on
    another frame (on a bone that moves) and on an untouched bone must survive."""
    arm, stick = _abstraction_humanoid()
    if name == "pose_abstraction":  # the left arm's curve of the stick abstraction, raised
        rest = ab.evaluated_polylines(stick)
        builders.pose_humanoid(arm, "raise_left_arm")
        lines = ab.evaluated_polylines(stick)
        builders.pose_humanoid(arm, "rest")
        moved = int(np.argmax([np.abs(a - b).max() for a, b in zip(lines, rest,
                                                                   strict=True)]))
        strokes = [lines[moved]]
        kwargs = {"abstraction": "Stick Figure"}
    else:  # a stroke along the forearm, then the same stroke turned about the elbow
        m = np.array(arm.matrix_world)
        bone = arm.data.bones["forearm.L"]
        head, tail = (m[:3, :3] @ np.array(v) + m[:3, 3]
                      for v in (bone.head_local, bone.tail_local))
        source = head + np.linspace(0.15, 0.9, 25)[:, None] * (tail - head) + [0, -0.2, 0]
        c, s = np.cos(np.radians(50.0)), np.sin(np.radians(50.0))
        turn = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        strokes = [source, (source - head) @ turn.T + head]
        kwargs = {}
    sketch = builders.add_grease_pencil("Sketch", strokes)
    _preset_keys(arm, "forearm.L", "head")
    before, keys = _snapshot(arm), _keys(arm)
    assert _run(name, arm, armature=arm.name, sketch=sketch.name, **kwargs) == {"FINISHED"}
    changed = _keyed_bones(arm, keys, FRAME)
    assert "forearm.L" in changed and changed <= LEFT_ARM
    after = _snapshot(arm)
    for bone in set(before["pose"]) - changed:
        np.testing.assert_allclose(after["pose"][bone], before["pose"][bone], atol=1e-12,
                                   err_msg=bone)
    assert after["strokes"].keys() == before["strokes"].keys()
    for k, v in before["strokes"].items():
        np.testing.assert_array_equal(after["strokes"][k], v)


# -- Stick figures -----------------------------------------------------------------------


def _unsolved(arm) -> tuple[list[str], list[str]]:
    """The humanoid's bones the stick solve poses, and those it leaves alone."""
    data = read_armature(arm)
    figure, _ = character_figure(data.skeleton, data.ik_limits)
    _, solved = base_pose(data, figure)
    names = list(data.names)
    return [names[i] for i in solved], [n for i, n in enumerate(names) if i not in solved]


def test_pose_stick_figure_keys_only_solved_bones_at_the_current_frame(registered,
                                                                      returned) -> None:
    sc = _stick_scene("stand")
    arm = sc["armature"]
    solved, unsolved = _unsolved(arm)
    finger = next(n for n in unsolved if n.startswith("fingers"))
    builders.apply_rotations(arm, {finger: ((1.0, 0.0, 0.0), 30.0)})
    bpy.context.view_layer.update()
    _preset_keys(arm, "thigh.L", finger)
    arm.pose.bones["pelvis"].keyframe_insert("location", frame=OTHER_FRAME)
    before, keys = _snapshot(arm), _keys(arm)
    assert _run("pose_stick_figure", arm, armature=arm.name, sketch="Sketch",
                suggestions=1) == {"FINISHED"}
    changed = _keyed_bones(arm, keys, FRAME)
    assert {"pelvis", "thigh.L"} <= changed <= set(solved)
    after = _snapshot(arm)
    for name in unsolved:
        np.testing.assert_array_equal(after["pose"][name], before["pose"][name],
                                      err_msg=name)
    assert after["strokes"].keys() == before["strokes"].keys()
    for k, v in before["strokes"].items():
        np.testing.assert_array_equal(after["strokes"][k], v)


def _store_two_suggestions(arm) -> None:
    """Two stored suggestions (as a solve leaves them): the left thigh forward, then back."""
    data = read_armature(arm)
    poses = []
    for deg in (25.0, -25.0):
        builders.apply_rotations(arm, {"thigh.L": ((1.0, 0.0, 0.0), deg)})
        bpy.context.view_layer.update()
        poses.append(read_armature(arm).pose)
    builders.reset_pose(arm)
    bpy.context.view_layer.update()
    store_suggestions(bpy.context.scene, arm.name, data.skeleton.names, poses, [0.1, 0.2],
                      FRAME)


def test_next_suggestion_leaves_bones_the_solve_does_not_pose(registered, returned) -> None:
    """A bone outside the stick figure (a finger), posed after the solve, keeps its pose
    and keys: a suggestion holds every bone's rotation at the time of the solve."""
    arm, _ = _front_humanoid()
    _store_two_suggestions(arm)
    solved, unsolved = _unsolved(arm)
    finger = next(n for n in unsolved if n.startswith("fingers"))
    builders.apply_rotations(arm, {finger: ((1.0, 0.0, 0.0), 30.0)})
    bpy.context.view_layer.update()
    _preset_keys(arm, "thigh.L", finger)
    before, keys = _snapshot(arm), _keys(arm)
    assert _run("next_suggestion", arm) == {"FINISHED"}
    changed = _keyed_bones(arm, keys, FRAME)
    assert changed == {"thigh.L"}
    after = _snapshot(arm)
    for name in unsolved:
        np.testing.assert_array_equal(after["pose"][name], before["pose"][name],
                                      err_msg=name)
    assert read_suggestions(bpy.context.scene)["current"] == 1


def test_next_suggestion_refusals_change_nothing(registered, returned) -> None:
    arm, _ = _front_humanoid()
    before = _snapshot(arm)
    assert _run("next_suggestion", arm) == {"CANCELLED"}  # nothing solved yet: a warning
    _assert_same(before, _snapshot(arm))
    _store_two_suggestions(arm)
    _preset_keys(arm, "thigh.L", "head")
    stored = read_suggestions(bpy.context.scene)
    stored["names"][3] = "renamed"
    bpy.context.scene[SUGGESTIONS_PROPERTY] = json.dumps(stored)
    _refused(returned, "next_suggestion", "bones changed since the last solve", arm)
    arm.name = "Other"
    _refused(returned, "next_suggestion", "armature 'Humanoid' of the last solve is gone", arm)


def test_pin_joint_refusals_keep_the_pins(registered, returned) -> None:
    sc = _stick_scene()
    arm = sc["armature"]
    assert _run("pin_joint", arm, armature=arm.name, sketch="Sketch",
                joint="ankle.L") == {"FINISHED"}
    _refused(returned, "pin_joint", r"Surface 9 does not exist; the surfaces under "
             r"'ankle.R' are 0: Floor", arm, armature=arm.name, sketch="Sketch",
             joint="ankle.R", candidate=9)
    bpy.data.collections.new("Nothing")
    _refused(returned, "pin_joint", "No environment meshes to pin to", arm,
             armature=arm.name, sketch="Sketch", joint="ankle.R", environment="Nothing")
    _refused(returned, "pin_joint", "No collection named 'Missing'", arm,
             armature=arm.name, sketch="Sketch", joint="ankle.R", environment="Missing")


# -- Trace Contours ----------------------------------------------------------------------


def test_trace_contours_refusals_write_nothing(registered, returned) -> None:
    arm, mesh = _front_humanoid()
    _refused(returned, "trace_contours", f"'{mesh.name}' exists and is not Grease Pencil",
             arm, armature=arm.name, target=mesh.name)
    bpy.data.objects.remove(mesh)
    _refused(returned, "trace_contours", "No mesh is deformed", arm, armature=arm.name)


# -- Edit Stick Figure (modal; its poll needs a 3D View, so its methods are called here) -


class _EditStub:
    """Stands in for the modal operator: its settings, and the reports it makes."""

    armature, sketch, global_radius = "", "", 60.0
    snap_radius, facing, environment, seed = 20.0, "front", "", 0
    suggestions, use_contact, insert_keys = 1, False, True

    def __init__(self) -> None:
        self.reports: list[tuple[set[str], str]] = []

    def report(self, level, text: str) -> None:
        self.reports.append((set(level), text))


def _event(kind: str, value: str, xy=(0.0, 0.0)):
    return type("Event", (), {"type": kind, "value": value, "mouse_region_x": xy[0],
                              "mouse_region_y": xy[1]})()


def test_edit_stick_figure_refuses_bad_input_on_invoke(registered) -> None:
    from gesture_pose.blender.operators.stick import GESTUREPOSE_OT_edit_stick_figure as op

    sc = _stick_scene()
    arm, sketch = sc["armature"], sc["sketch"]
    stub = _EditStub()
    before = _snapshot(arm)
    with _override(None):
        assert op.invoke(stub, bpy.context, None) == {"CANCELLED"}
    _assert_same(before, _snapshot(arm))
    builders.add_strokes(sketch, [_nan_stroke()])
    before = _snapshot(arm)
    stub.armature, stub.sketch = arm.name, sketch.name
    with _override(arm):
        assert op.invoke(stub, bpy.context, None) == {"CANCELLED"}
    _assert_same(before, _snapshot(arm))
    assert [r[0] for r in stub.reports] == [{"ERROR"}, {"ERROR"}]
    assert stub.reports[0][1].startswith("No armature: select")
    assert re.match(r"Stroke \d+ of layer 'Lines' has NaN", stub.reports[1][1])


def test_edit_stick_figure_reports_a_failed_solve_and_goes_on(registered,
                                                             monkeypatch) -> None:
    """A solve that fails on release (SolverError, not an InputError) is reported and the
    editing goes on; the pose and keys stay as they were."""
    from gesture_pose.blender import stick_io
    from gesture_pose.blender.operators.stick import GESTUREPOSE_OT_edit_stick_figure as op
    from gesture_pose.core.exceptions import SolverError

    sc = _stick_scene()
    arm, sketch = sc["armature"], sc["sketch"]
    stub = _EditStub()
    stub._session = stick_io.StickDragSession(bpy.context, stub, arm, sketch)

    def fail(_inp):
        raise SolverError("The stick figure solver found no finite solution.")

    monkeypatch.setattr(stick_io, "solve_stick", fail)
    stick = stub._session.stick
    xy = stick.points[stick.joint_names.index("wrist.L")]
    before = _snapshot(arm)
    for kind, value, at in (("LEFTMOUSE", "PRESS", xy), ("MOUSEMOVE", "NOTHING", xy + 15.0),
                            ("LEFTMOUSE", "RELEASE", xy + 15.0)):
        assert op.modal(stub, bpy.context, _event(kind, value, at)) == {"RUNNING_MODAL"}
    assert stub.reports == [({"ERROR"}, "The stick figure solver found no finite solution.")]
    after = _snapshot(arm)
    for part in ("pose", "keys"):
        assert after[part].keys() == before[part].keys()
        for k, v in before[part].items():
            np.testing.assert_array_equal(after[part][k], v)


# -- bones posed by constraints or drivers -----------------------------------------------
# Keys on such bones would not show (Blender evaluates constraints after the pose and
# drivers over the keys): every writing operator refuses them and changes nothing.

COPY_ROTATION = r"'forearm.L' \(its constraint 'Copy Rotation'\) is posed by constraints"


def _target():
    return add_empty("Target", (0.6, -0.4, 1.9))


def test_pose_stroke_refuses_a_chain_a_constraint_poses(registered, returned) -> None:
    arm, _ = _front_humanoid()
    cam = bpy.context.scene.camera
    sketch = builders.add_grease_pencil("Sketch", [builders.chain_stroke(
        arm, cam, ["upper_arm.L", "forearm.L", "hand.L", "fingers.L"],
        builders.HUMANOID_POSES["raise_left_arm"])])
    _preset_keys(arm, "forearm.L", "head")
    c = constrain(arm, "forearm.L", "COPY_ROTATION", target=arm, subtarget="head")
    _refused(returned, "pose_stroke", COPY_ROTATION + r".*set their influence to 0\) to "
             r"pose these bones here\.$", arm, armature=arm.name, sketch=sketch.name)
    c.mute = True  # muted, it no longer poses the bone
    keys = _keys(arm)
    assert _run("pose_stroke", arm, armature=arm.name, sketch=sketch.name) == {"FINISHED"}
    assert "forearm.L" in _keyed_bones(arm, keys, FRAME)


def test_pose_refuses_an_ik_chain_and_poses_the_rest_once_it_is_pinned(
        registered, returned, monkeypatch) -> None:
    """The refusal's advice works: with the IK chain's bones in the Pinned collection,
    Pose keys the rest and leaves the chain to its constraint."""
    arm, _ = _front_humanoid()
    builders.pose_humanoid(arm, "raise_left_arm")
    builders.apply_rotations(arm, {"thigh.R": ((1.0, 0.0, 0.0), 30.0)})
    bpy.context.view_layer.update()
    sketch, _, _ = _exact_fit(arm, monkeypatch)
    constrain(arm, "forearm.L", "IK", target=_target(), chain_count=2)
    _refused(returned, "pose_drawing", r"'upper_arm.L' \(the IK constraint 'IK' on "
             r"'forearm.L'\), 'forearm.L' \(the IK constraint 'IK' on 'forearm.L'\) are "
             r"posed by constraints", arm, armature=arm.name, sketch=sketch.name)
    pinned = arm.data.collections.new("Pinned")
    for name in ("upper_arm.L", "forearm.L"):
        pinned.assign(arm.data.bones[name])
    keys = _keys(arm)
    assert _run("pose_drawing", arm, armature=arm.name, sketch=sketch.name) == {"FINISHED"}
    changed = _keyed_bones(arm, keys, FRAME)
    assert "thigh.R" in changed and not changed & {"upper_arm.L", "forearm.L"}


def test_pose_stick_figure_refuses_a_driven_thigh_and_a_constrained_pelvis(
        registered, returned) -> None:
    """The stick mode poses the whole figure (the refusal suggests no pinned bones) and
    keys the pelvis' location, which a Copy Location constraint takes over."""
    sc = _stick_scene("stand")
    arm = sc["armature"]
    for k, value in enumerate(("1.0", "0.0", "0.0", "0.0")):
        fc = arm.pose.bones["thigh.L"].driver_add("rotation_quaternion", k)
        fc.driver.type = "SCRIPTED"
        fc.driver.expression = value
    constrain(arm, "pelvis", "COPY_LOCATION", target=_target())
    _preset_keys(arm, "thigh.L", "head")
    _refused(returned, "pose_stick_figure",
             r"'thigh.L' \(a driver on its rotation_quaternion\).*'pelvis' \(its "
             r"constraint 'Copy Location', on its location\).* to pose these bones here\.$",
             arm, armature=arm.name, sketch="Sketch", suggestions=1)


def test_flip_depth_refuses_a_limb_with_a_constrained_bone(registered, returned) -> None:
    arm, _ = _front_humanoid()
    builders.apply_rotations(arm, {"forearm.L": ((1.0, 0.0, 0.0), 50.0)})
    bpy.context.view_layer.update()
    _preset_keys(arm, "forearm.L", "head")
    constrain(arm, "hand.L", "DAMPED_TRACK", target=_target())
    _refused(returned, "flip_depth", r"'hand.L' \(its constraint 'Damped Track'\)", arm,
             armature=arm.name, bone="forearm.L")


def test_drawover_refuses_a_bone_a_constraint_poses(registered, returned) -> None:
    arm, _ = _abstraction_humanoid()
    m = np.array(arm.matrix_world)
    bone = arm.data.bones["forearm.L"]
    head, tail = (m[:3, :3] @ np.array(v) + m[:3, 3] for v in (bone.head_local,
                                                             bone.tail_local))
    source = head + np.linspace(0.15, 0.9, 25)[:, None] * (tail - head) + [0, -0.2, 0]
    c, s = np.cos(np.radians(50.0)), np.sin(np.radians(50.0))
    turn = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    sketch = builders.add_grease_pencil("Sketch", [source, (source - head) @ turn.T + head])
    _preset_keys(arm, "forearm.L", "head")
    # Aimed along the forearm as it is: the character under the strokes does not move.
    aim = _target()
    aim.location = head + 2.0 * (tail - head)
    constrain(arm, "forearm.L", "DAMPED_TRACK", target=aim)
    _refused(returned, "drawover", r"'forearm.L' \(its constraint 'Damped Track'\) is "
             r"posed.*'Pinned' bone collection", arm, armature=arm.name, sketch=sketch.name)


def test_pose_poses_legs_rigged_with_ik_through_their_controls(registered, returned,
                                                               monkeypatch) -> None:
    """The whole Pose (its 2D fit replaced by the exact embedding of a known step) on
    the humanoid with both legs rigged with IK gives the legs it gives with the rig's
    constraints muted, and keys the foot controls and poles with the legs' own
    channels."""
    arm, _ = _front_humanoid()
    for side in ("L", "R"):
        builders.add_ik_leg(arm, side)
    constraints = [c for pb in arm.pose.bones for c in pb.constraints]
    assert len(constraints) == 4
    for c in constraints:
        c.mute = True
    builders.pose_humanoid(arm, "step")
    bpy.context.view_layer.update()
    sketch, _, _ = _exact_fit(arm, monkeypatch)
    legs = ["thigh.L", "shin.L", "foot.L", "thigh.R", "shin.R", "foot.R"]
    assert _run("pose_drawing", arm, armature=arm.name, sketch=sketch.name,
                insert_keys=False) == {"FINISHED"}
    plain = builders.joint_positions(arm)
    builders.reset_pose(arm)
    for c in constraints:
        c.mute = False
    keys = _keys(arm)
    assert _run("pose_drawing", arm, armature=arm.name, sketch=sketch.name) == {"FINISHED"}
    bpy.context.view_layer.update()
    rigged = builders.joint_positions(arm)
    for name in legs:
        for k in (0, 1):
            np.testing.assert_allclose(rigged[name][k], plain[name][k], atol=2e-3,
                                       err_msg=name)
    changed = _keyed_bones(arm, keys, FRAME)
    assert {"foot_ik.L", "foot_ik.R", "knee_pole.L", "knee_pole.R"} | set(legs) <= changed


def test_flip_depth_flips_a_leg_rigged_with_ik(registered, returned) -> None:
    """A leg rigged with IK, bent out of the view plane through its controls, is mirrored
    about the view plane through the hip: the knee's depth changes sign and keeps its
    place in the image, and the leg's own channels hold the pose shown."""
    from mathutils import Quaternion

    from gesture_pose.blender.write_pose import apply_pose
    from gesture_pose.core.skeleton import Pose

    arm, _ = _front_humanoid()
    builders.add_ik_leg(arm, "R")
    data = read_armature(arm)
    rotations = np.array(data.pose.rotations)
    for name, deg in {"thigh.R": -40.0, "shin.R": 65.0}.items():
        rotations[data.skeleton.index(name)] = np.array(
            Quaternion((1.0, 0.0, 0.0), np.radians(deg)).to_matrix())
    apply_pose(arm, data, Pose(rotations, data.pose.translations), insert_keys=False)
    before = builders.joint_positions(arm)
    assert _run("flip_depth", arm, armature=arm.name, bone="thigh.R") == {"FINISHED"}
    after = builders.joint_positions(arm)
    hip, knee, new_knee = before["thigh.R"][0], before["shin.R"][0], after["shin.R"][0]
    assert abs(knee[1] - hip[1]) > 0.1  # out of the view plane (the camera looks along +Y)
    np.testing.assert_allclose(new_knee - hip, (knee - hip) * [1.0, -1.0, 1.0], atol=0.01)
    read = read_armature(arm)
    state = read.skeleton.forward(read.pose)
    world = np.array(arm.matrix_world)
    for name in ("thigh.R", "shin.R", "foot.R"):
        shown = world @ np.array(arm.pose.bones[name].matrix)
        np.testing.assert_allclose(state.heads[read.skeleton.index(name)], shown[:3, 3],
                                   atol=2e-3, err_msg=name)
