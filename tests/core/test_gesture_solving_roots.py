"""Which root joints are end caps: the legs hanging below a pelvis bone's head continue it."""

from __future__ import annotations

import numpy as np

from gesture_pose.core.gesture.solving import solving_skeleton
from gesture_pose.core.skeleton import Skeleton

from .fixtures import chain_skeleton, frame_along, tree_skeleton


def _pelvis_up_skeleton(sideways: bool = False) -> Skeleton:
    """A pelvis bone from the crotch (z 1.0) up to the spine, the legs hung from its top.

    As the Quaternius Adventurer reads (its joint skeleton's ``Hips`` runs from 7 cm below
    the hip joints up to the abdomen): the thighs' heads are nearer the pelvis' tail, so they
    hang from it by rigid offsets, and the legs run down past the pelvis' head. With
    ``sideways`` the two chains run out level with their heads instead (the arms of a T),
    never below the pelvis' head.
    """
    heads = np.array([[0, 0, 1.0], [0, 0, 1.1], [0.12, 0, 1.07], [0.12, 0, 0.55],
                      [-0.12, 0, 1.07], [-0.12, 0, 0.55]], float)
    tails = np.array([[0, 0, 1.1], [0, 0, 1.5], [0.12, 0, 0.55], [0.12, 0, 0.08],
                      [-0.12, 0, 0.55], [-0.12, 0, 0.08]], float)
    if sideways:
        heads[[3, 5]] = [[0.6, 0, 1.07], [-0.6, 0, 1.07]]
        tails[2:] = [[0.6, 0, 1.07], [1.1, 0, 1.07], [-0.6, 0, 1.07], [-1.1, 0, 1.07]]
    return Skeleton(
        names=("hips", "spine", "thigh.L", "shin.L", "thigh.R", "shin.R"),
        parents=np.array([-1, 0, 0, 2, 0, 4]),
        rest_heads=heads,
        rest_tails=tails,
        rest_frames=np.stack([frame_along(t - h) for h, t in zip(heads, tails, strict=True)]),
        inherit_rotation=np.ones(6, bool),
        connected=np.array([False, True, False, True, False, True]),
        deform=np.ones(6, bool),
    )


def test_a_pelvis_root_with_the_legs_below_it_is_not_an_end_cap():
    sol = solving_skeleton(_pelvis_up_skeleton())
    root = sol.head_joint[0]
    assert sol.joint_parent[root] == -1
    # One child joint (the pelvis' tail), from which the thighs hang by rigid offsets.
    assert np.flatnonzero(sol.joint_parent == root).tolist() == [sol.tail_joint[0]]
    thighs = [sol.head_joint[k] for k in (2, 4)]
    assert all(sol.joint_link_bone[t] == -1 and sol.joint_parent[t] == sol.tail_joint[0]
               for t in thighs)
    # The drawn body goes on past the crotch (the legs): no end cap there.
    assert sol.extends[root]
    assert not sol.terminal[root]
    # The real ends stay end caps, and the root still ends its chain for Section 5.4.
    ends = {sol.joint_bones[j] for j in np.flatnonzero(sol.terminal)}
    assert ends == {"spine tail", "shin.L tail", "shin.R tail"}
    assert sol.limb_ends[root]


def test_roots_that_end_the_drawn_shape_stay_end_caps():
    # Branches that stop short of the root (arms of a Y hung at its top) leave it an end.
    sol = solving_skeleton(tree_skeleton())
    assert sol.terminal[sol.head_joint[0]] and not sol.extends[sol.head_joint[0]]
    # The same chains hung from the pelvis' top but run out sideways, never below its
    # head, do not continue it either.
    sol = solving_skeleton(_pelvis_up_skeleton(sideways=True))
    assert sol.joint_link_bone[sol.head_joint[2]] == -1
    assert sol.terminal[sol.head_joint[0]] and not sol.extends[sol.head_joint[0]]
    # A chain without branches (a snake) ends at its root.
    chain = chain_skeleton(np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.0]]))
    sol = solving_skeleton(chain)
    assert sol.terminal[sol.head_joint[0]] and sol.terminal[sol.tail_joint[-1]]
