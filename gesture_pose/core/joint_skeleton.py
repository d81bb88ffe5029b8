"""Joint skeletons of imported rigs whose bones have token lengths (glTF).

glTF stores joints, not bones: it has no bone tails. Blender's glTF importer gives every
bone a made-up tail (a token length of about a centimetre, or the distance to a child
along some local axis) that does not reach the bone's children. Every posing method reads
bones as head -> tail segments, so such a rig is replaced, for the solvers only, by its
**joint skeleton**: each bone runs from its head to its principal child's head (the child
the chain continues through), end bones along their skinned mesh.

The joint skeleton keeps the heads, names, parents and flags of the real bones (a bone is
connected when it is its parent's principal child); only the
tails and the rest frames change. Bone ``i``'s new rest frame is ``R'_i = R_i C_i`` with
the constant frame change ``C_i`` (the smallest rotation taking the bone's local +Y to
the new segment, so the roll is kept as well as it can be). The world rotation of each
bone is the same in both descriptions, ``F'_i = F_i C_i``; with the forward kinematics of
``core/skeleton.py`` (``F_i = F_p R_p^T R_i Q_i``) this holds for every pose exactly when
the local transforms are conjugated::

    Q'_i = C_i^T Q_i C_i,      t'_i = C_i^T t_i          (real -> joint skeleton)
    Q_i  = C_i Q'_i C_i^T,     t_i  = C_i t'_i           (joint skeleton -> real)

because ``F'_p R'_p^T R'_i Q'_i = F_p C_p C_p^T R_p^T R_i C_i C_i^T Q_i C_i = F_i C_i``
and the heads ``h_i = h_p + F_p R_p^T (r_i - r_p + R_i t_i)`` are unchanged. Skinning
(``F_i R_i^T``) is unchanged too, so the mesh deforms the same in both descriptions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .names import mirror_name
from .rotations import normalize, rotation_between
from .skeleton import Pose, Skeleton

_Y = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class JointSkeleton:
    """A token-bone rig seen as head-to-child-head bones.

    Attributes:
        skeleton: The joint skeleton (same bones, heads and order as the rig).
        frame_change: ``C_i`` with ``R'_i = R_i C_i``, shape ``(n, 3, 3)`` (identity for
            bones whose frame did not change).
        principal_child: The child each bone now ends at, ``(n,)`` int, -1 for bones
            ending on their mesh or along their parent.
    """

    skeleton: Skeleton
    frame_change: np.ndarray
    principal_child: np.ndarray


def _size(skeleton: Skeleton) -> float:
    """Diagonal of the rest heads' and tails' bounding box, world units."""
    pts = np.concatenate([skeleton.rest_heads, skeleton.rest_tails])
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


def reaching_bones(skeleton: Skeleton, reach: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Which bones' tails reach one of their children.

    A child counts when its head is away from the bone's head (more than 1e-4 of the
    skeleton's size); the bone reaches it when the gap from the bone's tail to the child's
    head is below ``reach`` times the head-to-head distance.

    Args:
        skeleton: The skeleton as read from the rig.
        reach: Largest relative gap of a reached child.

    Returns:
        ``(reaches (n,) bool, has_child (n,) bool)``: bones with a child away from their
        head, and those among them whose tail reaches one.
    """
    p = skeleton.parents
    kids = np.flatnonzero(p >= 0)
    heads, tails = skeleton.rest_heads, skeleton.rest_tails
    span = np.linalg.norm(heads[kids] - heads[p[kids]], axis=1)
    gap = np.linalg.norm(heads[kids] - tails[p[kids]], axis=1)
    away = span > 1e-4 * _size(skeleton)
    has_child = np.zeros(skeleton.n_bones, bool)
    reaches = np.zeros(skeleton.n_bones, bool)
    has_child[p[kids[away]]] = True
    hit = away & (gap < reach * span)
    reaches[p[kids[hit]]] = True
    return reaches, has_child


def has_token_bones(skeleton: Skeleton, share: float = 0.5) -> bool:
    """Whether the rig's bones mostly miss their children (an imported glTF rig).

    Rigs made in Blender chain their bones tail to head; a few bones (a pelvis whose legs
    start beside it) missing their children does not make a token rig. The decision is
    per rig so that proper rigs are read exactly as they are.

    Args:
        skeleton: The skeleton as read from the rig.
        share: Smallest share of the bones with children that miss all of them.

    Returns:
        True when no bone is connected and at least ``share`` of the bones with children
        reach none of them.
    """
    if np.any(skeleton.connected):
        return False
    reaches, has_child = reaching_bones(skeleton)
    return bool(has_child.any() and np.mean(~reaches[has_child]) >= share)


def _chain_lengths(skeleton: Skeleton) -> np.ndarray:
    """Longest head-to-head path down from each bone, world units, ``(n,)``."""
    p = skeleton.parents
    out = np.zeros(skeleton.n_bones)
    for i in range(skeleton.n_bones - 1, 0, -1):  # children after parents
        if p[i] >= 0:
            step = np.linalg.norm(skeleton.rest_heads[i] - skeleton.rest_heads[p[i]])
            out[p[i]] = max(out[p[i]], step + out[i])
    return out


def _twins(skeleton: Skeleton, kids: list[int], chain: np.ndarray, i: int,
           tol: float = 0.02) -> set[int]:
    """Children of bone ``i`` that form a left/right pair by their shape alone.

    Two children are a pair when they are the only two at the same distance from the
    bone's head with chains of the same length below (within ``tol``), and apart (more
    than a twentieth of that distance): mirror images whatever their names (``b_Left..._15``
    and ``b_Right..._19`` in the Khronos fox). Four fingers alike are not a pair.
    """
    heads = skeleton.rest_heads
    dist = np.array([np.linalg.norm(heads[c] - heads[i]) for c in kids])
    length = chain[kids]
    alike = ((np.abs(dist[:, None] - dist[None]) <= tol * np.maximum(dist[:, None], dist[None]))
             & (np.abs(length[:, None] - length[None])
                <= tol * np.maximum(length[:, None], length[None]) + 1e-12))
    apart = np.linalg.norm(heads[kids][:, None] - heads[kids][None], axis=2) > 0.05 * dist[:, None]
    mate = alike & apart
    out = set()
    for a in range(len(kids)):
        if mate[a].sum() == 1:
            b = int(np.flatnonzero(mate[a])[0])
            if mate[b].sum() == 1:
                out.add(kids[a])
    return out


def principal_children(skeleton: Skeleton) -> np.ndarray:
    """The child each bone's chain continues through, ``(n,)`` int, -1 for none.

    Children whose heads sit on the bone's head are skipped, and so are left/right pairs
    of siblings, told by their names (``.L``/``.R``, ``Left``/``Right``) or their shape
    (``_twins``): shoulders and legs branch off a spine that continues to the neck. Of the
    rest, the child starting the longest chain below is taken (spine over tail, middle
    finger over thumb). A bone whose children are all in pairs has no principal child.

    Args:
        skeleton: The skeleton as read from the rig.
    """
    chain = _chain_lengths(skeleton)
    tiny = 1e-4 * _size(skeleton)
    names = skeleton.names
    out = -np.ones(skeleton.n_bones, dtype=int)
    for i in range(skeleton.n_bones):
        kids = [int(c) for c in skeleton.children(i)
                if np.linalg.norm(skeleton.rest_heads[c] - skeleton.rest_heads[i]) > tiny]
        if not kids:
            continue
        kid_names = {names[c] for c in kids}
        paired = _twins(skeleton, kids, chain, i)
        single = [c for c in kids if mirror_name(names[c]) not in kid_names and c not in paired]
        if single:
            reach = [np.linalg.norm(skeleton.rest_heads[c] - skeleton.rest_heads[i]) + chain[c]
                     for c in single]
            out[i] = single[int(np.argmax(reach))]
    return out


def _end_segment(i: int, skeleton: Skeleton, directions: np.ndarray, lengths: np.ndarray,
                 vertices: np.ndarray | None, weights: np.ndarray | None
                 ) -> tuple[np.ndarray, float]:
    """Direction and length of a bone without a principal child.

    Along its skinned region when it has one (the vertices it moves most, at least 8 of
    them with weight 0.5 or more): from the head to their centroid, as long as the region's
    95th-percentile reach along that direction. Otherwise along its parent's new direction,
    half as long (its own direction and length for a root).

    Returns:
        ``(unit direction (3,), length)``.
    """
    head = skeleton.rest_heads[i]
    if vertices is not None and weights is not None:
        region = vertices[weights[:, i] >= 0.5]
        if len(region) >= 8:
            centre = region.mean(axis=0) - head
            if np.linalg.norm(centre) > 1e-3 * _size(skeleton):
                d = normalize(centre)
                return d, float(max(np.percentile((region - head) @ d, 95.0),
                                    np.linalg.norm(centre)))
    p = skeleton.parents[i]
    if p >= 0 and lengths[p] > 0:
        return directions[p], 0.5 * float(lengths[p])
    d = skeleton.rest_tails[i] - head
    return normalize(d), float(np.linalg.norm(d))


def joint_skeleton(skeleton: Skeleton, vertices: np.ndarray | None = None,
                   weights: np.ndarray | None = None) -> JointSkeleton:
    """The head-to-child-head skeleton of a token-bone rig.

    Bones with a principal child (:func:`principal_children`) end at its head; bones
    whose children come in left/right pairs end between the pair's heads when that is
    away from their own head; the others end along their skinned mesh (see
    ``_end_segment``). With weights given, bones that move no vertex at all stop counting
    as deforming (an imported rig's root bone at the floor is not a limb).

    Args:
        skeleton: The rig's skeleton as read (token bones).
        vertices: Rest mesh vertices in world space, ``(V, 3)``, or None.
        weights: Normalized skin weights per bone, ``(V, n)``, or None.

    Returns:
        The joint skeleton and the frame changes.
    """
    n = skeleton.n_bones
    heads = np.asarray(skeleton.rest_heads, dtype=float)
    principal = principal_children(skeleton)
    tiny = 1e-4 * _size(skeleton)
    directions = np.zeros((n, 3))
    lengths = np.zeros(n)
    for i in range(n):  # parents first: end bones may follow their parent
        target = None
        if principal[i] >= 0:
            target = heads[principal[i]]
        elif len(skeleton.children(i)) >= 2:
            mid = heads[skeleton.children(i)].mean(axis=0)
            if np.linalg.norm(mid - heads[i]) > 0.1 * np.linalg.norm(
                    heads[skeleton.children(i)] - heads[i], axis=1).max():
                target = mid
        if target is not None and np.linalg.norm(target - heads[i]) > tiny:
            d = target - heads[i]
            lengths[i] = float(np.linalg.norm(d))
            directions[i] = d / lengths[i]
        else:
            directions[i], lengths[i] = _end_segment(i, skeleton, directions, lengths,
                                                     vertices, weights)
    rest = np.asarray(skeleton.rest_frames, dtype=float)
    local = np.einsum("nji,nj->ni", rest, directions)  # R_i^T d_i
    change = rotation_between(np.broadcast_to(_Y, local.shape), local)
    deform = np.asarray(skeleton.deform, dtype=bool).copy()
    if weights is not None and len(weights):
        deform &= np.asarray(weights).max(axis=0) > 0
    # A bone starts where its parent's new segment ends when it is that parent's principal
    # child: it is connected in the joint skeleton as it would be in a rig with tails.
    par = np.asarray(skeleton.parents)
    connected = (par >= 0) & (principal[np.maximum(par, 0)] == np.arange(n))
    joint = Skeleton(skeleton.names, skeleton.parents, heads, heads + directions *
                     lengths[:, None], rest @ change, skeleton.inherit_rotation,
                     connected, deform)
    return JointSkeleton(joint, change, principal)


def to_joint_pose(pose: Pose, frame_change: np.ndarray) -> Pose:
    """A rig pose in the joint skeleton's frames: ``Q' = C^T Q C``, ``t' = C^T t``.

    Args:
        pose: Local rotations and translations of the real bones.
        frame_change: ``C``, shape ``(n, 3, 3)``.
    """
    c = np.asarray(frame_change, dtype=float)
    ct = np.swapaxes(c, 1, 2)
    return Pose(ct @ np.asarray(pose.rotations, dtype=float) @ c,
                np.einsum("nij,nj->ni", ct, np.asarray(pose.translations, dtype=float)))


def from_joint_pose(pose: Pose, frame_change: np.ndarray) -> Pose:
    """A joint-skeleton pose in the real bones' frames: ``Q = C Q' C^T``, ``t = C t'``.

    Args:
        pose: Local rotations and translations in the joint skeleton's frames.
        frame_change: ``C``, shape ``(n, 3, 3)``.
    """
    c = np.asarray(frame_change, dtype=float)
    return Pose(c @ np.asarray(pose.rotations, dtype=float) @ np.swapaxes(c, 1, 2),
                np.einsum("nij,nj->ni", c, np.asarray(pose.translations, dtype=float)))


def remap_axis_settings(lock: np.ndarray, limits: np.ndarray, frame_change: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation locks and IK limits of the real bones, on the joint skeleton's axes.

    A rotation about the real local axis ``e_k`` is a rotation about ``C^T e_k`` in the
    joint skeleton's frame. When ``C`` is a signed axis permutation that is again a
    coordinate axis (the limits change sign with it); otherwise the setting cannot be
    expressed per axis and is dropped.

    Args:
        lock: Locked local axes, ``(n, 3)`` bool.
        limits: IK limits ``[min, max]`` per axis, radians, ``(n, 3, 2)`` (NaN = free).
        frame_change: ``C``, ``(n, 3, 3)``.

    Returns:
        ``(lock (n, 3), limits (n, 3, 2), dropped (n,) bool)``: the settings on the new
        axes, and the bones whose settings were dropped.
    """
    lock = np.asarray(lock, dtype=bool)
    limits = np.asarray(limits, dtype=float)
    new_lock = np.zeros_like(lock)
    new_limits = np.full_like(limits, np.nan)
    dropped = np.zeros(len(lock), bool)
    for i in np.flatnonzero(lock.any(axis=1) | np.isfinite(limits).any(axis=(1, 2))):
        image = np.asarray(frame_change[i]).T  # column k: C^T e_k
        rounded = np.round(image)
        if np.abs(image - rounded).max() > 1e-6:
            dropped[i] = True
            continue
        for k in range(3):
            m = int(np.flatnonzero(rounded[:, k])[0])
            sign = rounded[m, k]
            new_lock[i, m] = lock[i, k]
            new_limits[i, m] = np.sort(sign * limits[i, k]) if sign < 0 else limits[i, k]
    return new_lock, new_limits, dropped
