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

Junctions are found from the contour pieces matched to bones (the embedding's
correspondences): a piece end that is also a contour end and lies on the interior of
another bone's piece. The embedding's own occlusions are used as well.
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


def _ends_of_contours(embedding: Embedding2D) -> np.ndarray:
    """First and last samples of every contour, shape ``(2c, 2)``."""
    ends = [c[[0, -1]] for c in embedding.contours if len(c)]
    return np.concatenate(ends) if ends else np.zeros((0, 2))


def detect_junctions(embedding: Embedding2D, tolerance: float | None = None
                     ) -> list[tuple[int, int, np.ndarray]]:
    """T-junctions between contour pieces of different bones.

    A junction is a piece end of bone S (the stem) that ends its contour and lies within
    ``tolerance`` of the interior of a piece of bone T (the top), farther than
    ``2 * tolerance`` from that piece's ends.

    Args:
        embedding: The 2D embedding with its contour-to-bone correspondences.
        tolerance: Distance in pixels; defaults to 1.5 resampling steps (3 px if unknown).

    Returns:
        ``(stem_bone, top_bone, point)`` triples, point in pixels ``(2,)``.
    """
    tol = tolerance if tolerance is not None else (1.5 * embedding.epsilon
                                                   if embedding.epsilon > 0 else 3.0)
    contour_ends = _ends_of_contours(embedding)
    pieces = [(b, np.asarray(p, float)) for b, ps in enumerate(embedding.bone_segments)
              for p in ps if len(p) >= 2]
    found: dict[tuple[int, int], np.ndarray] = {}
    for stem, piece in pieces:
        for end in piece[[0, -1]]:
            if contour_ends.size and np.min(np.linalg.norm(contour_ends - end, axis=1)) > tol:
                continue
            for top, other in pieces:
                if top == stem:
                    continue
                d = np.linalg.norm(other - end, axis=1)
                k = int(np.argmin(d))
                arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(other, axis=0), axis=1))]
                interior = min(arc[k], arc[-1] - arc[k]) > 2.0 * tol
                if d[k] <= tol and interior and (stem, top) not in found:
                    found[(stem, top)] = other[k].copy()
    return [(s, t, p) for (s, t), p in found.items()]


def _radius_at(embedding: Embedding2D, bone: int, q: np.ndarray) -> float:
    """Drawn radius of a bone at point ``q``, interpolated between its joints, pixels."""
    s = embedding.solving
    h, t = s.head_joint[bone], s.tail_joint[bone]
    u, _ = _segment_param(q, embedding.joints2d[h], embedding.joints2d[t])
    return float((1.0 - u) * embedding.joint_radius[h] + u * embedding.joint_radius[t])


def ordering_constraints(embedding: Embedding2D, scale: float, names: tuple[str, ...] = (),
                         tolerance: float | None = None) -> list[OrderingConstraint]:
    """All depth-order constraints the drawing implies.

    Args:
        embedding: The 2D embedding.
        scale: Pixels per world unit.
        names: Solving-bone names for the labels (optional).
        tolerance: Junction tolerance in pixels (see :func:`detect_junctions`).

    Returns:
        Occlusion (Eq. 8) and T-junction constraints, without duplicates.
    """
    s = embedding.solving
    out = [occlusion_constraint(embedding, o, scale, names) for o in embedding.occlusions]
    seen = {(o.back_bone, o.front_bone) for o in embedding.occlusions}
    for stem, top, q in detect_junctions(embedding, tolerance):
        shared = {int(s.head_joint[stem]), int(s.tail_joint[stem])} & {
            int(s.head_joint[top]), int(s.tail_joint[top])}
        if shared:
            j = shared.pop()
            far = int(s.tail_joint[stem] if s.head_joint[stem] == j else s.head_joint[stem])
            label = (f"t_junction {names[stem]} turns behind {names[top]}" if names
                     else f"t_junction {stem} behind {top}")
            out.append(OrderingConstraint("t_junction", label, np.array([far]), np.ones(1),
                                          np.array([j]), np.ones(1), 0.0))
        elif (stem, top) not in seen:
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
