"""The rig's restrictions on the 3D solve: pinned bones, locked axes and IK limits."""

from __future__ import annotations

import numpy as np

from ...rotations import log_map
from ...skeleton import Pose, Skeleton
from . import twist
from .qp import LinearConstraint


def rig_rows(skeleton: Skeleton, jmap: twist.JointMap, pose: Pose, frames: np.ndarray,
              lock: np.ndarray | None, limits: np.ndarray | None,
              pinned: np.ndarray | None, axes: np.ndarray | None = None
              ) -> list[LinearConstraint]:
    """Rig restrictions on the twists: pinned bones, locked axes and IK limits.

    Args:
        skeleton: The full skeleton.
        jmap: Joint map of the solving skeleton.
        pose: Current pose.
        frames: Current world frames of the solving bones, ``(m, 3, 3)``.
        lock: Locked local rotation axes, ``(n, 3)`` bool, or None.
        limits: IK limits ``[min, max]`` per local axis, radians, ``(n, 3, 2)`` (NaN when
            unlimited), or None.
        pinned: Bones kept at their current rotation, ``(n,)`` bool, or None.
        axes: The local axes ``lock`` and ``limits`` refer to, as columns, ``(n, 3, 3)``
            (None: the bones' own axes). An imported rig read as its joint skeleton has
            its settings about the real bones' axes ``C^T e_k``.

    Returns:
        One constraint block on the twists (empty list when the rig restricts nothing).

    The local rotation vector after the step is about ``log(Q) + F^T delta`` (first order
    around small rotations), so a locked local axis ``a`` gives the row
    ``F[:, a] . delta = -log(Q)_a`` and an IK limit ``[lo, hi]`` the bounds
    ``lo - log(Q)_a <= F[:, a] . delta <= hi - log(Q)_a``; about a general local axis
    ``u`` (``axes``), ``F u`` and ``log(Q) . u`` take the places of ``F[:, a]`` and
    ``log(Q)_a``.
    """
    m = jmap.n_bones
    rows, lo, hi, labels = [], [], [], []
    rotvec = log_map(pose.rotations[jmap.bones])
    for k, bone in enumerate(jmap.bones):
        for axis in range(3):
            fixed = bool(pinned is not None and pinned[bone])
            locked = bool(lock is not None and lock[bone, axis])
            lim = limits[bone, axis] if limits is not None else np.array([np.nan, np.nan])
            if not (fixed or locked or np.all(np.isfinite(lim))):
                continue
            row = np.zeros((m, 3))
            if fixed:
                row[k, axis] = 1.0
                lo_k = hi_k = 0.0
            else:
                u = np.eye(3)[axis] if axes is None else axes[bone][:, axis]
                row[k] = frames[k] @ u
                now = float(rotvec[k] @ u)
                lo_k = hi_k = -now
                if not locked:
                    lo_k, hi_k = lim[0] - now, lim[1] - now
            rows.append(row.ravel())
            lo.append(lo_k)
            hi.append(hi_k)
            kind = "pinned" if fixed else ("locked" if locked else "ik limit")
            labels.append(f"{kind} {skeleton.names[bone]} {'xyz'[axis]}")
    if not rows:
        return []
    return [LinearConstraint(np.array(rows), np.array(lo), np.array(hi), tuple(labels))]
