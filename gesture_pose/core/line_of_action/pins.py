"""Pinned bones under stroke posing: a prioritized inverse kinematics.

Pinned bones keep their world position and orientation (head, tail and roll). After a
stroke has posed a chain, any pinned bone it moved is brought back in two steps:

1. A two-level task-priority IK (Siciliano and Slotine's scheme) over the rotations of the
   chain's bones and of the bones between the chain and each pin: the pinned heads are the
   first task, staying close to the drawn pose is the second (the chain's joints where the
   stroke put them, the other freed bones where they were), in the null space of the
   first::

       d1 = J1^+ e1,   N1 = I - V_r V_r^T,   d = d1 + N1 (J2 N1)^+ (e2 - J2 d1)

   ``J1^+`` is a pseudo-inverse from the SVD of ``J1`` with a tiny damping floor (steps
   stay bounded near singular configurations), ``V_r`` spans its row space (numerical
   rank), so ``N1`` is the exact null-space projector and the second task cannot pull the
   pins; ``(J2 N1)^+`` is damped. Parameters are world-space rotation vectors
   applied at each freed bone's head.
   The last iterations polish the first task alone (Gauss-Newton), since the second
   task's finite steps leave a small second-order pull on the pins.
2. Each pinned bone's local rotation is set so its world frame is the one it had before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rotations import exp_map
from ..skeleton import Pose, PoseState, Skeleton

_RANK_TOL = 1e-9  # numerical rank of J1: its null space is exact
_DAMPING = 1e-4   # of the squared rig scale, for the second task
_FLOOR = 1e-10    # of the squared rig scale, damping floor of the first task
_MAX_STEP = 0.3   # radians per iteration, per component
TOLERANCE = 1e-6  # pins held to this fraction of the longest bone
_POLISH = 20      # last iterations spent on the first task alone


@dataclass(frozen=True)
class PinReport:
    """Outcome of restoring pins.

    Attributes:
        pinned: Pinned bones that the stroke had moved.
        iterations: IK iterations run.
        residual: Largest remaining pin error (head or tail), world units.
        drawn_error: RMS distance of the chain joints from the drawn pose, world units.
        held: Whether every pin is within :data:`TOLERANCE` of the longest bone.
        freed: Bones whose rotation the IK changed besides the chain's.
    """

    pinned: tuple[int, ...]
    iterations: int
    residual: float
    drawn_error: float
    held: bool = True
    freed: tuple[int, ...] = ()


def _joints(state: PoseState, bones: np.ndarray) -> np.ndarray:
    return np.concatenate([state.heads[bones], state.tails[bones]])


def _jacobian(skeleton: Skeleton, state: PoseState, dofs: np.ndarray, pts: np.ndarray,
              owner: np.ndarray) -> np.ndarray:
    """d(points)/d(world rotation vectors at the ``dofs`` bones' heads), ``(3 m, 3 k)``.

    A rotation ``w`` about the head ``h`` of a bone moves every point ``x`` carried by it
    or its descendants by ``w x (x - h)``: the block is ``-[x - h]_x`` for those points.
    ``pts`` (shape ``(m, 3)``) are points carried by the bones ``owner`` (shape ``(m,)``).
    """
    jac = np.zeros((len(pts), 3, 3 * len(dofs)))
    zeros = np.zeros(len(pts))
    for c, b in enumerate(dofs):
        moved = np.isin(owner, skeleton.descendants(b))
        rx, ry, rz = (pts - state.heads[b]).T
        block = -np.stack([np.stack([zeros, -rz, ry], -1), np.stack([rz, zeros, -rx], -1),
                           np.stack([-ry, rx, zeros], -1)], 1)
        jac[moved, :, 3 * c:3 * c + 3] = block[moved]
    return jac.reshape(-1, 3 * len(dofs))


def _apply(skeleton: Skeleton, pose: Pose, state: PoseState, dofs: np.ndarray,
           d: np.ndarray) -> Pose:
    """Turn each freed bone's world frame by ``exp(d_c)`` about its head, parents first.

    With ``C`` the bone's parent carry after its ancestors turned, the new local rotation
    is ``Q' = C^T exp(d_c) C Q``.
    """
    rot = pose.rotations.copy()
    turns = exp_map(d.reshape(-1, 3))
    for c, b in enumerate(dofs):
        carry = skeleton.parent_carry(int(b), state)
        rot[b] = carry.T @ turns[c] @ carry @ rot[b]
        state = skeleton.forward(Pose(rot, pose.translations))
    return Pose(rot, pose.translations)


def _step(j1: np.ndarray, e1: np.ndarray, j2: np.ndarray | None, e2: np.ndarray | None,
          damping: float) -> np.ndarray:
    """One prioritized step (module docstring); without ``j2`` the first task only."""
    u, s, vt = np.linalg.svd(j1, full_matrices=False)
    d1 = vt.T @ ((u.T @ e1) * s / (s * s + damping * (_FLOOR / _DAMPING)))
    if j2 is None:
        return d1 * min(1.0, _MAX_STEP / max(float(np.max(np.abs(d1))), 1e-300))
    strong = s > _RANK_TOL * max(float(s[0]), 1e-300)
    v_r = vt[strong].T
    null = np.eye(j1.shape[1]) - v_r @ v_r.T
    a = j2 @ null
    d2 = null @ (a.T @ np.linalg.solve(a @ a.T + damping * np.eye(a.shape[0]),
                                       e2 - j2 @ d1))
    d = d1 + d2
    return d * min(1.0, _MAX_STEP / max(float(np.max(np.abs(d))), 1e-300))


def _freed_bones(skeleton: Skeleton, chain: np.ndarray, pins: np.ndarray) -> np.ndarray:
    """The chain plus the unpinned bones between the chain and each pin, parents first."""
    in_chain = set(int(b) for b in chain)
    pinned = set(int(p) for p in pins)
    freed = set(in_chain)
    for p in pins:
        path = []
        for bone in skeleton.ancestors(int(p))[1:]:
            if bone in in_chain:
                freed.update(b for b in path if b not in pinned)
                break
            path.append(bone)
    return np.array(sorted(freed - pinned), dtype=int)


def _restore_orientations(skeleton: Skeleton, pose: Pose, ref: PoseState,
                          pins: np.ndarray) -> Pose:
    """Give each pinned bone back its world frame through its local rotation."""
    rot = pose.rotations.copy()
    for p in sorted(int(b) for b in pins):
        state = skeleton.forward(Pose(rot, pose.translations))
        rot[p] = skeleton.local_rotation_for_frame(p, ref.frames[p], state)
    return Pose(rot, pose.translations)


def restore_pins(skeleton: Skeleton, before: Pose, drawn: Pose, chain: np.ndarray,
                 pinned: np.ndarray, iterations: int) -> tuple[Pose, PinReport]:
    """Bring moved pinned bones back while staying close to the drawn pose.

    Args:
        skeleton: The skeleton.
        before: Pose before the stroke (pinned positions are read from it).
        drawn: Pose after the stroke.
        chain: Bones the stroke posed, shape ``(k,)``.
        pinned: Boolean mask of pinned bones, shape ``(n,)``.
        iterations: Maximum IK iterations.

    Returns:
        The corrected pose and a report.
    """
    ref, state = skeleton.forward(before), skeleton.forward(drawn)
    scale = float(np.max(skeleton.lengths))
    pins = np.flatnonzero(pinned)
    moved = np.linalg.norm(_joints(state, pins) - _joints(ref, pins), axis=1)
    pins = pins[moved.reshape(2, -1).max(0) > TOLERANCE * scale]
    if pins.size == 0 or len(chain) == 0:
        return drawn, PinReport((), 0, 0.0, 0.0)
    dofs = _freed_bones(skeleton, np.asarray(chain, int), pins)
    # Pinned heads are the first task; a pin below another pin follows it exactly.
    tops = np.array([p for p in pins if not set(skeleton.ancestors(int(p))[1:]) & set(pins)])
    goal1 = ref.heads[tops]
    others = np.array(sorted(set(dofs.tolist()) - set(int(b) for b in chain)), dtype=int)
    second = np.concatenate([np.asarray(chain, int), others])
    goal2 = _joints(state, second)
    drawn_chain = _joints(state, np.asarray(chain, int))
    owner2 = np.concatenate([second, second])
    damping = _DAMPING * scale * scale
    pose, best, best_err, it = drawn, drawn, np.inf, 0
    for it in range(1, iterations + 1):  # noqa: B007
        e1 = (goal1 - state.heads[tops]).ravel()
        err = float(np.max(np.abs(e1)))
        if err < best_err:
            best, best_err = pose, err
        if err < 0.1 * TOLERANCE * scale or dofs.size == 0:
            break
        j1 = _jacobian(skeleton, state, dofs, state.heads[tops], tops)
        if it <= iterations - _POLISH:
            j2 = _jacobian(skeleton, state, dofs, _joints(state, second), owner2)
            d = _step(j1, e1, j2, (goal2 - _joints(state, second)).ravel(), damping)
        else:  # polish: the first task alone converges quadratically onto the pins
            d = _step(j1, e1, None, None, damping)
        pose = _apply(skeleton, pose, state, dofs, d)
        state = skeleton.forward(pose)
    pose = _restore_orientations(skeleton, best, ref, tops)
    final = skeleton.forward(pose)
    res = float(np.max(np.linalg.norm(_joints(final, pins) - _joints(ref, pins), axis=1)))
    chain_pts = _joints(final, np.asarray(chain, int))
    drawn_err = float(np.sqrt(np.mean(np.sum((drawn_chain - chain_pts) ** 2, axis=1))))
    report = PinReport(tuple(int(p) for p in pins), it, res, drawn_err,
                       res <= TOLERANCE * scale, tuple(int(b) for b in others))
    return pose, report
