"""Depth order of body parts read from the drawing (Gesture3D Section 7, Eq. 8).

Two cues decide which part is in front:

- **Inter-part occlusions.** Where the outline of part B disappears under part A, B is
  behind A. Eq. 8 asks the occluded part's surface to lie behind the occluder's along the
  view ray through the occluding point ``q``. With the bones as tubes of the drawn radii,
  the depth half-thickness of a tube of radius ``r`` at 2D distance ``e`` from its axis is
  ``h = sqrt(max(r^2 - e^2, 0))``, and the constraint is linear in the joint depths::

      d_B(q) - d_A(q) >= h_A(q) + h_B(q)                                     (Eq. 8)

  where ``d_X(q)`` interpolates the depths of bone X's head and tail at ``q``'s position
  along the bone.
- **Intra-part T-junctions.** When the contour of one bone ends on the interior of the
  contour of an adjacent bone (the stem and top of a T), the stem bone turns away: its far
  joint is deeper than the joint it shares with the top bone.

Junctions are found on the drawing's contours (a contour end that stops on another
contour's interior, across it) and attributed to bones through the embedding's
correspondences (the bones whose matched contour samples lie there). The embedding's own
occlusions are used as well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import Embedding2D, Occlusion
from .qp import LinearConstraint


@dataclass(frozen=True)
class OrderingConstraint:
    """``sum(back_w * d[back]) - sum(front_w * d[front]) >= margin`` on joint depths.

    Attributes:
        kind: ``"occlusion"`` or ``"t_junction"``.
        label: Human-readable description (bone names).
        back: Joints of the part that must be behind, shape ``(k,)``.
        back_w: Their interpolation weights (sum 1), shape ``(k,)``.
        front: Joints of the part in front, shape ``(k,)``.
        front_w: Their weights, shape ``(k,)``.
        margin: Required depth gap, world units (>= 0).
    """

    kind: str
    label: str
    back: np.ndarray
    back_w: np.ndarray
    front: np.ndarray
    front_w: np.ndarray
    margin: float

    def gap(self, depths: np.ndarray) -> float:
        """Depth of the back part minus depth of the front part, world units."""
        return float(self.back_w @ depths[self.back] - self.front_w @ depths[self.front])


def _segment_param(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Clamped parameter of ``p`` on segment ``ab`` and its 2D distance to it."""
    ab = b - a
    t = float(np.clip((p - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0))
    return t, float(np.linalg.norm(p - (a + t * ab)))


def occlusion_constraint(embedding: Embedding2D, occ: Occlusion, scale: float,
                         names: tuple[str, ...] = ()) -> OrderingConstraint:
    """Eq. 8 for one occlusion: the back bone's surface behind the front bone's at ``q``.

    Args:
        embedding: The 2D embedding (joint positions in pixels).
        occ: The occlusion (bones, point and radii in pixels).
        scale: Pixels per world unit.
        names: Solving-bone names for the label (optional).

    Returns:
        The constraint on joint depths.
    """
    s = embedding.solving
    q = np.asarray(occ.point2d, dtype=float)
    parts = []
    for bone, radius in ((occ.front_bone, occ.front_radius), (occ.back_bone, occ.back_radius)):
        h, t = s.head_joint[bone], s.tail_joint[bone]
        u, e = _segment_param(q, embedding.joints2d[h], embedding.joints2d[t])
        half = np.sqrt(max(radius**2 - e**2, 0.0)) / scale
        parts.append((np.array([h, t]), np.array([1.0 - u, u]), half))
    (front, front_w, h_front), (back, back_w, h_back) = parts
    label = (f"occlusion {names[occ.back_bone]} behind {names[occ.front_bone]}" if names
             else f"occlusion {occ.back_bone} behind {occ.front_bone}")
    return OrderingConstraint("occlusion", label, back, back_w, front, front_w,
                              h_front + h_back)


def _closest_on_polyline(poly: np.ndarray, x: np.ndarray) -> tuple[float, np.ndarray, float,
                                                                    np.ndarray]:
    """Closest point of a polyline ``(k, 2)`` to ``x``.

    Returns:
        ``(distance, point (2,), arc length there, unit tangent there (2,))``.
    """
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.clip(np.sum((x - a) * ab, axis=1) / np.maximum(np.sum(ab * ab, axis=1), 1e-12),
                0.0, 1.0)
    pts = a + t[:, None] * ab
    d = np.linalg.norm(pts - x, axis=1)
    i = int(np.argmin(d))
    seg = np.linalg.norm(ab, axis=1)
    arc = float(np.sum(seg[:i]) + t[i] * seg[i])
    return float(d[i]), pts[i], arc, ab[i] / max(seg[i], 1e-12)


def _bone_labels(embedding: Embedding2D) -> tuple[np.ndarray, np.ndarray]:
    """Every contour sample matched to a bone, ``(N, 2)``, and its solving bone, ``(N,)``."""
    pts = [np.asarray(p, float) for ps in embedding.bone_segments for p in ps if len(p)]
    lab = [np.full(len(p), b) for b, ps in enumerate(embedding.bone_segments)
           for p in ps if len(p)]
    if not pts:
        return np.zeros((0, 2)), np.zeros(0, int)
    return np.concatenate(pts), np.concatenate(lab)


def _bone_near(points: np.ndarray, labels: np.ndarray, x: np.ndarray, reach: float,
               exclude: int = -1) -> int:
    """The bone, other than ``exclude``, whose matched samples come nearest ``x``.

    Returns:
        The solving-bone index, or -1 when no such sample lies within ``reach``.
    """
    if not len(points):
        return -1
    d = np.where(labels == exclude, np.inf, np.linalg.norm(points - x, axis=1))
    i = int(np.argmin(d))
    return int(labels[i]) if d[i] <= reach else -1


def detect_junctions(embedding: Embedding2D, tolerance: float | None = None,
                     min_angle: float = np.radians(45.0), interior: float | None = None
                     ) -> list[tuple[int, int, np.ndarray]]:
    """T-junctions of the drawing's contours, attributed to bones.

    A contour end is the stem of a T when it stops within ``tolerance`` of another
    contour's interior (more than ``interior`` of arc length from that contour's ends) and
    meets it at more than ``min_angle``. The defaults are strict: with rough drawings and
    imperfect correspondences a wrong order does more harm than a missing one. The stem
    and top bones are those whose matched
    contour samples (the embedding's correspondences) lie nearest the stem's last sample
    but one and the junction point, within one resampling step.

    Args:
        embedding: The 2D embedding with its contours and contour-to-bone correspondences.
        tolerance: Distance in pixels; defaults to half a resampling step (a step is 2 px
            if unknown).
        min_angle: Smallest angle between the stem and the top contour, radians.
        interior: Smallest arc length between the junction and the top contour's ends,
            pixels (default: two resampling steps).

    Returns:
        ``(stem_bone, top_bone, point)`` triples (one per bone pair), point in pixels.
    """
    eps = embedding.epsilon if embedding.epsilon > 0 else 2.0
    tol = tolerance if tolerance is not None else 0.5 * eps
    inner = 2.0 * eps if interior is None else interior
    points, labels = _bone_labels(embedding)
    contours = [np.asarray(c, float) for c in embedding.contours if len(c) >= 2]
    found: dict[tuple[int, int], np.ndarray] = {}
    for ci, c in enumerate(contours):
        for end, prev in ((c[0], c[1]), (c[-1], c[-2])):
            tangent = (end - prev) / max(float(np.linalg.norm(end - prev)), 1e-12)
            for cj, other in enumerate(contours):
                if cj == ci:
                    continue
                d, q, arc, top_tangent = _closest_on_polyline(other, end)
                length = float(np.sum(np.linalg.norm(np.diff(other, axis=0), axis=1)))
                if d > tol or min(arc, length - arc) <= inner:
                    continue
                if abs(float(tangent @ top_tangent)) > np.cos(min_angle):
                    continue
                # The stem's end also lies on the top's outline: attribute the stem one
                # sample back along its own contour.
                stem = _bone_near(points, labels, prev, eps)
                top = _bone_near(points, labels, q, eps, exclude=stem)
                if stem >= 0 and top >= 0 and stem != top and (stem, top) not in found:
                    found[(stem, top)] = q
    return [(s, t, p) for (s, t), p in found.items()]


def _radius_at(embedding: Embedding2D, bone: int, q: np.ndarray) -> float:
    """Drawn radius of a bone at point ``q``, interpolated between its joints, pixels."""
    s = embedding.solving
    h, t = s.head_joint[bone], s.tail_joint[bone]
    u, _ = _segment_param(q, embedding.joints2d[h], embedding.joints2d[t])
    return float((1.0 - u) * embedding.joint_radius[h] + u * embedding.joint_radius[t])


def _bone_distance(parent: np.ndarray) -> np.ndarray:
    """Number of parent-child steps between every pair of solving bones, ``(m, m)``."""
    m = len(parent)
    up = []
    for k in range(m):
        path = [k]
        while parent[path[-1]] >= 0:
            path.append(int(parent[path[-1]]))
        up.append({b: i for i, b in enumerate(path)})
    dist = np.full((m, m), m, dtype=int)
    for i in range(m):
        for j in range(m):
            common = [up[i][c] + up[j][c] for c in up[j] if c in up[i]]
            if common:
                dist[i, j] = min(common)
    return dist


def ordering_constraints(embedding: Embedding2D, scale: float, names: tuple[str, ...] = (),
                         tolerance: float | None = None, min_parts: int = 3
                         ) -> list[OrderingConstraint]:
    """All depth-order constraints the drawing implies.

    A junction between adjacent bones (sharing a joint) is an intra-part T-junction; one
    between bones at least ``min_parts`` parent-child steps apart is an inter-part
    occlusion (Eq. 8). Junctions between nearby bones (a thigh and the pelvis, a shoulder
    and the chest) are where one outline turns into the next, not occlusions, and are
    ignored, as are pairs of bones found in front of each other both ways.

    Args:
        embedding: The 2D embedding.
        scale: Pixels per world unit.
        names: Solving-bone names for the labels (optional).
        tolerance: Junction tolerance in pixels (see :func:`detect_junctions`).
        min_parts: Fewest parent-child steps between the bones of an occlusion.

    Returns:
        Occlusion (Eq. 8) and T-junction constraints, without duplicates.
    """
    s = embedding.solving
    out = [occlusion_constraint(embedding, o, scale, names) for o in embedding.occlusions]
    seen = {(o.back_bone, o.front_bone) for o in embedding.occlusions}
    steps = _bone_distance(np.asarray(s.parent))
    junctions = detect_junctions(embedding, tolerance)
    pairs = {(stem, top) for stem, top, _ in junctions}
    for stem, top, q in junctions:
        if (top, stem) in pairs:
            continue  # contradictory evidence
        shared = {int(s.head_joint[stem]), int(s.tail_joint[stem])} & {
            int(s.head_joint[top]), int(s.tail_joint[top])}
        if shared and steps[stem, top] == 1:
            j = shared.pop()
            far = int(s.tail_joint[stem] if s.head_joint[stem] == j else s.head_joint[stem])
            label = (f"t_junction {names[stem]} turns behind {names[top]}" if names
                     else f"t_junction {stem} behind {top}")
            out.append(OrderingConstraint("t_junction", label, np.array([far]), np.ones(1),
                                          np.array([j]), np.ones(1), 0.0))
        elif steps[stem, top] >= min_parts and (stem, top) not in seen:
            seen.add((stem, top))
            occ = Occlusion(top, stem, q, _radius_at(embedding, top, q),
                            _radius_at(embedding, stem, q))
            out.append(occlusion_constraint(embedding, occ, scale, names))
    return out


def ordering_rows(constraints: list[OrderingConstraint], forward: np.ndarray,
                  n_joints: int) -> LinearConstraint:
    """The constraints as rows on flattened joint positions (depth ``d = forward . X``).

    Args:
        constraints: Ordering constraints.
        forward: Unit view direction, shape ``(3,)``.
        n_joints: ``J``.

    Returns:
        ``margin <= A x <= inf`` rows, one per constraint.
    """
    A = np.zeros((len(constraints), n_joints, 3))
    for i, c in enumerate(constraints):
        np.add.at(A[i], c.back, c.back_w[:, None] * forward)
        np.add.at(A[i], c.front, -c.front_w[:, None] * forward)
    lower = np.array([c.margin for c in constraints], dtype=float)
    return LinearConstraint(A.reshape(len(constraints), 3 * n_joints), lower,
                            np.full(len(constraints), np.inf),
                            tuple(c.label for c in constraints))


def violations(constraints: list[OrderingConstraint], depths: np.ndarray) -> np.ndarray:
    """Amount by which each constraint is violated (0 when satisfied), world units."""
    return np.array([max(c.margin - c.gap(depths), 0.0) for c in constraints])
