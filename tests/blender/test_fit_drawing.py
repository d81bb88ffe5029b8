"""Headless tests of Fit Drawing and Trace Contours on the sample humanoid.

Drawings are the traced visible contours of known poses (how Gesture3D validated itself);
the fitted joints are compared with the true joints projected in the same view, in percent
of the figure's projected height.
"""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.blender.operators import fit_drawing as op
from gesture_pose.blender.read_armature import read_armature
from gesture_pose.blender.read_view import camera_from_object
from gesture_pose.core.gesture.embedding import posed_joints

bpy = pytest.importorskip("bpy")
builders = pytest.importorskip("sample_scenes.builders")


def _humanoid():
    arm, _mesh = builders.build_humanoid()
    cam = builders.add_camera(arm, resolution=(800, 800))
    return arm, cam


def _posed(pose_name: str):
    """The sample humanoid in a named pose and its camera: ``(armature, core Camera)``."""
    arm, cam = _humanoid()
    builders.pose_humanoid(arm, pose_name)
    bpy.context.view_layer.update()
    return arm, camera_from_object(cam, bpy.context.scene)


def _errors(arm, emb, camera) -> np.ndarray:
    """Joint errors in % of the projected height of the posed figure, ``(J,)``."""
    data = read_armature(arm)
    truth = camera.project(posed_joints(emb.solving, data.skeleton, data.pose))
    height = np.ptp(truth[:, 1])
    return np.linalg.norm(emb.joints2d - truth, axis=1) / height * 100.0


def _trace(arm, target="Traced Contours", **kwargs):
    with bpy.context.temp_override(active_object=arm, object=arm, selected_objects=[arm]):
        assert bpy.ops.gesture_pose.trace_contours(armature=arm.name, target=target,
                                                   **kwargs) == {"FINISHED"}
    return bpy.data.objects[target]


# The check is every joint within 4% of the figure's projected height on clean traced
# contours. Measured on these drawings (this camera, framed on the rest pose), with the
# default costs (foreshortened bones: `foreshortening` 0.5 from 1 sigma, `exposed_conformity`,
# the limb re-solves after the refinement, `refined_resolves` 1, and since 367f8d4's round
# `oriented_conformity` with `resolve_rate`; docs/gesture.md):
#
#   pose            median  mean  max   joints within 4%
#   rest            0.28    0.33  1.47  100% (refined from the pose, see below)
#   step            1.49    1.52  3.21  100%
#   raise_left_arm  0.88    1.17  2.84  100%
#   reach           1.23    1.37  3.18  100%
#   crouch          1.15    1.78  3.65  100% (thighs pointing at the viewer, drawn at a third
#                                            of their length)
#
# Without `oriented_conformity` and `resolve_rate` (the round before): rest 0.36 / 0.31 /
# 0.79, step 1.68 / 2.06 / 4.00 / 88% (the pelvis group 24 px high, 4.002: the energy
# preferred it by 0.5), raise_left_arm 0.82 / 1.12 / 2.84, reach 1.23 / 1.38 / 3.18,
# crouch 1.32 / 1.67 / 3.58.
#
# (Coverage traded for energy at a rate, embedding._accepts: before it the step's left toe
# was 4.07 off, its foot lying on the shin's outline, and the crouch's worst joint 3.95.)
#
# With the paper's costs for those bones (`foreshortening` 0, `exposed_conformity` False,
# `refined_resolves` 0; the defaults before this round): step 2.55 / 2.51 / 5.14 / 80% (the
# right elbow 5.1), crouch 2.08 / 3.28 / 21.0 / 88% (Eq. 2 costs thighs drawn at a third of
# their length nearly 1, so the fit made them long and the shins short: the knees 17-21),
# the other three within 0.3 of the above.
#
# Before the search's three changes (rigid joints without a unary term in
# E_match, limb ends moved onto unexplained contours, no crossing test on bones without
# room between their joint circles; docs/gesture.md): step 0.71 / 1.03 / 4.05 / 96% (the
# left toe), reach 0.85 / 2.21 / 8.33 / 76% (the right arm stretched towards the viewer
# found short: its hand paid the consistency term for its own wrist ball), crouch 1.82 /
# 3.35 / 16.2 / 72%, rest and raise_left_arm within 0.1 of the above.
# The refinement's second start from the pose (GestureParams.bind_start) wins on the rest
# drawing: from the discrete answer the chest's rigid group stopped 20 px high.
#
# So the check holds on all five (test_every_joint_within_4_percent): the step's pelvis
# group stayed 0.002 over (4.002%) until `CostParams.oriented_conformity` gave the torso's
# links the outline where a crease meets it. The limits below are the measurements plus a
# margin for platform noise only (half a percent on the median, one joint on the share):
# the median error, and the share of joints the 4% holds for.
@pytest.mark.parametrize("pose_name,median_limit,within_limit", [
    ("step", 2.0, 0.96),
    ("rest", 0.8, 0.96),
    ("raise_left_arm", 1.4, 0.96),
    ("reach", 1.75, 0.96),
    ("crouch", 1.65, 0.96),
])
def test_fit_finds_the_joints_of_traced_poses(registered, pose_name, median_limit,
                                              within_limit):
    emb, err, n_strokes = _fit_traced(pose_name)
    assert n_strokes > 10
    names = emb.solving.joint_bones
    assert np.median(err) < median_limit, dict(zip(names, err.round(1), strict=True))
    assert np.mean(err <= 4.0) >= within_limit, dict(zip(names, err.round(1), strict=True))
    assert 0.5 < emb.coverage <= 1.0
    assert emb.timings["total"] > 0.0  # speed is the benchmark's (make bench), not a test's
    # The refinement's start from the pose wins on the rest drawing only (when it came in:
    # E_match 4.67 against 7.90 from the discrete solution; the moved poses keep the
    # discrete walk).
    assert emb.terms["pose_start"] == int(pose_name == "rest")


def _fit_traced(pose_name: str):
    """Fit the clean traced contours of a pose; ``(embedding, errors %h, strokes)``."""
    arm, camera = _posed(pose_name)
    sketch = _trace(arm)
    emb, n_strokes = op.fit_scene_drawing(arm, sketch, camera)
    return emb, _errors(arm, emb, camera), n_strokes


@pytest.mark.parametrize("pose_name", [
    "rest",
    "step",
    "raise_left_arm",
    "reach",
    "crouch",
])
def test_every_joint_within_4_percent(registered, pose_name):
    emb, err, _ = _fit_traced(pose_name)
    assert err.max() <= 4.0, dict(zip(emb.solving.joint_bones, err.round(1), strict=True))


def test_fit_operator_writes_only_its_overlay_layer(registered):
    arm, camera = _posed("step")
    sketch = _trace(arm)
    user = sketch.data.layers["Lines"].current_frame().drawing
    before = np.array([p.position[:] for s in user.strokes for p in s.points])
    for _ in range(2):  # fitting again replaces the overlay, it does not add to it
        with bpy.context.temp_override(active_object=arm, object=arm):
            assert bpy.ops.gesture_pose.fit_drawing(armature=arm.name,
                                                    sketch=sketch.name) == {"FINISHED"}
        fit = sketch.data.layers[op.FIT_LAYER].current_frame().drawing
        n_fit = len(fit.strokes)
        emb, _ = op.fit_scene_drawing(arm, sketch, camera)
        expected = sum(len(v) for v in op.fit_overlay(emb).values())
        assert n_fit == expected
    user = sketch.data.layers["Lines"].current_frame().drawing
    after = np.array([p.position[:] for s in user.strokes for p in s.points])
    np.testing.assert_array_equal(before, after)
    assert [layer.name for layer in sketch.data.layers] == ["Lines", op.FIT_LAYER]


def test_fit_report_names_the_drawing_settings_it_read_with(registered, capfd):
    """Facing and Body Up stay set on the scene for the next drawing: the report says
    when they are not As Seen and Up."""
    arm, _ = _posed("step")
    sketch = _trace(arm)
    for kwargs, note in (({}, ""), ({"facing": "back", "body_up": "down"},
                                    "; read with Facing Back, Body Up Down")):
        capfd.readouterr()
        with bpy.context.temp_override(active_object=arm, object=arm):
            assert bpy.ops.gesture_pose.fit_drawing(armature=arm.name, sketch=sketch.name,
                                                    **kwargs) == {"FINISHED"}
        line = next(x for x in capfd.readouterr().out.splitlines() if "Fitted" in x)
        assert line.endswith("%" + note), line


def test_curve_sketch_from_svg_is_accepted(registered):
    """Vector drawings arrive as curve objects (Blender's SVG importer makes curves)."""
    arm, camera = _posed("reach")
    obj = _curve_sketch(arm, camera)
    emb, n = op.fit_scene_drawing(arm, obj, camera)
    assert n == len(obj.data.splines) == len(op.trace_character(arm, camera).pixels)
    assert np.median(_errors(arm, emb, camera)) < 5.0


def _curve_sketch(arm, camera):
    """The traced contours of ``arm`` as a curve object (what the SVG importer makes)."""
    traced = op.trace_character(arm, camera)
    curve = bpy.data.curves.new("Svg", "CURVE")
    curve.dimensions = "3D"
    for pts in traced.world(camera):
        spline = curve.splines.new("POLY")
        spline.points.add(len(pts) - 1)
        spline.points.foreach_set("co", np.c_[pts, np.ones(len(pts))].ravel())
    obj = bpy.data.objects.new("Svg", curve)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.update()
    return obj


def _curve_points(obj) -> np.ndarray:
    out = []
    for spline in obj.data.splines:
        co = np.zeros(4 * len(spline.points))
        spline.points.foreach_get("co", co)
        out.append(co)
    return np.concatenate(out)


def test_curve_sketch_gets_a_fit_overlay_object(registered):
    """A curve sketch cannot hold Grease Pencil strokes: its fit goes to its own object."""
    arm, camera = _posed("step")
    sketch = _curve_sketch(arm, camera)
    before = _curve_points(sketch)
    n_objects = len(bpy.data.objects)
    for _ in range(2):  # fitting again replaces the overlay in the same object
        with bpy.context.temp_override(active_object=arm, object=arm):
            assert bpy.ops.gesture_pose.fit_drawing(armature=arm.name,
                                                    sketch=sketch.name) == {"FINISHED"}
        fits = [o for o in bpy.data.objects if o.get(op.FIT_OF) == sketch.name]
        assert len(fits) == 1 and fits[0].type == "GREASEPENCIL"
        assert len(bpy.data.objects) == n_objects + 1
        fit = fits[0]
        assert [layer.name for layer in fit.data.layers] == [op.FIT_LAYER]
        emb, _ = op.fit_scene_drawing(arm, sketch, camera)
        expected = sum(len(v) for v in op.fit_overlay(emb).values())
        assert len(fit.data.layers[op.FIT_LAYER].current_frame().drawing.strokes) == expected
    # The joints drawn in the overlay lie where the fit put them, seen in the view.
    drawing = fit.data.layers[op.FIT_LAYER].current_frame().drawing
    pts = np.array([p.position[:] for s in drawing.strokes for p in s.points])
    seen = camera.project(pts)
    for centre in emb.joints2d[:3]:
        assert np.min(np.linalg.norm(seen - centre, axis=1)) < max(emb.joint_radius) + 1.0
    np.testing.assert_array_equal(_curve_points(sketch), before)
    assert sketch.type == "CURVE"
    with pytest.raises(op.InputError, match="is the fit shown for"):
        op.fit_scene_drawing(arm, fit, camera)
    # Searching for a sketch (none named or picked) never settles on the overlay.
    from gesture_pose.blender.operator_utils import resolve_sketch

    assert not [o for o in bpy.context.scene.objects
                if o.type == "GREASEPENCIL" and o is not fit]
    with bpy.context.temp_override(active_object=fit, selected_objects=[fit]):
        with pytest.raises(op.InputError, match="No sketch"):
            resolve_sketch(bpy.context)


def test_bad_input_is_reported(registered):
    arm, cam = _humanoid()
    camera = camera_from_object(cam, bpy.context.scene)
    empty = builders.add_grease_pencil("Empty", [])
    with pytest.raises(op.InputError, match="no strokes"):
        op.fit_scene_drawing(arm, empty, camera)
    # A scribble far smaller than the character in the view.
    centre = np.array(builders.joint_positions(arm)["chest"][0])
    tiny = [centre + np.array([[0, -0.2, 0], [0.01, -0.2, 0.01], [0.02, -0.2, 0]])]
    small = builders.add_grease_pencil("Small", tiny)
    with pytest.raises(op.InputError, match="far smaller"):
        op.fit_scene_drawing(arm, small, camera)
    with bpy.context.temp_override(active_object=arm, object=arm), \
            pytest.raises(RuntimeError, match="far smaller"):
        bpy.ops.gesture_pose.fit_drawing(armature=arm.name, sketch=small.name)
    # An armature without a mesh cannot measure the joint radii.
    bpy.data.objects.remove(bpy.data.objects[arm.name + "_Mesh"])
    sketch = builders.add_grease_pencil("Sketch", [centre + np.array([[-0.5, -0.2, -0.8],
                                                                       [0.5, -0.2, 0.8]])])
    with pytest.raises(op.InputError, match="mesh"):
        op.fit_scene_drawing(arm, sketch, camera)


def test_overlay_colours_joints_by_the_side_of_their_bone():
    # The side of the bone's name in any convention core/names.py reads (before, names
    # such as 'Bip01 L Thigh' were drawn in the right side's colour).
    names = ("Bip01 L Thigh tail", "thigh.R head", "spine tail", "mixamorig:LeftArm tail",
             "arm_joint_L_1 tail", "DEF-shin.R.001 tail")
    assert [op._side(n) for n in names] == ["L", "R", "C", "L", "L", "R"]
