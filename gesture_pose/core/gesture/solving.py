"""The solving skeleton: the bones a gesture drawing can show (Gesture3D Section 5).

Gesture drawings show limbs, torso and head; fingers, toes, face and other bones much
smaller than the drawing's resolution cannot be located and follow their parents. A bone
is kept when it deforms and is at least ``min_bone_epsilons`` resampling steps long, with
the step measured on the rest skeleton the way the drawing's step is measured on the
drawing (2% of the bounding-box diagonal). Given the skin weights, a bone that moves no
skin, itself or through the bones below it, is left out too (ours): an importer marks
every joint of a glTF skin as deforming, IK pole targets and prop sockets included. A bone
collection named "Gesture" overrides the automatic choice.

Joints where the drawn shape ends (end caps, for the unary cost) are the joints of degree
one, unless the shape goes on past them: a tail continued by excluded bones (a hand by its
fingers), or a root whose single child carries branches reaching beyond it (the legs below
a pelvis bone that starts at the crotch, :func:`branches_past_root`).
"""

from __future__ import annotations

import numpy as np

from ..exceptions import InputError
from ..names import mirror_name
from ..skeleton import Skeleton
from .types import SolvingSkeleton


def skinned_subtrees(skeleton: Skeleton, weighted: np.ndarray) -> np.ndarray:
    """Which bones move skin, themselves or through a bone below them, ``(n,)`` bool.

    Args:
        skeleton: The full skeleton.
        weighted: Whether each bone has skin weights, ``(n,)`` bool.

    Returns:
        The mask.
    """
    out = np.asarray(weighted, dtype=bool).copy()
    for i in range(skeleton.n_bones - 1, -1, -1):  # children come after their parents
        p = int(skeleton.parents[i])
        if p >= 0 and out[i]:
            out[p] = True
    return out


def select_bones(skeleton: Skeleton, override: np.ndarray | None = None,
                 min_bone_epsilons: float = 2.0, epsilon_fraction: float = 0.02,
                 weighted: np.ndarray | None = None) -> np.ndarray:
    """Boolean mask of the solving bones, shape ``(n,)``.

    Args:
        skeleton: The full skeleton.
        override: Bones of the "Gesture" collection, ``(n,)`` bool, or None.
        min_bone_epsilons: Shortest kept bone in resampling steps.
        epsilon_fraction: Step as a fraction of the rest bounding-box diagonal.
        weighted: Whether each bone has skin weights, ``(n,)`` bool, or None (not known):
            bones moving no skin (:func:`skinned_subtrees`) are left out when some do.

    Raises:
        InputError: The override is empty or no bone is long enough.
    """
    if override is not None:
        mask = np.asarray(override, dtype=bool)
        if mask.shape != (skeleton.n_bones,) or not mask.any():
            raise InputError("The 'Gesture' bone collection is empty: add the bones a drawing "
                             "shows to it, or delete the collection to choose automatically.")
        return mask
    deform = np.asarray(skeleton.deform, dtype=bool)
    if not deform.any():
        deform = np.ones(skeleton.n_bones, dtype=bool)
    if weighted is not None and np.any(weighted):
        deform = deform & skinned_subtrees(skeleton, weighted)
    pts = np.concatenate([skeleton.rest_heads[deform], skeleton.rest_tails[deform]])
    eps = epsilon_fraction * float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    mask = deform & (skeleton.lengths >= min_bone_epsilons * eps)
    if not mask.any():
        raise InputError("No bone of the armature is long enough to be seen in a drawing.")
    return mask


def build_solving_skeleton(skeleton: Skeleton, mask: np.ndarray) -> SolvingSkeleton:
    """Build the joint tree of the masked bones.

    A bone's solving parent is its nearest masked ancestor. Its head joint is the parent's
    tail joint when it is connected (or its head lies on the parent's tail), the parent's
    head joint when the heads coincide, else a new joint linked to the nearer joint of the
    parent by a rigid offset.

    Args:
        skeleton: The full skeleton.
        mask: Solving bones, ``(n,)`` bool.

    Returns:
        The solving skeleton.
    """
    mask = np.asarray(mask, dtype=bool)
    bones = np.flatnonzero(mask)
    position = -np.ones(skeleton.n_bones, dtype=int)
    position[bones] = np.arange(len(bones))
    pts = np.concatenate([skeleton.rest_heads, skeleton.rest_tails])
    tol = 1e-3 * float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    parent = -np.ones(len(bones), dtype=int)
    head = np.zeros(len(bones), dtype=int)
    tail = np.zeros(len(bones), dtype=int)
    names: list[str] = []
    jparent: list[int] = []
    jlink: list[int] = []
    rest: list[np.ndarray] = []

    def new_joint(name: str, par: int, link: int, where: np.ndarray) -> int:
        names.append(name)
        jparent.append(par)
        jlink.append(link)
        rest.append(where)
        return len(names) - 1

    for k, b in enumerate(bones):
        anc = skeleton.parents[b]
        while anc >= 0 and not mask[anc]:
            anc = skeleton.parents[anc]
        h = skeleton.rest_heads[b]
        name = skeleton.names[b]
        if anc < 0:
            head[k] = new_joint(f"{name} head", -1, -1, h)
        else:
            p = position[anc]
            parent[k] = p
            d_tail = np.linalg.norm(h - skeleton.rest_tails[anc])
            d_head = np.linalg.norm(h - skeleton.rest_heads[anc])
            if (skeleton.connected[b] and skeleton.parents[b] == anc) or d_tail < tol:
                head[k] = tail[p]
            elif d_head < tol:
                head[k] = head[p]
            else:
                near = tail[p] if d_tail <= d_head else head[p]
                head[k] = new_joint(f"{name} head", near, -1, h)
        tail[k] = new_joint(f"{name} tail", head[k], k, skeleton.rest_tails[b])
    excluded = np.flatnonzero(~mask & np.asarray(skeleton.deform, dtype=bool))
    extends = np.zeros(len(names), dtype=bool)
    for e in excluded:
        anc = skeleton.parents[e]
        while anc >= 0 and not mask[anc]:
            anc = skeleton.parents[anc]
        if anc >= 0:
            extends[tail[position[anc]]] = True
    jparent_arr, rest_arr = np.array(jparent, int), np.array(rest)
    extends |= branches_past_root(jparent_arr, np.array(jlink, int), rest_arr)
    return SolvingSkeleton(bones=bones, parent=parent, head_joint=head, tail_joint=tail,
                           joint_bones=tuple(names), joint_parent=jparent_arr,
                           joint_link_bone=np.array(jlink, int), rest_joints=rest_arr,
                           excluded=excluded, extends=extends)


def branches_past_root(joint_parent: np.ndarray, joint_link_bone: np.ndarray,
                       rest_joints: np.ndarray) -> np.ndarray:
    """Roots the drawn shape goes on past, though they have a single child, ``(J,)`` bool.

    A root joint with one child joint ends its chain, and the unary cost takes such an end
    for an end cap (Section 5's terminal joints). That is wrong when the child carries
    branches hung by rigid offsets that reach beyond the root: a pelvis bone running from
    the crotch up to the spine with the legs hanging from its top (the Quaternius rigs read
    as joint skeletons: the Adventurer's ``Hips`` head lies 7 cm below its hip joints and
    the legs go on 0.9 m below it). There the root sits inside the body and is continued
    like a hand tail followed by fingers. A branch reaches beyond the root when one of its
    joints lies farther past the root, along the child-to-root direction, than the root's
    bone is long.

    Args:
        joint_parent: Parent joint of each joint, -1 for roots, ``(J,)`` int.
        joint_link_bone: Solving bone linking each joint to its parent, -1 for a rigid
            offset, ``(J,)`` int.
        rest_joints: Rest positions of the joints, ``(J, 3)``, world units.

    Returns:
        Roots continued past by such a branch, ``(J,)`` bool.
    """
    out = np.zeros(len(joint_parent), dtype=bool)
    for r in np.flatnonzero(joint_parent < 0):
        kids = np.flatnonzero(joint_parent == r)
        if len(kids) != 1:
            continue
        c = int(kids[0])
        axis = rest_joints[r] - rest_joints[c]
        length = float(np.linalg.norm(axis))
        if length <= 0.0:
            continue
        hung = np.flatnonzero((joint_parent == c) & (joint_link_bone < 0))
        members = _subtree(joint_parent, hung)
        past = (rest_joints[members] - rest_joints[r]) @ (axis / length)
        out[r] = bool(members.size) and float(past.max()) > length
    return out


def _subtree(joint_parent: np.ndarray, tops: np.ndarray) -> np.ndarray:
    """The joints ``tops`` and all their descendants in the joint tree, ``(k,)`` int."""
    inside = np.zeros(len(joint_parent), dtype=bool)
    inside[tops] = True
    for j in range(len(joint_parent)):  # parents come before their children
        if joint_parent[j] >= 0 and inside[joint_parent[j]]:
            inside[j] = True
    return np.flatnonzero(inside)


def solving_skeleton(skeleton: Skeleton, override: np.ndarray | None = None,
                     min_bone_epsilons: float = 2.0, weighted: np.ndarray | None = None
                     ) -> SolvingSkeleton:
    """Select the solving bones and build their joint tree (see :func:`select_bones`)."""
    return build_solving_skeleton(skeleton, select_bones(skeleton, override, min_bone_epsilons,
                                                         weighted=weighted))


def symmetric_joint_pairs(solving: SolvingSkeleton) -> np.ndarray:
    """Pairs of left/right joints found from the bone names, shape ``(p, 2)`` int."""
    index = {n: i for i, n in enumerate(solving.joint_bones)}
    out = []
    for i, n in enumerate(solving.joint_bones):
        bone, _, end = n.rpartition(" ")
        m = mirror_name(bone)
        m = None if m is None else f"{m} {end}"
        if m is not None and m in index and index[m] > i:
            out.append((i, index[m]))
    return np.array(out, dtype=int).reshape(-1, 2)
