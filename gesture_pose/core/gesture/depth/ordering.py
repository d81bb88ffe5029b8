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

A third is ours: outlines of a part that stop at its root on the outline of the body it
hangs from (an arm pulled back behind the torso) turn the part away, as the stem of an
intra-part T-junction (:func:`.occlusions.root_junctions`).

All are read from the drawing's contours and the 2D fit's correspondences by
:mod:`.occlusions`; the embedding's own occlusions (known poses, :mod:`.synthetic`) are
used as well. The intra-part rule is off by default (:class:`.solve3d.DepthOptions`): on
traced drawings of known poses it was right for only about 3 junctions in 4 and, as hard
constraints, raised the mean 3D error.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..types import Embedding2D, Occlusion
from . import occlusions
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
        soft: Not enforced: not a constraint of the QPs, only reported (ours;
            :class:`.solve3d.DepthOptions` ``enforce_contour_orders``). Unless that
            option is set, every order the 3D step reads from the drawing's contours
            (:mod:`.occlusions`) starts soft and chooses the start's depth sides; the
            solve makes those the start meets hard (``soft=False``), so in
            ``Pose3DResult.ordering`` the flag marks the contour orders the start
            contradicted.
    """

    kind: str
    label: str
    back: np.ndarray
    back_w: np.ndarray
    front: np.ndarray
    front_w: np.ndarray
    margin: float
    soft: bool = False

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


def ordering_constraints(embedding: Embedding2D, scale: float, names: tuple[str, ...] = (),
                         tolerance: float = 0.5, interior: float = 1.0, min_parts: int = 2,
                         overlap: float = 1.0, t_junctions: bool = False,
                         soft: bool = False, root_junctions: bool = False
                         ) -> list[OrderingConstraint]:
    """All depth-order constraints the drawing implies.

    The embedding's own occlusions, then those detected on its contours
    (:mod:`.occlusions`): a junction between bones at least ``min_parts`` parent-child
    steps apart whose drawn tubes overlap (within ``overlap`` times the sum of their
    radii) is an inter-part occlusion (Eq. 8); one between bones sharing a joint an
    intra-part T-junction (the stem's far joint deeper than the shared one).

    Args:
        embedding: The 2D embedding.
        scale: Pixels per world unit.
        names: Solving-bone names for the labels (optional).
        tolerance: Largest gap between a stem's end and the top contour, resampling steps.
        interior: Smallest arc length from the junction to the top contour's ends, steps.
        min_parts: Fewest parent-child steps between the bones of an occlusion.
        overlap: Largest closest-approach of the two bones' axes over their radii.
        t_junctions: Keep the intra-part T-junctions.
        soft: Mark the orders detected on the contours ``soft`` (the embedding's own
            occlusions stay hard).
        root_junctions: Read the T-junctions at a part's root on the outline of the
            body it hangs from (:func:`.occlusions.root_junctions`, ours): the part turns
            away, its tail deeper than its head.

    Returns:
        Occlusion (Eq. 8) and T-junction constraints, without duplicates.
    """
    s = embedding.solving
    out = [occlusion_constraint(embedding, o, scale, names) for o in embedding.occlusions]
    seen = {(o.back_bone, o.front_bone) for o in embedding.occlusions}
    if not embedding.contours:
        return out
    eps = embedding.epsilon if embedding.epsilon > 0 else 2.0
    raw = occlusions.find_junctions(embedding.contours, eps, embedding.bridges, tolerance,
                                    interior)
    found = occlusions.detect_junctions(embedding, tolerance, interior, found=raw)
    occ, tees = occlusions.junction_occlusions(embedding, found, min_parts, overlap)
    for o in occ:
        if (o.back_bone, o.front_bone) not in seen and (o.front_bone, o.back_bone) not in seen:
            seen.add((o.back_bone, o.front_bone))
            out.append(replace(occlusion_constraint(embedding, o, scale, names), soft=soft))
    for stem, top in tees if t_junctions else ():
        j = ({int(s.head_joint[stem]), int(s.tail_joint[stem])}
             & {int(s.head_joint[top]), int(s.tail_joint[top])}).pop()
        far = int(s.tail_joint[stem] if s.head_joint[stem] == j else s.head_joint[stem])
        label = (f"t_junction {names[stem]} turns behind {names[top]}" if names
                 else f"t_junction {stem} behind {top}")
        out.append(OrderingConstraint("t_junction", label, np.array([far]), np.ones(1),
                                      np.array([j]), np.ones(1), 0.0, soft))
    turned = set()
    for rj in occlusions.root_junctions(embedding, raw) if root_junctions else ():
        b = rj.bone
        if b in turned:
            continue  # the same order, read on the outline of another ancestor
        turned.add(b)
        label = (f"root {names[b]} turns behind {names[rj.occluder]}" if names
                 else f"root {b} behind {rj.occluder}")
        out.append(OrderingConstraint("root_junction", label, np.array([s.tail_joint[b]]),
                                      np.ones(1), np.array([s.head_joint[b]]), np.ones(1),
                                      0.0, soft))
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


def ancestors(joint_parent: np.ndarray, j: int) -> list[int]:
    """Joint ``j`` and its ancestors up to the root, nearest first."""
    out = [int(j)]
    while joint_parent[out[-1]] >= 0:
        out.append(int(joint_parent[out[-1]]))
    return out


def drawn_as_bind(constraints: list[OrderingConstraint], joint_parent: np.ndarray,
                  link_agreement: np.ndarray, keep: float = 0.5) -> np.ndarray:
    """Whether each constraint joins parts drawn, with everything between them, as at bind.

    The relative depth of two parts depends on the links of the joint-tree path between
    them. When every one of those links (and the parts' own) is drawn as the bind pose
    shows it, the drawing repeats the bind pose there and the bind pose's depth order is
    the best guess (E_b keeps those links at their bind vectors): an order read from the
    contours that contradicts it comes from misattributed contour pieces (on the
    benchmark's traced drawings: a neck read behind the spine below it, a quadruped's
    spine behind its own unchanged hind leg).

    Args:
        constraints: Ordering constraints.
        joint_parent: Parent joint of each joint, -1 for the root, ``(J,)``.
        link_agreement: Agreement of the link ending at each joint with its bind
            projection (:func:`.energies.bind_agreement`; anything for the root), ``(J,)``.
        keep: Smallest agreement of a link drawn as at bind.

    Returns:
        Shape ``(k,)`` bool (False for a constraint between separate trees).
    """
    parent = np.asarray(joint_parent, int)
    agree = np.asarray(link_agreement, float) >= keep
    out = np.zeros(len(constraints), bool)
    for i, c in enumerate(constraints):
        joints = {int(j) for j in (*c.back, *c.front)}
        chains = [ancestors(parent, j) for j in joints]
        common = set.intersection(*(set(ch) for ch in chains))
        if not common:
            continue  # parts of separate trees (a prop): no chain of links between them
        # Links below the deepest common ancestor on every chain (child joints).
        links = {j for ch in chains for j in ch[:next(k for k, a in enumerate(ch)
                                                        if a in common)]}
        out[i] = all(agree[j] for j in links)
    return out


TURN_KINDS = ("t_junction", "root_junction")
"""Kinds of order that turn one bone away: its far joint deeper than its near one."""


def turned_joints(constraints: list[OrderingConstraint]) -> np.ndarray:
    """Joints of the enforced (not ``soft``) orders that turn a bone away, sorted, ``(k,)``.

    A T-junction read from the drawing decides that bone's depth side (ours): its
    mirror image, or another labelling of its joints, would break it.
    """
    return np.unique(np.array([int(j) for c in constraints
                               if not c.soft and c.kind in TURN_KINDS
                               for j in (*c.back, *c.front)], dtype=int))


def violations(constraints: list[OrderingConstraint], depths: np.ndarray) -> np.ndarray:
    """Amount by which each constraint is violated (0 when satisfied), world units."""
    return np.array([max(c.margin - c.gap(depths), 0.0) for c in constraints])
