"""The start of the 3D solve: the bind pose lifted to the drawing (Gesture3D Section 7).

A drawn link fixes how much a bone leaves the view plane, ``sqrt(l^2 - l_2d^2)``, not to
which side. The start aims every solving bone at its drawn direction, lifted by that
amount, on the bind pose's side when the bone clearly has one (depth slope above 0.3), else
towards the viewer; then sides that break depth-order constraints are flipped greedily.
Starting lifted matters: from a flat pose the linearized projection cannot shorten a bone
(the depth direction is a saddle), so the SQP alone would never leave the view plane.
"""

from __future__ import annotations

import numpy as np

from ...skeleton import Pose, Skeleton
from ..types import Embedding2D
from . import twist
from .energies import ViewFrame
from .ordering import OrderingConstraint, violations


def lifted_pose(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
                embedding: Embedding2D, bind: Pose, signs: np.ndarray, fixed: np.ndarray
                ) -> Pose:
    """The bind pose with each solving bone aimed at its drawn direction, lifted.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        embedding: The 2D embedding.
        bind: The bind pose.
        signs: Depth side of each solving bone (+1 away from the viewer), ``(m,)``.
        fixed: Solving bones left at their bind rotation, ``(m,)`` bool.

    Returns:
        The lifted pose.
    """
    s, f = embedding.solving, frame
    pose = bind
    for k, bone in enumerate(jmap.bones):
        if fixed[k]:
            continue
        drawn = (embedding.joints2d[s.tail_joint[k]] - embedding.joints2d[s.head_joint[k]]) \
            / f.scale
        length = skeleton.lengths[bone]
        depth = np.sqrt(max(length**2 - drawn @ drawn, 0.0)) * signs[k]
        direction = drawn[0] * f.right + drawn[1] * f.up + depth * f.forward
        if np.linalg.norm(direction) < 1e-9 * length:
            continue
        state = skeleton.forward(pose)
        rot = skeleton.aim_local(int(bone), direction, state, pose.rotations[bone])
        pose = pose.with_rotations(np.array([bone]), rot[None])
    return pose


def start_pose(skeleton: Skeleton, jmap: twist.JointMap, frame: ViewFrame,
               order: list[OrderingConstraint], embedding: Embedding2D, bind: Pose,
               toward_viewer: bool = True, pinned: np.ndarray | None = None
               ) -> tuple[Pose, np.ndarray]:
    """The lifted start pose and the depth side of each solving bone.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        frame: The view.
        order: Depth-order constraints the sides should satisfy.
        embedding: The 2D embedding.
        bind: The bind pose.
        toward_viewer: Default side of a bone the bind pose does not decide.
        pinned: Bones kept at their bind rotation, ``(n,)`` bool (full skeleton).

    Returns:
        ``(pose, signs)``: the start pose and the sides, ``(m,)``.
    """
    jm, f = jmap, frame
    fixed = (np.zeros(jm.n_bones, bool) if pinned is None
             else np.asarray(pinned, bool)[jm.bones])
    state = skeleton.forward(bind)
    bind_slope = ((state.tails[jm.bones] - state.heads[jm.bones]) @ f.forward) \
        / skeleton.lengths[jm.bones]
    default = -1.0 if toward_viewer else 1.0
    signs = np.where(np.abs(bind_slope) > 0.3, np.sign(bind_slope), default)
    pose = lifted_pose(skeleton, jm, f, embedding, bind, signs, fixed)
    if not order:
        return pose, signs

    # Greedy flips on a linear model of the depths: flipping bone k moves every joint below
    # its tail by -2 s_k m_k along the view (rigid offsets turning with it are ignored
    # here; the SQP enforces the constraints exactly).
    X, _ = twist.joint_positions(skeleton, jm, pose)
    depth = f.depth(X)
    s = embedding.solving
    drawn = np.linalg.norm(embedding.joints2d[s.tail_joint] - embedding.joints2d[s.head_joint],
                           axis=1) / f.scale
    lengths = skeleton.lengths[jm.bones]
    lift = np.sqrt(np.maximum(lengths**2 - drawn**2, 0.0))
    lifted = np.flatnonzero((drawn < 0.98 * lengths) & ~fixed)
    shift = jm.moves[:, lifted].astype(float) * lift[lifted]

    def badness(d: np.ndarray) -> float:
        return float(np.sum(violations(order, d)))

    current, flipped = badness(depth), False
    for _ in range(len(lifted)):
        if current <= 1e-12:
            break
        trials = depth[:, None] - 2.0 * signs[lifted] * shift
        scores = np.array([badness(trials[:, i]) for i in range(len(lifted))])
        if not len(scores) or scores.min() >= current - 1e-12:
            break
        i = int(np.argmin(scores))
        signs[lifted[i]] = -signs[lifted[i]]
        depth, current, flipped = trials[:, i], scores[i], True
    if flipped:
        pose = lifted_pose(skeleton, jm, f, embedding, bind, signs, fixed)
    return pose, signs
