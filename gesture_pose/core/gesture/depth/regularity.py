"""Regularity cues of the 3D lifting (Gesture3D Section 7).

- **Same direction (hard).** Consecutive links whose drawn directions are within 10
  degrees are read as one straight limb: their 3D unit directions are made equal,
  ``(X_c - X_b) / l_bc - (X_b - X_a) / l_ab = 0``, linear in the joint positions.
- **Contacts (hard).** Two joints far apart in the skeleton whose drawn circles meet
  (without one covering the other) and whose contour pieces touch are in contact: their
  depths may differ by at most the sum of their radii, ``|d_i - d_j| <= (r_i + r_j) /
  scale``.
- **Limb splines (soft).** For each limb (a joint-tree path from a branch point or the
  root to a terminal joint) a quadratic curve is fitted to the drawn joints; the joints
  within half their radius of it are attracted to the quadratic fitted to the limb's 3D
  joints, ``|| ((I - H) X)_j ||^2`` with ``H`` the least-squares hat matrix of the fit.

- **The spine's straight runs (ours).** Where consecutive links of the body's axis (from
  the root, the unsided chain through the chest: pelvis to head; to the first branch
  point on a rig without sides in its names) are drawn within 10 degrees of each other
  and one of them is drawn longer than it is, the joints between them are placed along
  the drawn run in the proportions of the bind pose's image, each with the joints the 2D
  fit moves rigidly with it (:func:`spine_runs`): inside the drawn torso the contours
  say where the run goes, not where along it those joints are.

Near-symmetric limbs are handled after the solve (:mod:`.symmetry`).
"""

from __future__ import annotations

import numpy as np

from ...names import side_of
from ..mrf import interior_joints, rigid_descendants, rigid_joints
from ..solving import mirror_name
from ..types import Embedding2D, SolvingSkeleton
from .energies import LinearTerm, ViewFrame
from .ordering import ancestors
from .qp import LinearConstraint


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between 2D vectors, radians, shape ``(k,)``."""
    cos = np.sum(u * v, axis=-1) / np.maximum(
        np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-12)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def parallel_pairs(joint_parent: np.ndarray, joints2d: np.ndarray,
                   max_angle: float = np.radians(10.0), ratios: np.ndarray | None = None,
                   max_ratio_gap: float = 0.2, rest_joints: np.ndarray | None = None,
                   max_rest_angle: float = np.radians(30.0)) -> np.ndarray:
    """Consecutive links drawn in nearly the same direction (and equally foreshortened).

    Two links with one 3D direction are foreshortened alike, so a pair whose drawn
    foreshortening differs by more than ``max_ratio_gap`` is not one straight limb but a
    bend in depth, and is left out; so is a pair bent by more than ``max_rest_angle`` in
    the bind pose (an ankle drawn straight in a front view is a foot pointing at the
    viewer, not a straight leg).

    Args:
        joint_parent: Parent joint per joint, -1 for roots, shape ``(J,)``.
        joints2d: Drawn joints, pixels, shape ``(J, 2)``.
        max_angle: Largest angle between the drawn directions, radians (paper: 10 deg).
        ratios: Foreshortening of the link ending at each joint, shape ``(J,)`` (optional).
        max_ratio_gap: Largest difference of the two links' foreshortening.
        rest_joints: Bind-pose joints, shape ``(J, 3)`` (optional).
        max_rest_angle: Largest bend of the pair in the bind pose, radians.

    Returns:
        Joint triples ``(a, b, c)`` with ``a`` parent of ``b`` parent of ``c``, ``(k, 3)``.
    """
    jp = np.asarray(joint_parent)
    c = np.flatnonzero(jp >= 0)
    b = jp[c]
    keep = b >= 0
    c, b = c[keep], b[keep]
    a = jp[b]
    keep = a >= 0
    a, b, c = a[keep], b[keep], c[keep]
    keep = _angle(joints2d[b] - joints2d[a], joints2d[c] - joints2d[b]) <= max_angle
    if ratios is not None:
        keep &= np.abs(ratios[c] - ratios[b]) <= max_ratio_gap
    if rest_joints is not None:
        keep &= _angle(rest_joints[b] - rest_joints[a], rest_joints[c] - rest_joints[b]
                       ) <= max_rest_angle
    return np.stack([a, b, c], axis=1)[keep].reshape(-1, 3)


def direction_constraints(triples: np.ndarray, rest_joints: np.ndarray, X: np.ndarray,
                          labels: tuple[str, ...] = ()) -> LinearConstraint:
    """Equal 3D unit directions for each triple, 2 rows each.

    ``u_ab = (X_b - X_a) / l_ab`` and ``u_bc`` are unit vectors, so their difference has no
    first-order component along ``n = u_ab + u_bc``; a third row along ``n`` would make the
    linearized system rank deficient and, at second order, inconsistent. The rows are
    therefore ``e_k . (u_bc - u_ab) = 0`` for two unit vectors ``e_1, e_2`` orthogonal to
    ``n`` at the current positions ``X`` (rebuilt every SQP iteration).

    Args:
        triples: ``(a, b, c)`` joint triples, shape ``(k, 3)``.
        rest_joints: Rest joints (for the link lengths), shape ``(J, 3)``.
        X: Current joint positions, shape ``(J, 3)``.
        labels: Joint names for the labels (optional).

    Returns:
        Equality rows on the flattened joint positions.
    """
    n_j = len(rest_joints)
    A = np.zeros((len(triples), 2, n_j, 3))
    names = []
    for i, (a, b, c) in enumerate(triples):
        l1 = np.linalg.norm(rest_joints[b] - rest_joints[a])
        l2 = np.linalg.norm(rest_joints[c] - rest_joints[b])
        n = (X[b] - X[a]) / l1 + (X[c] - X[b]) / l2
        n = n / max(np.linalg.norm(n), 1e-12)
        helper = np.eye(3)[int(np.argmin(np.abs(n)))]
        e1 = np.cross(n, helper)
        e1 /= np.linalg.norm(e1)
        basis = np.stack([e1, np.cross(n, e1)])
        A[i, :, c] += basis / l2
        A[i, :, b] -= basis / l2 + basis / l1
        A[i, :, a] += basis / l1
        tag = f"{labels[b]}" if labels else f"joint {b}"
        names.extend([f"straight at {tag}"] * 2)
    A = A.reshape(2 * len(triples), 3 * n_j)
    zero = np.zeros(len(A))
    return LinearConstraint(A, zero, zero.copy(), tuple(names))


def _tree_distance(joint_parent: np.ndarray) -> np.ndarray:
    """Number of links between every pair of joints (``J`` across trees), ``(J, J)``."""
    n = len(joint_parent)
    path = [[j] for j in range(n)]
    for j in range(n):
        while joint_parent[path[j][-1]] >= 0:
            path[j].append(int(joint_parent[path[j][-1]]))
    depth = np.array([len(p) - 1 for p in path])
    dist = np.zeros((n, n), dtype=int)
    for i in range(n):
        anc_i = {a: k for k, a in enumerate(path[i])}
        for j in range(n):
            common = next((a for a in path[j] if a in anc_i), -1)
            dist[i, j] = n if common < 0 else depth[i] + depth[j] - 2 * depth[common]
    return dist


def _mirrored(a: str, b: str) -> bool:
    """Whether two joint names (``"<bone> head|tail"``) are left/right mirror images."""
    bone_a, _, end_a = a.rpartition(" ")
    bone_b, _, end_b = b.rpartition(" ")
    return end_a == end_b and mirror_name(bone_a) == bone_b


def contact_pairs(embedding: Embedding2D, min_links: int = 4, touch: float | None = None,
                  overlap: tuple[float, float] = (0.6, 1.2),
                  require_segments: bool | None = None) -> np.ndarray:
    """Joint pairs in contact in the drawing.

    Two joints touch when their drawn circles meet rather than cover each other (centre
    distance between ``overlap[0]`` and ``overlap[1]`` times the sum of the radii; one
    circle deep inside the other is an occlusion, as the two front paws of a quadruped
    seen from the side) and, when the fit matched contour samples to both, those samples
    come within ``touch`` of each other (the joints' contour segments are adjacent). A
    joint and its left/right mirror (two knees, two paws) are not taken for a contact:
    in a side view they meet in the image while the body holds them apart.

    Args:
        embedding: The 2D embedding.
        min_links: Only joints at least this many links apart count (nearby joints overlap
            anyway).
        touch: Largest gap between the joints' contour pieces, pixels (default half a
            resampling step, 1 px if unknown).
        overlap: Range of centre distance over the sum of the radii.
        require_segments: Accept only pairs whose contour segments are known and adjacent;
            by default, when the embedding has contours (a drawing, not a projection).

    Returns:
        Joint pairs ``(i, j)``, ``i < j``, shape ``(k, 2)``.
    """
    s: SolvingSkeleton = embedding.solving
    p, r = embedding.joints2d, embedding.joint_radius
    gap = touch if touch is not None else (0.5 * embedding.epsilon if embedding.epsilon > 0
                                           else 1.0)
    dist = _tree_distance(np.asarray(s.joint_parent))
    d2 = np.linalg.norm(p[:, None] - p[None], axis=-1)
    reach = r[:, None] + r[None]
    meet = (d2 >= overlap[0] * reach) & (d2 < overlap[1] * reach)
    cand = np.argwhere(np.triu(meet & (dist >= min_links), 1))
    segs = embedding.joint_segments
    names = s.joint_bones
    if require_segments is None:
        require_segments = len(embedding.contours) > 0
    keep = []
    for i, j in cand:
        if len(names) == len(p) and _mirrored(names[i], names[j]):
            continue
        if require_segments or (len(segs) > max(i, j) and len(segs[i]) and len(segs[j])):
            if len(segs) <= max(i, j) or not len(segs[i]) or not len(segs[j]):
                continue  # no contour evidence of the contact
            sep = np.min(np.linalg.norm(segs[i][:, None] - segs[j][None], axis=-1))
            if sep > gap:
                continue
        keep.append((i, j))
    return np.asarray(keep, dtype=int).reshape(-1, 2)


def contact_constraints(pairs: np.ndarray, embedding: Embedding2D, frame: ViewFrame,
                        labels: tuple[str, ...] = ()) -> LinearConstraint:
    """``|d_i - d_j| <= (r_i + r_j) / scale`` for each contact pair.

    Args:
        pairs: Joint pairs, shape ``(k, 2)``.
        embedding: The 2D embedding (joint radii in pixels).
        frame: The view.
        labels: Joint names (optional).

    Returns:
        Two-sided rows on the flattened joint positions.
    """
    n_j = len(embedding.joints2d)
    A = np.zeros((len(pairs), n_j, 3))
    idx = np.arange(len(pairs))
    A[idx, pairs[:, 0]] += frame.forward
    A[idx, pairs[:, 1]] -= frame.forward
    reach = (embedding.joint_radius[pairs[:, 0]] + embedding.joint_radius[pairs[:, 1]]) \
        / frame.scale
    names = tuple(f"contact {labels[i]}-{labels[j]}" if labels else f"contact {i}-{j}"
                  for i, j in pairs)
    return LinearConstraint(A.reshape(len(pairs), 3 * n_j), -reach, reach, names)


def side_constraints(a: np.ndarray, b: np.ndarray, sides: np.ndarray, frame: ViewFrame,
                     n_joints: int, labels: tuple[str, ...] = ()) -> LinearConstraint:
    """``s (d_b - d_a) >= 0``: each link keeps the depth side ``s`` (ours).

    Args:
        a: Parent joint of each link, shape ``(k,)``.
        b: Child joint of each link, shape ``(k,)``.
        sides: Depth side of each link, +1 (its child joint deeper: away from the viewer)
            or -1, shape ``(k,)``.
        frame: The view (``forward``: depth grows along it).
        n_joints: ``J``.
        labels: One label per link (optional).

    Returns:
        One-sided rows on the flattened joint positions, ``(k, 3J)``.
    """
    sides = np.asarray(sides, float)
    A = np.zeros((len(a), n_joints, 3))
    idx = np.arange(len(a))
    A[idx, b] += frame.forward
    A[idx, a] -= frame.forward
    names = labels or tuple(f"side {i}-{j}" for i, j in zip(a, b, strict=True))
    return LinearConstraint(A.reshape(len(a), 3 * n_joints) * sides[:, None],
                            np.zeros(len(a)), np.full(len(a), np.inf), tuple(names))


def limbs(joint_parent: np.ndarray) -> list[np.ndarray]:
    """Joint paths from each branch point (or root) down to each terminal joint.

    Args:
        joint_parent: Parent joint per joint, shape ``(J,)``.

    Returns:
        One array of joint indices per terminal joint, from the top of the limb down.
    """
    jp = np.asarray(joint_parent)
    n_children = np.bincount(jp[jp >= 0], minlength=len(jp))
    out = []
    for t in np.flatnonzero(n_children == 0):
        path = [int(t)]
        while jp[path[-1]] >= 0:
            path.append(int(jp[path[-1]]))
            if n_children[path[-1]] != 1:
                break
        out.append(np.array(path[::-1]))
    return out


def _hat(joints2d: np.ndarray) -> np.ndarray:
    """Hat matrix of a quadratic least-squares fit over drawn arc length, ``(k, k)``."""
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(joints2d, axis=0), axis=1))]
    t = arc / max(arc[-1], 1e-9)
    V = np.stack([np.ones_like(t), t, t * t], axis=1)
    return V @ np.linalg.pinv(V)


def _runs(limb: np.ndarray, free: np.ndarray) -> list[np.ndarray]:
    """Split a limb where a link is deliberately foreshortened (joint ``free``)."""
    cuts = [i for i in range(1, len(limb)) if free[limb[i]]]
    bounds = [0, *cuts, len(limb)]
    return [limb[lo:hi] for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]


def spline_term(embedding: Embedding2D, rest_joints: np.ndarray, frame: ViewFrame,
                weight: float = 1.0, free: np.ndarray | None = None) -> LinearTerm:
    """The soft limb-spline term on joint depths (see the module docstring).

    A deliberately foreshortened link (E_v weight 0) is a bend in depth, not part of a
    smooth curve: limbs are split there and each run is fitted on its own.

    Args:
        embedding: The 2D embedding.
        frame: The view (depth axis).
        free: Whether the link ending at each joint is deliberately foreshortened,
            shape ``(J,)`` bool (optional).
        rest_joints: Rest joints (for the length normalization), shape ``(J, 3)``.
        weight: Term weight.

    Returns:
        The term (no rows when no limb has 4 joints or more).
    """
    s = embedding.solving
    n_j = len(embedding.joints2d)
    rows = []
    free = np.zeros(n_j, bool) if free is None else np.asarray(free, bool)
    runs = [r for limb in limbs(np.asarray(s.joint_parent)) for r in _runs(limb, free)]
    for limb in runs:
        if len(limb) < 4:
            continue
        H = _hat(embedding.joints2d[limb])
        off = (np.eye(len(limb)) - H) @ embedding.joints2d[limb]
        near = np.linalg.norm(off, axis=1) <= 0.5 * embedding.joint_radius[limb]
        seg = np.linalg.norm(np.diff(rest_joints[limb], axis=0), axis=1).mean()
        for k in np.flatnonzero(near):
            row = np.zeros((n_j, 3))
            row[limb] = (((np.arange(len(limb)) == k) - H[k]) / seg)[:, None] * frame.forward
            rows.append(row.ravel())
    M = np.array(rows).reshape(-1, 3 * n_j)
    return LinearTerm("spline", M, np.zeros(len(M)), np.full(len(M), weight))


def _sided_joints(solving: SolvingSkeleton) -> np.ndarray:
    """Joints whose bone's name has a left/right side (:func:`~...names.side_of`), ``(J,)``."""
    return np.array([side_of(name.rpartition(" ")[0]) is not None
                     for name in solving.joint_bones], dtype=bool)


def spine_chain(solving: SolvingSkeleton, through_branches: bool = False) -> np.ndarray:
    """The spine's joints: from the root along unsided links, to a branch point or beyond.

    At each joint the chain follows the child joint of an unsided bone (no ``.L``/``.R``
    side) with the largest subtree (the body, not a tail hanging from the hips). By
    default it stops at the first joint with more than one child (the chest, where neck
    and arms branch); with ``through_branches`` on a rig with sides it goes on to the end
    of the unsided chain (the head).

    Args:
        solving: The solving skeleton.
        through_branches: Go on past branch points to the end of the unsided chain (the
            body's axis up to the head: chest, neck, head). Only on a rig with sides in
            its names, where the unsided child at the chest is the neck; without them
            (every child unsided) the chain still stops at the first branch point.

    Returns:
        Joint indices, root first, shape ``(k,)`` (just the root when there is no chain).
    """
    jp = np.asarray(solving.joint_parent, int)
    size = np.ones(len(jp), int)
    for j in np.argsort([len(ancestors(jp, j)) for j in range(len(jp))])[::-1]:
        if jp[j] >= 0:
            size[jp[j]] += size[j]
    # The body's root: the root of the largest tree (a prop can be a separate tree).
    chain = [int(max(np.flatnonzero(jp < 0), key=lambda r: size[r]))] if len(jp) else []
    sided = _sided_joints(solving)
    through_branches = through_branches and bool(sided.any())
    while chain:
        kids = [int(k) for k in np.flatnonzero(jp == chain[-1]) if not sided[k]]
        if not kids:
            break
        chain.append(max(kids, key=lambda k: size[k]))
        if np.sum(jp == chain[-1]) != 1 and not through_branches:
            break
    return np.asarray(chain, int)


def axial_joints(solving: SolvingSkeleton) -> np.ndarray:
    """Joints on the body's axis, where the same-direction rule does not apply (ours).

    With left/right sides in the bone names these are the joints of unsided bones (spine,
    neck, head, tail). A rig whose names carry no side at all (no bone has one) would make
    every joint axial and lose the rule on its limbs too; there the axis is the spine
    chain (:func:`spine_chain`, from the root to the first branch point), found from the
    joint tree alone, and the limbs, neck and tails keep the rule.

    Args:
        solving: The solving skeleton.

    Returns:
        Shape ``(J,)`` bool.
    """
    sided = _sided_joints(solving)
    if sided.any():
        return ~sided
    axial = np.zeros(solving.n_joints, bool)
    axial[spine_chain(solving)] = True
    return axial


def rigid_followers(solving: SolvingSkeleton, joint: int,
                    radius: np.ndarray | None = None,
                    stop: np.ndarray | None = None) -> np.ndarray:
    """The joints the 2D fit moves with ``joint``: its rigid neighbourhood below it.

    These are the descendants reached through rigid-offset links (``joint_link_bone <
    0``: the shoulder and hip heads hanging from a chest or pelvis) and, below those, the
    tails of interior bones (a clavicle inside the torso's outline), collected down the
    tree as the 2D fit's rigid groups are (:func:`~..refine.rigid_groups`). A tail is
    interior by the 2D fit's test (:func:`~..mrf.interior_joints`: its circle overlaps
    the circle of the joint its rigid offset starts from), read here with ``radius``;
    the fit reads the mesh's largest radii, which the depth step does not have.

    Args:
        solving: The solving skeleton.
        joint: The joint moved.
        radius: Radius of each joint, world units, ``(J,)``, or None (no interior tails).
        stop: Joints the walk neither collects nor passes through, ``(J,)`` bool, or None
            (:func:`spine_runs` stops at the body's axis, whose joints it places itself:
            joints below an axis joint follow that joint only, not every axis joint above
            it too).

    Returns:
        Joint indices, ``joint`` excluded, shape ``(k,)``.
    """
    return rigid_descendants(np.asarray(solving.joint_parent),
                             _follower_mask(solving, radius, stop), joint)[1:]


def _follower_mask(solving: SolvingSkeleton, radius: np.ndarray | None,
                   stop: np.ndarray | None) -> np.ndarray:
    """The joints :func:`rigid_followers` may collect and pass through, ``(J,)`` bool."""
    interior = None if radius is None else interior_joints(solving, np.asarray(radius, float))
    rigid = rigid_joints(solving, interior)
    return rigid if stop is None else rigid & ~np.asarray(stop, bool)


def spine_runs(solving: SolvingSkeleton, joints2d: np.ndarray, rest_joints: np.ndarray,
               frame: ViewFrame, max_angle: float = np.radians(10.0),
               max_ratio: float = 1.05, radius: np.ndarray | None = None,
               max_spread: float = np.inf) -> np.ndarray:
    """Drawn joints with the spine's straight runs spaced as in the bind pose's image.

    Consecutive links of the body's axis (:func:`spine_chain` through its branch points:
    pelvis to head on a rig with sides) drawn within ``max_angle`` of each other form a
    run. When one of its links is drawn longer than it can be (more than ``max_ratio`` of
    its 3D length), the 2D fit has slid a joint along the run: the inner joints are moved
    along the drawn polyline so that the links divide its length as their bind-pose
    images do. The 2D fit slides a joint with its rigid neighbourhood (a chest with the
    shoulder heads and the clavicles' tails, :func:`rigid_followers`), so each moved
    joint's followers off the axis are translated with it. A run that stops short of the
    axis' free end (at a bend or a branch) is respaced too when its links' drawn
    foreshortening differs by more than ``max_spread`` (ours): links drawn in line at
    1.0 and 0.7 of their lengths would bend the spine by 45 degrees in depth at the
    joint between them, and the 2D fit's slide of that joint is the likelier reading;
    at the free end (a head nodding towards the viewer at the neck) a turned last link
    is not. The run's ends, its drawn path and every other joint stay; a run drawn
    within its lengths keeps its joints otherwise. (On the benchmark's traced drawings
    the 2D fit drew a pelvis link at 40% of its length and the chest above it at 162%,
    which the solve read as a 47 degree pelvis tilt; the run as a whole was drawn at its
    full length. The same slide at the chest, whose tail the 2D fit draws up the neck
    (chests at 112-193% of their length), left necks at 34-86% and heads at 14-65%,
    turned up to 90 degrees out of the view plane; hence the run through the neck to
    the head.)

    Args:
        solving: The solving skeleton.
        joints2d: Drawn joints, pixels, shape ``(J, 2)``.
        rest_joints: Bind-pose joints, world units, shape ``(J, 3)``.
        frame: The view.
        max_angle: Largest angle between consecutive drawn links of a run, radians.
        max_ratio: Drawn over 3D length of a link above which its run is respaced.
        radius: Drawn radius of each joint, pixels, ``(J,)``, for the interior tails
            among the followers (:func:`rigid_followers`), or None (rigid offsets only).
        max_spread: Largest difference of the drawn over 3D lengths of the links of a
            run short of the axis' free end for its joints to stay (``inf``: only
            ``max_ratio`` decides).

    Returns:
        The drawn joints, respaced, shape ``(J, 2)``.
    """
    out = np.array(joints2d, dtype=float)
    chain = spine_chain(solving, through_branches=True)
    if len(chain) < 3:
        return out
    on_axis = np.zeros(len(out), bool)
    on_axis[chain] = True
    world_radius = None if radius is None else np.asarray(radius, float) / frame.scale
    par = np.asarray(solving.joint_parent)
    followers = _follower_mask(solving, world_radius, on_axis)  # see rigid_followers
    drawn = np.diff(out[chain], axis=0)
    straight = _angle(drawn[1:], drawn[:-1]) <= max_angle
    bind = np.linalg.norm(np.diff(rest_joints[chain] @ np.stack([frame.right, frame.up], 1),
                                  axis=0), axis=1)
    ratio = np.linalg.norm(drawn, axis=1) / frame.scale / np.maximum(
        np.linalg.norm(np.diff(rest_joints[chain], axis=0), axis=1), 1e-12)
    start = 0
    for i in range(len(drawn)):
        if i < len(straight) and straight[i]:
            continue
        joints = chain[start:i + 2]  # links start..i
        if (len(joints) > 2 and bind[start:i + 1].sum() > 1e-12
                and (ratio[start:i + 1].max() > max_ratio
                     or (i + 1 < len(drawn) and np.ptp(ratio[start:i + 1]) > max_spread))):
            pts = out[joints]
            arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
            target = np.r_[0.0, np.cumsum(bind[start:i + 1])] / bind[start:i + 1].sum() \
                * arc[-1]
            moved = np.stack([np.interp(target, arc, pts[:, 0]),
                              np.interp(target, arc, pts[:, 1])], 1)[1:-1]
            for j, p in zip(joints[1:-1], moved, strict=True):
                follow = rigid_descendants(par, followers, int(j))[1:]
                out[follow] += p - out[j]
                out[j] = p
        start = i + 1
    return out
