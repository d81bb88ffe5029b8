"""The character's stick model: major joints, stick edges and the bones that move them.

Humanoids are recognised from bone names (``pelvis``/``hips``, ``neck``, ``head``, upper
arm, forearm, hand, thigh, shin, foot, toe with a left/right marker such as ``.L``,
``_L`` or ``Left``). The stick figure of Lin et al. (2012) has a pelvis root of
degree 3 (spine and two legs), a neck of degree 4 (spine, head and two arms), elbows,
wrists, knees and ankles, and optional hand and foot tips.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..exceptions import InputError
from ..names import side_of
from ..rotations import normalize
from ..skeleton import Skeleton

#: Stick joints of a humanoid, parents first: (name, parent joint, optional).
HUMANOID_JOINTS: tuple[tuple[str, str | None, bool], ...] = (
    ("pelvis", None, False),
    ("neck", "pelvis", False),
    ("head", "neck", False),
    ("elbow.L", "neck", False),
    ("wrist.L", "elbow.L", False),
    ("hand.L", "wrist.L", True),
    ("elbow.R", "neck", False),
    ("wrist.R", "elbow.R", False),
    ("hand.R", "wrist.R", True),
    ("knee.L", "pelvis", False),
    ("ankle.L", "knee.L", False),
    ("toe.L", "ankle.L", True),
    ("knee.R", "pelvis", False),
    ("ankle.R", "knee.R", False),
    ("toe.R", "ankle.R", True),
)

_ROLE_WORDS: dict[str, tuple[str, ...]] = {
    "pelvis": ("pelvis", "hips", "hip"),
    "neck": ("neck",),
    "head": ("head",),
    "upper_arm": ("upperarm", "arm", "uparm"),
    "forearm": ("forearm", "lowerarm", "elbow"),
    "hand": ("hand", "wrist"),
    "thigh": ("thigh", "upperleg", "upleg", "hip"),
    "shin": ("shin", "lowerleg", "leg", "calf", "knee"),
    "foot": ("foot", "ankle"),
    "toe": ("toe", "toes", "toebase", "ball"),
}
_SIDED = {"upper_arm", "forearm", "hand", "thigh", "shin", "foot", "toe"}
#: Words of a bone name: runs of letters (digits and separators split them).
_WORDS = re.compile(r"[A-Za-z]+")
#: Words that only say a side (the side itself is read by :func:`~..names.side_of`).
_SIDE_WORDS = {"l", "r", "left", "right"}


def bone_side(name: str) -> str:
    """``"L"``, ``"R"`` or ``""``: the side :func:`~gesture_pose.core.names.side_of` reads.

    The conventions the other modes share: suffixes (``.L``, ``_r``, ``thigh.L.001``),
    a lone ``L``/``R`` token (``Bip01 L Thigh``, ``L_Thigh``) and the words ``Left`` and
    ``Right`` (``LeftForeArm``).
    """
    return side_of(name) or ""


def _name_words(name: str) -> list[str]:
    """The words of a bone name that may say its role, lower case.

    Its letter runs without the words that only say a side (``L``, ``right``) and without
    a leading ``Left``/``Right`` glued to a word (``LeftUpLeg`` -> ``upleg``).
    """
    words = [w for w in _WORDS.findall(name) if w.lower() not in _SIDE_WORDS]
    return [re.sub(r"^(left|right)(?=[A-Z])", "", w, flags=re.I).lower() for w in words]


#: Words that qualify the next one in a role (``upper_arm``, ``lower_leg``): never dropped
#: as a rig prefix.
_QUALIFIERS = {"upper", "lower", "up", "low", "fore"}


@dataclass(frozen=True)
class GeneGroup:
    """Bones that share one set of rotation genes.

    Every bone ``b`` of the group gets the local rotation ``Q0_b exp(B_b g / k)`` with
    ``k = len(bones)`` (a bending spine shares its rotation equally).

    Attributes:
        name: Readable name (``"spine"``, ``"forearm.L"``, ...).
        bones: Bone indices, shape ``(k,)``.
        bases: Local axes of the genes per bone, shape ``(k, 3, m)`` (orthonormal columns).
        bounds: Gene bounds in radians, shape ``(m, 2)``.
        comfort: Unit of the comfort term per gene in radians, shape ``(m,)``; None: the
            range's half-width.
    """

    name: str
    bones: np.ndarray
    bases: np.ndarray
    bounds: np.ndarray
    comfort: np.ndarray | None = None


@dataclass(frozen=True)
class CharacterFigure:
    """The stick model of a character.

    Attributes:
        joint_names: Stick joint names, parents first (``HUMANOID_JOINTS`` order).
        joint_parents: Parent joint per joint, -1 for the pelvis, shape ``(J,)``.
        joint_bones: Bone whose head or tail is the joint, shape ``(J,)``.
        joint_at_tail: Whether the joint is that bone's tail, shape ``(J,)``.
        optional: Joints the drawing may omit (hand and foot tips), shape ``(J,)``.
        root_bone: The pelvis bone (free translation and rotation).
        groups: Rotation gene groups of the other moving bones.
        forward: The character's rest facing direction in world space, shape ``(3,)``.
        up: World up, shape ``(3,)``.
    """

    joint_names: tuple[str, ...]
    joint_parents: np.ndarray
    joint_bones: np.ndarray
    joint_at_tail: np.ndarray
    optional: np.ndarray
    root_bone: int
    groups: tuple[GeneGroup, ...]
    forward: np.ndarray
    up: np.ndarray

    @property
    def n_joints(self) -> int:
        """Number of stick joints."""
        return len(self.joint_names)

    def joint(self, name: str) -> int:
        """Index of the stick joint ``name``."""
        return self.joint_names.index(name)

    def edges(self) -> np.ndarray:
        """Stick edges ``(parent, child)`` as joint indices, shape ``(J - 1, 2)``."""
        child = np.flatnonzero(self.joint_parents >= 0)
        return np.stack([self.joint_parents[child], child], 1)

    def rest_joints(self, skeleton: Skeleton) -> np.ndarray:
        """Joint positions in the rest pose, world units, ``(J, 3)``."""
        return self.joint_positions(skeleton.rest_heads, skeleton.rest_tails)

    def edge_lengths(self, skeleton: Skeleton) -> np.ndarray:
        """Rest 3D length of each stick edge by its child joint (0 at the root), ``(J,)``."""
        pos = self.rest_joints(skeleton)
        out = np.zeros(self.n_joints)
        child = np.flatnonzero(self.joint_parents >= 0)
        out[child] = np.linalg.norm(pos[child] - pos[self.joint_parents[child]], axis=1)
        return out

    def joint_positions(self, heads: np.ndarray, tails: np.ndarray) -> np.ndarray:
        """Joint positions from posed bones, ``(..., n, 3) -> (..., J, 3)``."""
        return np.where(self.joint_at_tail[:, None], tails[..., self.joint_bones, :],
                        heads[..., self.joint_bones, :])


def find_humanoid_bones(skeleton: Skeleton, roles: Mapping[str, str] | None = None
                        ) -> dict[str, int]:
    """Map humanoid roles (``"pelvis"``, ``"upper_arm.L"``, ...) to bone indices by name.

    Args:
        skeleton: The character's skeleton.
        roles: Roles the rig gives outright, ``{role: bone name}`` (a Rigify rig's
            ``spine`` is its pelvis, ``spine.006`` its head); the names decide the rest.

    Returns:
        Roles found; sided roles end in ``.L`` or ``.R``. Only deforming bones are used
        when the armature has any.

    Raises:
        InputError: A role needed by the stick figure is missing.
    """
    found = {role: skeleton.index(name) for role, name in (roles or {}).items()}
    usable = skeleton.deform if np.any(skeleton.deform) else np.ones(skeleton.n_bones, bool)
    names = [_name_words(name) for name in skeleton.names]
    sides = [bone_side(name) for name in skeleton.names]
    # The whole name's words joined first (``upper_arm.L`` -> ``upperarm``); only roles
    # still missing are then looked for without one or two leading words (rig prefixes:
    # ``Bip01 L Thigh``, ``DEF-thigh.L``, ``mixamorig:Hips``), so that a name read whole
    # is never overridden.
    for depth in range(3):
        for i, words_i in enumerate(names):
            if depth >= len(words_i) or _QUALIFIERS & set(words_i[:depth]):
                continue
            word, side = "".join(words_i[depth:]), sides[i]
            for role, words in _ROLE_WORDS.items():
                if word not in words or (role in _SIDED) != bool(side):
                    continue
                key = f"{role}.{side}" if side else role
                if key not in found and (usable[i] or role == "pelvis"):
                    found[key] = i
                break
    required = ["pelvis", "neck", "head"] + [f"{r}.{s}" for s in "LR" for r in
                                             ("upper_arm", "forearm", "hand", "thigh",
                                              "shin", "foot")]
    missing = [r for r in required if r not in found]
    if missing:
        raise InputError(
            f"The armature is not recognised as a humanoid (no bones for {missing}); "
            "name its bones like pelvis/hips, neck, head, upper_arm.L, forearm.L, hand.L, "
            "thigh.L, shin.L, foot.L (and .R), or draw a figure matching its topology.")
    return found


def _path(skeleton: Skeleton, top: int, bottom: int) -> list[int]:
    """Bones strictly between ancestor ``top`` and ``bottom`` plus ``bottom``, top first."""
    chain = skeleton.ancestors(bottom)
    if top not in chain:
        raise InputError(f"Bone '{skeleton.names[bottom]}' is not below "
                         f"'{skeleton.names[top]}': check the armature's hierarchy.")
    return chain[: chain.index(top)][::-1]


def _limb_axes(skeleton: Skeleton, upper: int, lower: int, forward: np.ndarray,
               bend_forward: bool) -> np.ndarray:
    """World hinge axis ``a`` of a limb: rotating the lower bone by ``+theta`` flexes it.

    The rest bend of the limb gives the axis when it exceeds 3 degrees; otherwise the
    limb is assumed to flex forward (elbow) or backward (knee) relative to ``forward``.
    """
    d1 = normalize(skeleton.rest_tails[upper] - skeleton.rest_heads[upper])
    d2 = normalize(skeleton.rest_tails[lower] - skeleton.rest_heads[lower])
    axis = np.cross(d1, d2)
    if np.linalg.norm(axis) > np.sin(np.radians(3.0)):
        return normalize(axis)
    f = forward if bend_forward else -forward
    f = f - d2 * (f @ d2)
    return normalize(np.cross(d2, f))


def _ball(skeleton: Skeleton, bone: int, axis: np.ndarray, bounds_deg) -> tuple:
    """Gene basis of a limb bone: columns hinge axis, bone direction and their cross."""
    d = normalize(skeleton.rest_tails[bone] - skeleton.rest_heads[bone])
    a = normalize(axis - d * (axis @ d))
    world = np.stack([a, d, np.cross(a, d)], 1)
    return skeleton.rest_frames[bone].T @ world, np.radians(np.asarray(bounds_deg, float))


def _group(name, skeleton, bones, basis_bounds, ik_limits, comfort=None) -> GeneGroup:
    """A gene group, replaced by the rig's IK limits when the bone has any.

    ``comfort`` (radians, ``(m,)``) is kept with the default range only: with IK limits
    the comfort unit is their half-width.
    """
    bones = np.asarray(bones, int)
    basis, bounds = basis_bounds
    if ik_limits is not None and len(bones) == 1 and np.any(np.isfinite(ik_limits[bones[0]])):
        lim = ik_limits[bones[0]]
        bounds = np.where(np.isfinite(lim), lim, np.radians([[-120.0, 120.0]] * 3))
        basis, comfort = np.eye(3), None
    bases = np.broadcast_to(basis, (len(bones),) + basis.shape).copy()
    return GeneGroup(name, bones, bases, np.asarray(bounds, float),
                     None if comfort is None else np.asarray(comfort, float))


def humanoid_figure(skeleton: Skeleton, ik_limits: np.ndarray | None = None,
                    up: np.ndarray = (0.0, 0.0, 1.0),
                    roles: Mapping[str, str] | None = None) -> CharacterFigure:
    """Build the stick model of a humanoid skeleton.

    Ranges of motion are the rig's IK limits where set (``ik_limits``, ``(n, 3, 2)``
    radians, NaN where unlimited) and anatomical defaults otherwise: hinge elbows and
    knees flexing 0-150 degrees; shoulders flexing -50 to 170 degrees, abducting +-130 and
    twisting +-80; hips flexing -20 to 130 degrees, abducting +-45 and twisting +-40;
    spine, neck, hands and feet balls of +-30 to 70 degrees.

    Args:
        skeleton: Rest skeleton (world space).
        ik_limits: Optional per-bone IK limits, shape ``(n, 3, 2)``.
        up: World up direction, shape ``(3,)``.
        roles: Roles the rig gives outright (:func:`find_humanoid_bones`).

    Returns:
        The figure.
    """
    b = find_humanoid_bones(skeleton, roles)
    up = normalize(np.asarray(up, float))
    forward = np.array([0.0, -1.0, 0.0])
    f = sum(skeleton.rest_tails[b[f"foot.{s}"]] - skeleton.rest_heads[b[f"foot.{s}"]]
            for s in "LR")
    f = f - up * (f @ up)
    if np.linalg.norm(f) > 1e-3:
        forward = normalize(f)
    pelvis = b["pelvis"]
    joints, bones, at_tail = [], [], []
    for name, _, _ in HUMANOID_JOINTS:
        side = name[-1] if name[-2:] in (".L", ".R") else ""
        base = name[:-2] if side else name
        bone, tail = {
            "pelvis": (pelvis, False), "neck": (b["neck"], False), "head": (b["head"], True),
            "elbow": (b.get(f"forearm.{side}"), False), "wrist": (b.get(f"hand.{side}"), False),
            "hand": (b.get(f"hand.{side}"), True), "knee": (b.get(f"shin.{side}"), False),
            "ankle": (b.get(f"foot.{side}"), False),
            "toe": (b.get(f"toe.{side}", b.get(f"foot.{side}")), True),
        }[base]
        joints.append(name)
        bones.append(bone)
        at_tail.append(tail)
    index = {n: i for i, n in enumerate(joints)}
    parents = np.array([index[p] if p else -1 for _, p, _ in HUMANOID_JOINTS])
    groups = [
        _group("spine", skeleton, _path(skeleton, pelvis, b["neck"])[:-1],
               (np.eye(3), np.radians([[-60, 60], [-45, 45], [-45, 45]])), None),
        _group("head", skeleton, [b["neck"], b["head"]],
               (np.eye(3), np.radians([[-60, 60], [-70, 70], [-50, 50]])), None),
    ]
    for s in "LR":
        ua, fa, hd = b[f"upper_arm.{s}"], b[f"forearm.{s}"], b[f"hand.{s}"]
        th, sh, ft = b[f"thigh.{s}"], b[f"shin.{s}"], b[f"foot.{s}"]
        elbow = _limb_axes(skeleton, ua, fa, forward, True)
        knee = _limb_axes(skeleton, th, sh, forward, False)
        groups += [
            _group(f"upper_arm.{s}", skeleton, [ua],
                   _ball(skeleton, ua, elbow, [[-50, 170], [-80, 80], [-130, 130]]),
                   ik_limits),
            _group(f"forearm.{s}", skeleton, [fa],
                   (skeleton.rest_frames[fa].T @ elbow[:, None], np.radians([[0.0, 150.0]])),
                   ik_limits),
            _group(f"hand.{s}", skeleton, [hd],
                   _ball(skeleton, hd, elbow, [[-70, 70], [-30, 30], [-60, 60]]), ik_limits),
            _group(f"thigh.{s}", skeleton, [th],
                   _ball(skeleton, th, knee, [[-130, 20], [-40, 40], [-45, 45]]), ik_limits),
            _group(f"shin.{s}", skeleton, [sh],
                   (skeleton.rest_frames[sh].T @ knee[:, None], np.radians([[0.0, 150.0]])),
                   ik_limits),
            _group(f"foot.{s}", skeleton, [ft],
                   _ball(skeleton, ft, knee, [[-45, 45], [-30, 30], [-30, 30]]), ik_limits),
        ]
    groups = [g for g in groups if len(g.bones)]
    return CharacterFigure(
        joint_names=tuple(joints), joint_parents=parents, joint_bones=np.array(bones),
        joint_at_tail=np.array(at_tail), optional=np.array([o for *_, o in HUMANOID_JOINTS]),
        root_bone=pelvis, groups=tuple(groups), forward=forward, up=up)


def is_humanoid(figure: CharacterFigure) -> bool:
    """Whether the figure is the humanoid stick model (pelvis, neck, arms, legs)."""
    return figure.joint_names[:2] == ("pelvis", "neck") and "knee.L" in figure.joint_names


def spine_joint(figure: CharacterFigure) -> int:
    """The joint that, with the root, gives the body's main axis.

    The neck for humanoids; otherwise the root's child with the largest subtree.
    """
    if is_humanoid(figure):
        return figure.joint("neck")
    kids = np.flatnonzero(figure.joint_parents == 0)
    size = [np.sum([j in _joint_subtree(figure.joint_parents, k)
                    for j in range(figure.n_joints)]) for k in kids]
    return int(kids[int(np.argmax(size))]) if len(kids) else 0


def _joint_subtree(parents: np.ndarray, j: int) -> set[int]:
    out = {j}
    for k in range(j + 1, len(parents)):
        if parents[k] in out:
            out.add(k)
    return out


def topology_figure(skeleton: Skeleton, ik_limits: np.ndarray | None = None,
                    up: np.ndarray = (0.0, 0.0, 1.0), min_fraction: float = 0.04
                    ) -> CharacterFigure:
    """A stick model for any character: one stick edge per (deforming) bone.

    The root bone's head is the root joint; every bone adds a joint at its tail, drawn from
    its parent's joint (the offset of an unconnected bone, like a hip, is folded into its
    edge). Bones shorter than ``min_fraction`` of the character's height are merged into
    their children. Every bone but the root gets the rig's IK limits where set and
    otherwise the default range of its chain (:func:`topology_ranges`: legs hinge in the
    sagittal plane, spine, neck and tail segments share a plausible total bend). Joints
    are named after their bones.

    Args:
        skeleton: Rest skeleton.
        ik_limits: Optional IK limits, ``(n, 3, 2)`` radians.
        up: World up.
        min_fraction: Shortest bone kept, as a fraction of the height.

    Returns:
        The figure.

    Raises:
        InputError: The armature has several root bones.
    """
    up = normalize(np.asarray(up, float))
    use = skeleton.deform if np.any(skeleton.deform) else np.ones(skeleton.n_bones, bool)
    roots = [i for i in range(skeleton.n_bones) if use[i] and not any(
        use[a] for a in skeleton.ancestors(i)[1:])]
    if len(roots) != 1:
        raise InputError(f"The armature has {len(roots)} root bones among its deforming "
                         "bones: the stick figure needs one root (parent them to one bone).")
    root = roots[0]
    pts = np.concatenate([skeleton.rest_heads, skeleton.rest_tails])
    height = float(np.ptp(pts @ up))
    names, bones, tails, parents = [skeleton.names[root] + ".head"], [root], [False], [-1]
    position = [skeleton.rest_heads[root]]
    joint_of: dict[int, int] = {}
    head_joint: dict[int, int] = {root: 0}
    for i in range(skeleton.n_bones):
        if not use[i]:
            continue
        anc = [a for a in skeleton.ancestors(i)[1:] if use[a]]
        parent_joint = 0
        if anc:
            # Drawn from the parent's tail or, when it starts there, the parent's head.
            options = [joint_of.get(anc[0], 0), head_joint.get(anc[0], 0)]
            gaps = [np.linalg.norm(position[o] - skeleton.rest_heads[i]) for o in options]
            parent_joint = options[int(np.argmin(gaps))]
        head_joint[i] = parent_joint
        if i != root and skeleton.lengths[i] < min_fraction * height and any(
                skeleton.parents[k] == i for k in range(skeleton.n_bones)):
            joint_of[i] = parent_joint
            continue
        joint_of[i] = len(names)
        position.append(skeleton.rest_tails[i])
        names.append(skeleton.names[i])
        bones.append(i)
        tails.append(True)
        parents.append(parent_joint)
    forward = np.array([0.0, -1.0, 0.0])
    # The comfort prior keeps the unit of a +-90 degree ball (+-45 of twist): narrower
    # default ranges limit the pose, they do not pull it harder towards the rest pose.
    groups = [_group(skeleton.names[i], skeleton, [i], basis_bounds, ik_limits,
                     np.radians([90.0, 45.0, 90.0])[:basis_bounds[1].shape[0]])
              for i, basis_bounds in topology_ranges(skeleton, use, root, forward, up)]
    return CharacterFigure(
        joint_names=tuple(names), joint_parents=np.array(parents),
        joint_bones=np.array(bones), joint_at_tail=np.array(tails),
        optional=np.zeros(len(names), bool), root_bone=root, groups=tuple(groups),
        forward=forward, up=up)


#: Default total bend and twist (degrees) of a chain spread over its segments.
CHAIN_BEND = {"trunk": (60.0, 40.0), "neck": (90.0, 60.0), "tail": (180.0, 90.0)}


def bone_chains(skeleton: Skeleton, use: np.ndarray, root: int) -> list[list[int]]:
    """Unbranched runs of used bones below the root, each top first.

    A chain starts at a bone whose parent is the root or has several used children and
    continues while its last bone has exactly one used child.

    Args:
        skeleton: The skeleton.
        use: Bones taking part, shape ``(n,)``.
        root: The root bone (not in any chain).

    Returns:
        The chains, parents first.
    """
    parent = np.array([next((a for a in skeleton.ancestors(i)[1:] if use[a]), -1)
                       for i in range(skeleton.n_bones)])
    kids = [[k for k in range(skeleton.n_bones) if use[k] and parent[k] == i]
            for i in range(skeleton.n_bones)]
    chains = []
    for i in range(skeleton.n_bones):
        if not use[i] or i == root or not (parent[i] == root or len(kids[parent[i]]) != 1):
            continue
        chain = [i]
        while len(kids[chain[-1]]) == 1:
            chain.append(kids[chain[-1]][0])
        chains.append(chain)
    return chains


def chain_kind(skeleton: Skeleton, chain: list[int], has_children: bool, up: np.ndarray,
               ground: float, height: float) -> str:
    """``"leg"``, ``"trunk"``, ``"neck"``, ``"tail"`` or ``"other"`` from the rest shape.

    A leg starts downward (within 60 degrees of down) and ends within 15 % of the height
    above the lowest point; a chain with bones below its end is the trunk; a free chain of
    four or more bones is a tail (or a tentacle); a shorter free one pointing up a neck.
    """
    d = normalize(skeleton.rest_tails[chain[0]] - skeleton.rest_heads[chain[0]])
    end = min(float(skeleton.rest_tails[chain[-1]] @ up), float(skeleton.rest_heads[chain[-1]]
                                                                 @ up))
    if d @ up < -0.5 and end - ground < 0.15 * height and not has_children:
        return "leg"
    if has_children:
        return "trunk"
    if len(chain) >= 4:
        return "tail"
    return "neck" if d @ up > 0.3 else "other"


def _hinge_sign(skeleton: Skeleton, parent: int, bone: int, lateral: np.ndarray) -> float:
    """The sense (+1, -1) about ``lateral`` of the rest bend at ``bone``.

    Returns:
        +1 or -1; 0 when the two bones are straight at rest (within 5 degrees).
    """
    d1 = normalize(skeleton.rest_tails[parent] - skeleton.rest_heads[parent])
    d2 = normalize(skeleton.rest_tails[bone] - skeleton.rest_heads[bone])
    c = np.cross(d1, d2) @ lateral
    return float(np.sign(c)) if abs(c) > np.sin(np.radians(5.0)) else 0.0


def topology_ranges(skeleton: Skeleton, use: np.ndarray, root: int, forward: np.ndarray,
                    up: np.ndarray) -> list[tuple[int, tuple[np.ndarray, np.ndarray]]]:
    """Default gene bases and ranges of motion of a character that is not a humanoid.

    The bones are cut into unbranched chains (:func:`bone_chains`), classified from their
    rest shape (:func:`chain_kind`):

    - **legs** move mostly in the sagittal plane (the plane of ``forward`` and ``up``): the
      top bone is a ball swinging +-100 degrees about the lateral axis, abducting +-45 and
      twisting +-30; the middle bones are hinges about the lateral axis, turned so that a
      positive angle deepens their rest bend, flexing -20..140 degrees (+-120 when
      straight at rest); the last one
      (paw, hoof) flexes +-60 and turns +-15;
    - **trunk, neck and tail** segments bend about both axes across the bone and twist by
      the chain's total (``CHAIN_BEND``: spine 60/40, neck 90/60, tail or tentacle 180/90
      degrees) over its number of segments, so the whole chain bends plausibly however
      finely it is cut;
    - anything else is a ball of +-90 degrees (+-45 of twist).

    Args:
        skeleton: Rest skeleton (world space).
        use: Bones taking part, shape ``(n,)``.
        root: The root bone (free; not returned).
        forward: The character's facing, shape ``(3,)``.
        up: World up, shape ``(3,)``.

    Returns:
        ``(bone, (basis, bounds))`` per used bone but the root, in bone order: basis in the
        bone's local frame, shape ``(3, m)``; bounds in radians, shape ``(m, 2)``.
    """
    pts = np.concatenate([skeleton.rest_heads, skeleton.rest_tails]) @ up
    ground, height = float(pts.min()), float(np.ptp(pts))
    lateral = normalize(np.cross(forward, up))
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    chains = bone_chains(skeleton, use, root)
    for chain in chains:
        below = any(use[k] and chain[-1] in skeleton.ancestors(k)[1:]
                    for k in range(skeleton.n_bones))
        kind = chain_kind(skeleton, chain, below, up, ground, height)
        k = len(chain)
        for pos, b in enumerate(chain):
            if kind == "leg":
                if pos == 0:
                    out[b] = _ball(skeleton, b, lateral, [[-100, 100], [-30, 30], [-45, 45]])
                elif pos == k - 1 and k >= 3:
                    out[b] = _ball(skeleton, b, lateral, [[-60, 60], [-15, 15], [-15, 15]])
                else:
                    # The axis turned so that a positive angle deepens the rest bend.
                    sign = _hinge_sign(skeleton, chain[pos - 1], b, lateral)
                    lim = [-120.0, 120.0] if sign == 0 else [-20.0, 140.0]
                    basis, _ = _ball(skeleton, b, (sign or 1.0) * lateral, [[0, 0]] * 3)
                    out[b] = (basis[:, :1], np.radians([lim]))
            elif kind in CHAIN_BEND:
                bend, twist = (v / k for v in CHAIN_BEND[kind])
                out[b] = (np.eye(3), np.radians([[-bend, bend], [-twist, twist],
                                                 [-bend, bend]]))
            else:
                out[b] = (np.eye(3), np.radians([[-90, 90], [-45, 45], [-90, 90]]))
    return [(b, out.get(b, (np.eye(3), np.radians([[-90, 90], [-45, 45], [-90, 90]]))))
            for b in range(skeleton.n_bones) if use[b] and b != root]


def character_figure(skeleton: Skeleton, ik_limits: np.ndarray | None = None,
                     roles: Mapping[str, str] | None = None
                     ) -> tuple[CharacterFigure, bool]:
    """The humanoid stick model when the bones are recognised, else the topology one.

    Args:
        skeleton: Rest skeleton (world space).
        ik_limits: Optional per-bone IK limits, shape ``(n, 3, 2)``.
        roles: Roles the rig gives outright (:func:`find_humanoid_bones`).

    Returns:
        ``(figure, humanoid)``.
    """
    try:
        return humanoid_figure(skeleton, ik_limits, roles=roles), True
    except InputError:
        return topology_figure(skeleton, ik_limits), False
