"""The 3D step's warnings about depth orders: the count they give and the orders they name
agree."""

from __future__ import annotations

import re

import numpy as np

from gesture_pose.core.gesture.depth import DepthOptions, solve_pose3d
from gesture_pose.core.gesture.depth.synthetic import project_embedding, solving_skeleton
from gesture_pose.core.gesture.types import Occlusion
from gesture_pose.core.skeleton import Pose
from tests.core.fixtures import front_camera, tree_skeleton


def _contradictory_drawing():
    """The tree with its left arm raised 60 degrees in the view plane, and three occlusions
    that cannot all hold: the forearm behind the upper arm at two points (two orders with
    one label) and in front of it at one."""
    sk = tree_skeleton()
    s = solving_skeleton(sk)
    cam = front_camera(ortho=True)
    pose = Pose.identity(sk.n_bones)
    rot = sk.aim_local(2, np.array([0.5, 0.0, np.sqrt(3.0) / 2.0]), sk.forward(pose),
                       pose.rotations[2])
    drawn = pose.with_rotations(np.array([2]), rot[None])
    state = sk.forward(drawn)
    head, tail = cam.project(state.heads[3:4])[0], cam.project(state.tails[3:4])[0]
    points = (0.5 * (head + tail), 0.25 * head + 0.75 * tail)
    occ = (Occlusion(front_bone=2, back_bone=3, point2d=points[0], front_radius=6.0,
                     back_radius=6.0),
           Occlusion(front_bone=2, back_bone=3, point2d=points[1], front_radius=6.0,
                     back_radius=6.0),
           Occlusion(front_bone=3, back_bone=2, point2d=points[0], front_radius=6.0,
                     back_radius=6.0))
    return sk, cam, project_embedding(sk, s, drawn, cam, occlusions=occ)


def _count_and_names(warning: str) -> tuple[int, list[tuple[str, int]]]:
    """The count a warning starts with and the labels it lists, with their counts."""
    count = int(warning.split(" ", 1)[0])
    listed = warning.split(": ", 1)[1].rstrip(".").split(", ")
    names = []
    for item in listed:
        m = re.fullmatch(r"(.*) \((\d+)x\)", item)
        names.append((m.group(1), int(m.group(2))) if m else (item, 1))
    return count, names


def test_the_dropped_orders_warning_names_as_many_orders_as_it_counts():
    sk, cam, emb = _contradictory_drawing()
    res = solve_pose3d(sk, emb, cam)
    (warning,) = [w for w in res.warnings if "contradicted the drawing" in w]
    count, names = _count_and_names(warning)
    # All three are dropped; two share a label (before: "3 ... dropped:" and two labels).
    assert count == 3
    assert sorted(names) == [("occlusion arm.L behind fore.L", 1),
                             ("occlusion fore.L behind arm.L", 2)]
    assert res.ordering == ()


def test_the_unmet_orders_warning_names_as_many_orders_as_it_counts():
    sk, cam, emb = _contradictory_drawing()
    forced = solve_pose3d(sk, emb, cam, options=DepthOptions(drop_unmet_orders=False))
    (warning,) = [w for w in forced.warnings if "are not met" in w]
    count, names = _count_and_names(warning)
    unmet = [c.label for c, ok in zip(forced.ordering, forced.ordering_satisfied,
                                      strict=True) if not ok]
    assert count == len(unmet) == sum(n for _, n in names)
    assert sorted(names) == sorted((lab, unmet.count(lab)) for lab in set(unmet))
