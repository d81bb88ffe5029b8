"""Depth-step helpers on skeletons of several trees (a character with a separate prop)."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.gesture.depth.ordering import OrderingConstraint, drawn_as_bind
from gesture_pose.core.gesture.depth.regularity import spine_chain
from gesture_pose.core.gesture.solving import solving_skeleton
from gesture_pose.core.skeleton import Skeleton
from tests.core.fixtures import frame_along


def _forest() -> Skeleton:
    """A two-bone prop (its own root, listed first) and a four-bone body with an arm."""
    heads = np.array([[1.0, 0, 0], [1.0, 0, 0.5],                     # prop, blade
                      [0, 0, 0], [0, 0, 0.4], [0, 0, 0.8], [0, 0, 0.8]], float)
    tails = np.array([[1.0, 0, 0.5], [1.0, 0, 1.2],
                      [0, 0, 0.4], [0, 0, 0.8], [0, 0, 1.2], [0.5, 0, 0.8]], float)
    parents = np.array([-1, 0, -1, 2, 3, 3])
    frames = np.stack([frame_along(t - h, 0.1 * i) for i, (h, t) in
                       enumerate(zip(heads, tails, strict=True))])
    return Skeleton(names=("prop", "blade", "spine", "chest", "neck", "arm.L"),
                    parents=parents, rest_heads=heads, rest_tails=tails, rest_frames=frames,
                    inherit_rotation=np.ones(6, bool), connected=parents >= 0,
                    deform=np.ones(6, bool))


def test_an_order_between_separate_trees_is_not_drawn_as_at_bind():
    # Joints 0-1-2 and 3-4-5 form two trees; a blade drawn over the body's spine has no
    # chain of links to the body (the old code raised StopIteration here).
    parent = np.array([-1, 0, 1, -1, 3, 4])
    order = OrderingConstraint("occlusion", "blade over spine", np.array([5]), np.ones(1),
                               np.array([2]), np.ones(1), 0.01)
    inside = OrderingConstraint("occlusion", "in one tree", np.array([2]), np.ones(1),
                                np.array([1]), np.ones(1), 0.01)
    got = drawn_as_bind([order, inside], parent, np.ones(6), 0.5)
    assert got.tolist() == [False, True]


def test_the_spine_starts_at_the_body_not_at_a_prop_listed_first():
    s = solving_skeleton(_forest())
    assert (s.joint_parent < 0).sum() == 2
    chain = [s.joint_bones[j] for j in spine_chain(s)]
    assert chain[0] == "spine head" and "blade tail" not in chain
    assert chain[-1] == "chest tail"  # where the neck and the arm branch
