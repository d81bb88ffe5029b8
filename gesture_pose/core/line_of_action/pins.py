"""Pinned bones under stroke posing: a prioritized inverse kinematics.

Pinned bones keep their world position (head and tail). After a stroke has posed a chain,
any pinned bone it moved is brought back with a two-level task-priority IK over the chain's
rotations (Siciliano and Slotine's scheme): the pins are the first task, staying close to
the drawn pose's joint positions is the second, solved in the null space of the first::

    d1 = J1^+ e1,   N1 = I - J1^+ J1,   d = d1 + N1 (J2 N1)^+ (e2 - J2 d1)

with damped pseudo-inverses. Parameters are world-space rotation vectors applied at each
chain bone's head.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rotations import exp_map, orthonormalize
from ..skeleton import Pose, Skeleton

_DAMPING = 1e-4
_MAX_STEP = 0.3


@dataclass(frozen=True)
class PinReport:
    """Outcome of restoring pins.

    Attributes:
        pinned: Pinned bones that the stroke had moved.
        iterations: IK iterations run.
        residual: Largest remaining pin error, world units.
        drawn_error: RMS distance of the chain joints from the drawn pose, world units.
    """

    pinned: tuple[int, ...]
    iterations: int
    residual: float
    drawn_error: float


def _pinv(a: np.ndarray, damping: float) -> np.ndarray:
    """Damped pseudo-inverse ``A^T (A A^T + damping I)^-1``."""
    return a.T @ np.linalg.inv(a @ a.T + damping * np.eye(a.shape[0]))


def _points(state, bones: np.ndarray) -> np.ndarray:
    return np.concatenate([state.heads[bones], state.tails[bones]])


def _jacobian(skeleton: Skeleton, state, chain: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """d(points)/d(world rotation vectors at chain heads), shape ``(6 len(bones), 3 k)``."""
    pts = _points(state, bones)
    owner = np.concatenate([bones, bones])
    jac = np.zeros((pts.shape[0], 3, 3 * len(chain)))
    for c, b in enumerate(chain):
        moved = np.isin(owner, skeleton.descendants(b))
        rel = pts[moved] - state.heads[b]
        # d(w x r)/dw = -[r]_x
        jac[moved, :, 3 * c:3 * c + 3] = -np.stack([
            np.stack([np.zeros(len(rel)), -rel[:, 2], rel[:, 1]], -1),
            np.stack([rel[:, 2], np.zeros(len(rel)), -rel[:, 0]], -1),
            np.stack([-rel[:, 1], rel[:, 0], np.zeros(len(rel))], -1)], 1)
    return jac.reshape(-1, 3 * len(chain))


def _apply(skeleton: Skeleton, pose: Pose, state, chain: np.ndarray, d: np.ndarray) -> Pose:
    """Rotate each chain bone's world frame by ``exp(d_c)``, parents first."""
    rot = pose.rotations.copy()
    cur_pose, cur = pose, state
    for c, b in enumerate(chain):
        w = exp_map(d[3 * c:3 * c + 3])
        carry = cur.frames[b] @ rot[b].T
        rot[b] = orthonormalize(carry.T @ w @ cur.frames[b])
        cur_pose = Pose(rot.copy(), pose.translations)
        cur = skeleton.forward(cur_pose)
    return cur_pose


def restore_pins(skeleton: Skeleton, before: Pose, drawn: Pose, chain: np.ndarray,
                 pinned: np.ndarray, iterations: int) -> tuple[Pose, PinReport]:
    """Bring moved pinned bones back while staying close to the drawn pose.

    Args:
        skeleton: The skeleton.
        before: Pose before the stroke (pinned positions are read from it).
        drawn: Pose after the stroke.
        chain: Bones the stroke posed (the IK's degrees of freedom), shape ``(k,)``.
        pinned: Boolean mask of pinned bones, shape ``(n,)``.
        iterations: Maximum IK iterations.

    Returns:
        The corrected pose and a report.
    """
    ref = skeleton.forward(before)
    state = skeleton.forward(drawn)
    pins = np.flatnonzero(pinned)
    goal1 = _points(ref, pins)
    moved = np.linalg.norm(_points(state, pins) - goal1, axis=1).reshape(2, -1).max(0)
    scale = float(np.max(skeleton.lengths))
    pins = pins[moved > 1e-9 * scale]
    if pins.size == 0 or len(chain) == 0:
        return drawn, PinReport((), 0, 0.0, 0.0)
    goal1 = _points(ref, pins)
    goal2 = _points(state, chain)
    pose, it = drawn, 0
    best, best_err = drawn, np.inf
    for it in range(1, iterations + 1):  # noqa: B007
        e1 = (goal1 - _points(state, pins)).ravel()
        err = float(np.max(np.abs(e1)))
        if err < best_err:
            best, best_err = pose, err
        if err < 1e-10 * scale:
            break
        e2 = (goal2 - _points(state, chain)).ravel()
        j1 = _jacobian(skeleton, state, chain, pins)
        j2 = _jacobian(skeleton, state, chain, chain)
        damping = _DAMPING * scale * scale
        j1p = _pinv(j1, damping * 1e-4)
        d1 = j1p @ e1
        null = np.eye(j1.shape[1]) - j1p @ j1
        d = d1 + null @ (_pinv(j2 @ null, damping) @ (e2 - j2 @ d1))
        d *= min(1.0, _MAX_STEP / max(float(np.max(np.abs(d))), 1e-300))
        pose = _apply(skeleton, pose, state, chain, d)
        state = skeleton.forward(pose)
    if float(np.max(np.abs(goal1 - _points(state, pins)))) > best_err:
        pose, state = best, skeleton.forward(best)
    res = float(np.max(np.linalg.norm(goal1 - _points(state, pins), axis=1)))
    drawn_err = float(np.sqrt(np.mean(np.sum((goal2 - _points(state, chain)) ** 2, axis=1))))
    return pose, PinReport(tuple(int(p) for p in pins), it, res, drawn_err)
