"""Strokes -> graph -> tree matched to the humanoid's stick joints, left and right."""

from __future__ import annotations

import numpy as np
import pytest

from gesture_pose.core.exceptions import InputError
from gesture_pose.core.stick.figure import humanoid_figure
from gesture_pose.core.stick.graph import (
    build_graph,
    side_offsets,
    simplify,
    stick_figure_from_strokes,
)
from tests.core.test_stick_figure import humanoid_skeleton

# A front-view stick figure in pixels (character's left on the image's right).
P = {"pelvis": (400, 300), "neck": (400, 450), "head": (405, 510),
     "elbow.L": (470, 420), "wrist.L": (520, 350), "elbow.R": (330, 420),
     "wrist.R": (300, 480), "knee.L": (440, 200), "ankle.L": (445, 100),
     "knee.R": (350, 200), "ankle.R": (350, 95), "toe.R": (315, 85)}


def _seg(a, b, n=6):
    return np.linspace(P[a], P[b], n)


def _figure():
    return humanoid_figure(humanoid_skeleton())


def _bones():
    return [("pelvis", "neck"), ("neck", "head"), ("neck", "elbow.L"), ("elbow.L", "wrist.L"),
            ("neck", "elbow.R"), ("elbow.R", "wrist.R"), ("pelvis", "knee.L"),
            ("knee.L", "ankle.L"), ("pelvis", "knee.R"), ("knee.R", "ankle.R"),
            ("ankle.R", "toe.R")]


def test_one_stroke_per_bone_in_any_order_and_direction():
    rng = np.random.default_rng(1)
    strokes = [_seg(a, b) if rng.random() < 0.5 else _seg(b, a) for a, b in _bones()]
    order = rng.permutation(len(strokes))
    fig = stick_figure_from_strokes([strokes[i] for i in order], _figure())
    for name, p in P.items():
        assert np.allclose(fig.points[fig.joint_names.index(name)], p), name
    assert not fig.present[fig.joint_names.index("hand.L")]
    assert fig.present[fig.joint_names.index("toe.R")]
    assert fig.ambiguous_sides == ()


def test_polyline_limbs_and_t_junction_at_the_neck():
    # Spine and head as one straight stroke; arms start at a point on it (T-junction);
    # each arm and leg is one bent stroke.
    spine_head = np.linspace(P["pelvis"], P["head"], 20)
    strokes = [spine_head]
    for chain in (["neck", "elbow.L", "wrist.L"], ["neck", "elbow.R", "wrist.R"],
                  ["pelvis", "knee.L", "ankle.L"], ["pelvis", "knee.R", "ankle.R", "toe.R"]):
        pts = np.concatenate([_seg(a, b)[:-1] for a, b in zip(chain, chain[1:], strict=False)] +
                             [np.array([P[chain[-1]]])])
        strokes.append(pts[::-1] if len(chain) == 3 else pts)
    # Arm ends 6 px off the spine line: still snapped onto it.
    strokes[1] = strokes[1] + [0.0, 0.0]
    strokes[1][-1] += [6.0, 0.0]
    fig = stick_figure_from_strokes(strokes, _figure())
    neck = fig.points[fig.joint_names.index("neck")]
    assert np.linalg.norm(neck - P["neck"]) < 6.0
    for name in ("elbow.L", "wrist.R", "knee.L", "toe.R", "head"):
        assert np.allclose(fig.points[fig.joint_names.index(name)], P[name]), name


def test_left_right_follow_the_front_view_sign_test():
    strokes = [_seg(a, b) for a, b in _bones()]
    mirrored = [s * [-1, 1] + [800, 0] for s in strokes]
    fig = stick_figure_from_strokes(mirrored, _figure())
    # Mirrored drawing: the limb on the image's right is now the former right limb.
    assert np.allclose(fig.points[fig.joint_names.index("elbow.L")], [800 - 330, 420])
    back = stick_figure_from_strokes(strokes, _figure(), facing="back")
    assert np.allclose(back.points[back.joint_names.index("elbow.L")], P["elbow.R"])
    swapped = back.swapped("arms")
    assert np.allclose(swapped.points[swapped.joint_names.index("elbow.L")], P["elbow.L"])
    # Legs keep their (back-view) assignment, with the toe following its leg.
    assert swapped.present[swapped.joint_names.index("toe.L")]


def test_side_offsets_read_the_labels():
    strokes = [_seg(a, b) for a, b in _bones()]
    front = stick_figure_from_strokes(strokes, _figure())
    offsets = side_offsets(front)
    # Left elbow and wrist 70 and 120 px right of the neck, right ones -70 and -100: the
    # arms' value is the difference of their means.
    assert offsets["arms"] == pytest.approx((70 + 120) / 2 - (-70 - 100) / 2)
    assert offsets["legs"] > 0
    # Labelled from behind (Facing Back): every pair's value changes sign.
    back = stick_figure_from_strokes(strokes, _figure(), facing="back")
    assert side_offsets(back)["arms"] == pytest.approx(-offsets["arms"])
    assert side_offsets(back)["legs"] == pytest.approx(-offsets["legs"])
    assert side_offsets(front.swapped("arms"))["legs"] == pytest.approx(offsets["legs"])


def test_symmetric_limbs_are_flagged_ambiguous():
    pts = dict(P)
    P2 = {**pts, "elbow.L": (405, 380), "wrist.L": (408, 320), "elbow.R": (396, 381),
          "wrist.R": (393, 321)}
    strokes = [np.linspace(P2[a], P2[b], 5) for a, b in _bones()]
    fig = stick_figure_from_strokes(strokes, _figure(), snap_radius=0.5)
    assert "arms" in fig.ambiguous_sides and "legs" not in fig.ambiguous_sides


def test_contact_dot_is_not_a_bone():
    strokes = [_seg(a, b) for a, b in _bones()] + [np.array([[420.0, 280], [423, 281]])]
    fig = stick_figure_from_strokes(strokes, _figure())
    assert np.allclose(fig.contacts, [[421.5, 280.5]])


@pytest.mark.parametrize("drop, message", [(("pelvis", "knee.L"), "falls apart"),
                                           (None, "closed loop")])
def test_bad_drawings_raise_clear_errors(drop, message):
    bones = [b for b in _bones() if b != drop]
    strokes = [_seg(a, b) for a, b in bones]
    if drop is None:
        strokes.append(_seg("wrist.L", "knee.L"))
    with pytest.raises(InputError, match=message):
        stick_figure_from_strokes(strokes, _figure())


def test_wrong_topology_is_explained():
    bones = [b for b in _bones() if "knee.L" not in b and "ankle.L" not in b]
    with pytest.raises(InputError, match="does not match the character"):
        stick_figure_from_strokes([_seg(a, b) for a, b in bones], _figure())


def test_straight_arm_without_elbow_does_not_match():
    bones = [b for b in _bones() if b[1] not in ("elbow.L", "wrist.L")]
    strokes = [_seg(a, b) for a, b in bones] + [_seg("neck", "wrist.L")]
    with pytest.raises(InputError, match="bent at the elbow"):
        stick_figure_from_strokes(strokes, _figure())


def test_graph_nodes_and_corners():
    pts = np.array([[0, 0], [50, 1], [100, 0], [100, 60], [101, 120.0]])
    assert simplify(pts, 3.0).tolist() == [0, 2, 4]
    g = build_graph([pts, [[100, 0], [160, -40]]], snap_radius=5)
    assert len(g.nodes) == 4 and sorted(g.degrees().tolist()) == [1, 1, 1, 3]


def _animal():
    """A four-legged skeleton: body, a 3-bone neck, two-bone legs (hind from the hips)."""
    from gesture_pose.core.skeleton import Skeleton
    from tests.core.fixtures import frame_along
    rows = [("hips", None, (0, 0, 1.0), (0, -0.6, 1.0)),
            ("neck", "hips", (0, -0.6, 1.0), (0, -0.8, 1.3)),
            ("neck.001", "neck", (0, -0.8, 1.3), (0, -0.95, 1.5)),
            ("head", "neck.001", (0, -0.95, 1.5), (0, -1.2, 1.45))]
    for side, sx in (("L", 1), ("R", -1)):
        rows += [(f"front_upper.{side}", "hips", (0.15 * sx, -0.6, 1.0),
                  (0.15 * sx, -0.65, 0.5)),
                 (f"front_lower.{side}", f"front_upper.{side}", (0.15 * sx, -0.65, 0.5),
                  (0.15 * sx, -0.6, 0.0)),
                 (f"hind_upper.{side}", "hips", (0.15 * sx, 0.0, 1.0), (0.15 * sx, 0.1, 0.5)),
                 (f"hind_lower.{side}", f"hind_upper.{side}", (0.15 * sx, 0.1, 0.5),
                  (0.15 * sx, 0.0, 0.0))]
    order = {r[0]: i for i, r in enumerate(rows)}
    heads = np.array([r[2] for r in rows], float)
    tails = np.array([r[3] for r in rows], float)
    n = len(rows)
    return Skeleton(tuple(r[0] for r in rows),
                    np.array([order[r[1]] if r[1] else -1 for r in rows]), heads, tails,
                    np.stack([frame_along(t - h) for h, t in zip(heads, tails, strict=True)]),
                    np.ones(n, bool), np.zeros(n, bool), np.ones(n, bool))


def test_non_humanoid_matched_by_topology():
    from gesture_pose.core.camera import Camera
    from gesture_pose.core.stick.figure import character_figure
    sk = _animal()
    fig, humanoid = character_figure(sk)
    assert not humanoid and fig.n_joints == sk.n_bones + 1
    cam = Camera.look_at([3.0, -2.0, 1.0], [0, -0.4, 0.7], width=800, height=600)
    pos = fig.joint_positions(sk.rest_heads, sk.rest_tails)
    px = cam.project(pos)
    strokes = [np.linspace(px[p], px[c], 5) for c, p in enumerate(fig.joint_parents) if p >= 0]
    stick = stick_figure_from_strokes(strokes[::-1], fig, snap_radius=6.0)
    assert np.allclose(stick.points, px, atol=1e-6) or stick.ambiguous_sides == ("limbs",)
    # The neck (3 segments) is never taken for a leg (2 segments).
    for name in ("neck", "neck.001", "head"):
        assert np.allclose(stick.points[fig.joint(name)], px[fig.joint(name)])


def test_symmetric_topology_is_reported_ambiguous():
    from gesture_pose.core.stick.figure import topology_figure
    from tests.core.fixtures import tree_skeleton
    sk = tree_skeleton()
    fig = topology_figure(sk)
    pos = fig.joint_positions(sk.rest_heads, sk.rest_tails)[:, [0, 2]] * 200 + 400
    strokes = [np.linspace(pos[p], pos[c], 5) for c, p in enumerate(fig.joint_parents)
               if p >= 0]
    with pytest.raises(InputError, match="different ways"):
        stick_figure_from_strokes(strokes, fig, snap_radius=5.0)


def test_bone_lengths_tell_apart_chains_of_equal_segments():
    from gesture_pose.core.camera import Camera
    from gesture_pose.core.stick.figure import character_figure
    from tests.core.test_stick_figure import quadruped_skeleton
    sk = quadruped_skeleton()
    fig, _ = character_figure(sk)
    cam = Camera.look_at([3.0, -3.0, 1.8], [0, 0, 0.5], width=960, height=960)
    px = cam.project(fig.joint_positions(sk.rest_heads, sk.rest_tails))
    strokes = [np.linspace(px[p], px[c], 5) for c, p in enumerate(fig.joint_parents)
               if p >= 0]
    # By topology alone the 3-bone neck and the 3-bone front legs can be exchanged.
    with pytest.raises(InputError, match="different ways"):
        stick_figure_from_strokes(strokes, fig, snap_radius=8.0)
    stick = stick_figure_from_strokes(strokes, fig, snap_radius=8.0,
                                      lengths=fig.edge_lengths(sk))
    for name in ("neck", "neck.001", "head", "chest", "tail.005"):
        assert np.allclose(stick.points[fig.joint(name)], px[fig.joint(name)])
    # Legs land on drawn legs (left and right may be exchanged: flagged).
    for side in "LR":
        other = "R" if side == "L" else "L"
        got = stick.points[fig.joint(f"front_paw.{side}")]
        assert min(np.linalg.norm(got - px[fig.joint(f"front_paw.{s}")])
                   for s in (side, other)) < 1e-6
    assert stick.ambiguous_sides == ("limbs",)
