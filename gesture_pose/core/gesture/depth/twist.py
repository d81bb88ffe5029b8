"""Twist (exponential-map) coordinates of a solving skeleton, with exact bone lengths.

Gesture3D Section 7 solves for the 3D joint positions with one twist per joint, so that
every bone keeps its length whatever the step. Here a step is one world-space rotation
vector ``delta_k`` (radians, shape ``(3,)``) per solving bone ``k``; it rotates the bone and
everything below it about the bone's head. In local coordinates this is (``F_k`` the
bone's current world frame, ``Q_k`` its local rotation)::

    Q_k <- Q_k exp(F_k^T delta_k)

and, to first order, every joint ``X_j`` below bone ``k`` moves by
``delta_k x (X_j - h_k)`` (``h_k`` the bone's head). Joint positions always come from
forward kinematics, so bone lengths are exact; only the step is linearized.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...exceptions import InputError
from ...rotations import exp_map, orthonormalize, skew
from ...skeleton import Pose, PoseState, Skeleton
from ..types import SolvingSkeleton


@dataclass(frozen=True)
class JointMap:
    """Where each joint of a solving skeleton comes from in the full skeleton.

    Attributes:
        bones: Full-skeleton index of each solving bone, shape ``(m,)``.
        joint_bone: Full-skeleton bone whose head or tail is the joint, shape ``(J,)``.
        joint_is_tail: Whether the joint is that bone's tail (else its head), ``(J,)``.
        moves: ``moves[j, k]`` is True when a twist of solving bone ``k`` moves joint ``j``,
            shape ``(J, m)`` bool.
        solving_parent: Nearest solving ancestor of each solving bone, -1 if none, ``(m,)``.
    """

    bones: np.ndarray
    joint_bone: np.ndarray
    joint_is_tail: np.ndarray
    moves: np.ndarray
    solving_parent: np.ndarray

    @property
    def n_joints(self) -> int:
        """Number of joints ``J``."""
        return len(self.joint_bone)

    @property
    def n_bones(self) -> int:
        """Number of solving bones ``m``."""
        return len(self.bones)


def joint_map(skeleton: Skeleton, solving: SolvingSkeleton) -> JointMap:
    """Relate the joints of ``solving`` to the bones of ``skeleton``.

    Args:
        skeleton: The full skeleton.
        solving: The solving skeleton (bones, head and tail joints).

    Returns:
        The joint map.

    Raises:
        InputError: A joint is not the head or tail of any solving bone, or a solving bone
            index is out of range.
    """
    bones = np.asarray(solving.bones, dtype=int)
    if bones.size == 0 or bones.min() < 0 or bones.max() >= skeleton.n_bones:
        raise InputError("The solving skeleton does not match the armature: redo the fit.")
    n_joints = int(max(np.max(solving.head_joint), np.max(solving.tail_joint))) + 1
    joint_bone = np.full(n_joints, -1)
    is_tail = np.zeros(n_joints, dtype=bool)
    joint_bone[solving.head_joint] = bones
    joint_bone[solving.tail_joint] = bones
    is_tail[solving.tail_joint] = True
    if np.any(joint_bone < 0):
        raise InputError("Some joints of the solving skeleton belong to no bone: redo the fit.")
    position = {int(b): k for k, b in enumerate(bones)}
    solving_parent = np.full(len(bones), -1)
    chains = []
    for k, b in enumerate(bones):
        up = [position[a] for a in skeleton.ancestors(int(b)) if a in position]
        chains.append(set(up))
        if len(up) > 1:
            solving_parent[k] = up[1]
    moves = np.zeros((n_joints, len(bones)), dtype=bool)
    for j in range(n_joints):
        k = position[int(joint_bone[j])]
        movers = set(chains[k])
        if not is_tail[j]:
            movers.discard(k)
        moves[j, sorted(movers)] = True
    return JointMap(bones, joint_bone, is_tail, moves, solving_parent)


def joint_positions(skeleton: Skeleton, jmap: JointMap, pose: Pose) -> tuple[np.ndarray,
                                                                              PoseState]:
    """World positions of the joints in ``pose`` (forward kinematics).

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        pose: Local transforms of every bone.

    Returns:
        ``(X, state)``: joints ``(J, 3)`` in world units and the full forward kinematics.
    """
    state = skeleton.forward(pose)
    X = np.where(jmap.joint_is_tail[:, None], state.tails[jmap.joint_bone],
                 state.heads[jmap.joint_bone])
    return X, state


def position_jacobian(jmap: JointMap, X: np.ndarray, state: PoseState) -> np.ndarray:
    """Jacobian of the flattened joint positions with respect to the twists.

    ``dX_j / d delta_k = -[X_j - h_k]_x`` when twist ``k`` moves joint ``j``, else zero.

    Args:
        jmap: Joint map.
        X: Joint positions, shape ``(J, 3)``.
        state: Forward kinematics the positions came from.

    Returns:
        ``G`` with ``vec(X(delta)) ~ vec(X) + G delta``, shape ``(3J, 3m)``; ``vec`` is
        row-major (x, y, z of joint 0 first).
    """
    heads = state.heads[jmap.bones]
    blocks = -skew(X[:, None, :] - heads[None, :, :])
    blocks = blocks * jmap.moves[:, :, None, None]
    n_j, m = jmap.moves.shape
    return blocks.transpose(0, 2, 1, 3).reshape(3 * n_j, 3 * m)


def apply_twists(skeleton: Skeleton, jmap: JointMap, pose: Pose, state: PoseState,
                 delta: np.ndarray) -> Pose:
    """Rotate every solving bone's subtree by its twist, exactly (no linearization).

    The world rotation applied to bone ``k`` is ``W_k = W_p exp([delta_k])`` with ``p`` its
    nearest solving ancestor. Bones that inherit their parent's rotation get
    ``Q_k <- Q_k exp(F_k^T delta_k)``; bones that do not get ``Q_k <- R_k^T W_k F_k``.
    Bones outside the solving skeleton keep their local rotations.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map.
        pose: Current pose.
        state: Forward kinematics of ``pose``.
        delta: World rotation vectors, shape ``(m, 3)``, radians.

    Returns:
        The new pose.
    """
    delta = np.asarray(delta, dtype=float).reshape(-1, 3)
    frames = state.frames[jmap.bones]
    step = exp_map(delta)
    local_step = np.swapaxes(frames, 1, 2) @ step @ frames
    rot = pose.rotations[jmap.bones] @ local_step
    no_inherit = np.flatnonzero(~skeleton.inherit_rotation[jmap.bones]
                                & (skeleton.parents[jmap.bones] >= 0))
    if no_inherit.size:
        world = np.empty_like(step)
        for k in range(jmap.n_bones):
            p = jmap.solving_parent[k]
            world[k] = step[k] if p < 0 else world[p] @ step[k]
        for k in no_inherit:
            b = jmap.bones[k]
            rot[k] = skeleton.rest_frames[b].T @ world[k] @ frames[k]
    # Re-orthonormalize: Q F^T E F repeats Q three times and would amplify rounding.
    return pose.with_rotations(jmap.bones, orthonormalize(rot))
