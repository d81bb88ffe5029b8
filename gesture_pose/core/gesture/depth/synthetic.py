"""Embeddings of known poses: the 3D step's input without a drawing.

Projecting a known 3D pose gives the embedding a perfect 2D fit would produce. Tests and
benchmarks use it to measure the 3D lifting alone, separately from the 2D fit.
"""

from __future__ import annotations

import numpy as np

from ...camera import Camera
from ...skeleton import Pose, Skeleton
from ..solving import build_solving_skeleton
from ..types import Embedding2D, Occlusion, SolvingSkeleton


def solving_skeleton(skeleton: Skeleton, bones: np.ndarray | None = None) -> SolvingSkeleton:
    """The solving skeleton over ``bones`` (full indices; default every bone)."""
    mask = np.zeros(skeleton.n_bones, dtype=bool)
    mask[np.arange(skeleton.n_bones) if bones is None else np.asarray(bones, int)] = True
    return build_solving_skeleton(skeleton, mask)


def _closest_params(p0, p1, q0, q1) -> tuple[float, float]:
    """Parameters of the closest points of 2D segments ``p0p1`` and ``q0q1``."""
    best = (np.inf, 0.0, 0.0)
    for s in np.linspace(0.0, 1.0, 21):
        a = p0 + s * (p1 - p0)
        d = q1 - q0
        t = float(np.clip((a - q0) @ d / max(d @ d, 1e-12), 0.0, 1.0))
        dist = float(np.linalg.norm(a - (q0 + t * d)))
        if dist < best[0]:
            best = (dist, s, t)
    return best[1], best[2]


def occlusions_from_pose(skeleton: Skeleton, solving: SolvingSkeleton, pose: Pose,
                         camera: Camera, radius_px: np.ndarray) -> tuple[Occlusion, ...]:
    """The occlusions a perfect contour analysis would report for a known pose.

    Two solving bones that do not share a joint overlap where their drawn tubes (radius
    interpolated between the joints) come closer than the sum of their radii. When their
    depths there differ by more than the sum of their radii (separate parts, not one
    blob), the one nearer the camera is in front.

    Args:
        skeleton: The full skeleton.
        solving: Its solving skeleton.
        pose: The pose drawn.
        camera: The view.
        radius_px: Drawn radius at each joint, pixels, shape ``(J,)``.

    Returns:
        One occlusion per overlapping pair.
    """
    state = skeleton.forward(pose)
    h3, t3 = state.heads[solving.bones], state.tails[solving.bones]
    center = np.concatenate([h3, t3]).mean(axis=0)
    scale = camera.pixels_per_unit(float(camera.depth(center[None])[0]))
    h2, t2 = camera.project(h3), camera.project(t3)
    out = []
    m = solving.n_bones
    for i in range(m):
        for j in range(i + 1, m):
            ends_i = {solving.head_joint[i], solving.tail_joint[i]}
            if ends_i & {solving.head_joint[j], solving.tail_joint[j]}:
                continue
            si, tj = _closest_params(h2[i], t2[i], h2[j], t2[j])
            pi, pj = h2[i] + si * (t2[i] - h2[i]), h2[j] + tj * (t2[j] - h2[j])
            ri = (1 - si) * radius_px[solving.head_joint[i]] + si * radius_px[
                solving.tail_joint[i]]
            rj = (1 - tj) * radius_px[solving.head_joint[j]] + tj * radius_px[
                solving.tail_joint[j]]
            if np.linalg.norm(pi - pj) >= ri + rj:
                continue
            di = camera.depth((h3[i] + si * (t3[i] - h3[i]))[None])[0]
            dj = camera.depth((h3[j] + tj * (t3[j] - h3[j]))[None])[0]
            if abs(di - dj) <= (ri + rj) / scale:
                continue
            front, back, rf, rb = (i, j, ri, rj) if di < dj else (j, i, rj, ri)
            out.append(Occlusion(front, back, 0.5 * (pi + pj), float(rf), float(rb)))
    return tuple(out)


def project_embedding(skeleton: Skeleton, solving: SolvingSkeleton, pose: Pose,
                      camera: Camera, radius: float | np.ndarray = 0.05,
                      occlusions: tuple[Occlusion, ...] | str = ()) -> Embedding2D:
    """The embedding of a drawing that shows ``pose`` exactly, from ``camera``.

    Args:
        skeleton: The full skeleton.
        solving: Its solving skeleton.
        pose: The pose drawn.
        camera: The view.
        radius: Body radius at each joint, world units (scalar or ``(J,)``).
        occlusions: Occlusions to record, or ``"auto"`` for :func:`occlusions_from_pose`.

    Returns:
        The embedding (no contours: cues that need them are absent).
    """
    state = skeleton.forward(pose)
    n_j = solving.n_joints
    X = np.zeros((n_j, 3))
    X[solving.head_joint] = state.heads[solving.bones]
    X[solving.tail_joint] = state.tails[solving.bones]
    px = camera.project(X)
    center = X.mean(axis=0)
    scale = camera.pixels_per_unit(float(camera.depth(center[None])[0]))
    radius_px = np.broadcast_to(np.asarray(radius, float), (n_j,)) * scale
    m = solving.n_bones
    if isinstance(occlusions, str):
        occlusions = occlusions_from_pose(skeleton, solving, pose, camera, radius_px)
    return Embedding2D(
        solving=solving, joints2d=px, joint_visible=np.ones(n_j, bool),
        joint_radius=radius_px.copy(), bone_segments=((),) * m,
        bone_segment_sides=((),) * m, occlusions=tuple(occlusions), contours=(),
        contour_normals=(), coverage=1.0, e_match=0.0,
    )
