"""Data types of the gesture-drawing mode (Bessmeltsev, Vining and Sheffer 2016).

The 2D skeletal embedding (Sections 4-6 of "Gesture3D") places every joint of a *solving
skeleton* in a drawing and matches contour segments to bones. Everything here is in pixels
(origin bottom-left, x right, y up) and independent of the camera, so the 3D lifting step
(Section 7) can consume it with any view.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class SolvingSkeleton:
    """The bones a gesture drawing can show, as a tree of joints.

    Bones are ordered parents first. Joints are the points the embedding places: every
    bone's tail, every root's head and the heads of bones not connected to their solving
    parent. A connected child's head joint is its parent's tail joint.

    Attributes:
        bones: Index of each solving bone in the full :class:`Skeleton`, shape ``(m,)``.
        parent: Index of each bone's parent among the solving bones, -1 for roots, ``(m,)``.
        head_joint: Joint index of each bone's head, shape ``(m,)``.
        tail_joint: Joint index of each bone's tail, shape ``(m,)``.
        joint_bones: Display name of each joint (``"forearm.L head"``), length ``J``.
        joint_parent: Parent joint of each joint in the joint tree, -1 for the root, ``(J,)``.
        joint_link_bone: Solving bone that links each joint to its parent joint, or -1
            when the link is a rigid offset (an unconnected bone's head), shape ``(J,)``.
        rest_joints: Rest (bind-pose) world positions of the joints, ``(J, 3)``, world units.
        excluded: Full-skeleton indices of the deforming bones left out (they follow their
            parents), shape ``(k,)``.
        extends: Joints the drawn shape goes on past, ``(J,)`` bool: continued by
            excluded bones (a hand tail followed by fingers), or a root with one child
            whose rigidly hung branches reach beyond it (``solving.branches_past_root``).
    """

    bones: np.ndarray
    parent: np.ndarray
    head_joint: np.ndarray
    tail_joint: np.ndarray
    joint_bones: tuple[str, ...]
    joint_parent: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    joint_link_bone: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    rest_joints: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    excluded: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    extends: np.ndarray | None = None

    @property
    def n_bones(self) -> int:
        """Number of solving bones ``m``."""
        return len(self.bones)

    @property
    def n_joints(self) -> int:
        """Number of joints ``J``."""
        return len(self.joint_bones)

    def joint_children(self, j: int) -> np.ndarray:
        """Child joints of joint ``j`` in the joint tree, shape ``(k,)``."""
        return np.flatnonzero(self.joint_parent == j)

    @property
    def limb_ends(self) -> np.ndarray:
        """Joints of degree one in the joint tree, ``(J,)`` bool.

        The ends of the limbs, head and tail (and a root with a single child), whether or
        not an excluded bone continues them: a hand with fingers still ends its arm in the
        drawing. Section 5.4's enumeration places these; :attr:`terminal` (the joints with
        an end cap of their own) decides the unary cost.
        """
        degree = (self.joint_parent >= 0).astype(int)
        np.add.at(degree, self.joint_parent[self.joint_parent >= 0], 1)
        return degree <= 1

    @property
    def terminal(self) -> np.ndarray:
        """Joints where the drawn shape ends, ``(J,)`` bool.

        These are the joints of degree one in the joint tree (leaves, and a root with a
        single child) that the drawn shape does not go on past (see ``extends``).
        """
        degree = (self.joint_parent >= 0).astype(int)
        np.add.at(degree, self.joint_parent[self.joint_parent >= 0], 1)
        ends = degree <= 1
        if self.extends is not None:
            ends &= ~self.extends
        return ends


@dataclass(frozen=True)
class Occlusion:
    """One bone drawn in front of another where their outlines cross.

    Attributes:
        front_bone: Solving-bone index of the occluding bone.
        back_bone: Solving-bone index of the occluded bone.
        point2d: Where the occlusion is seen, pixels, shape ``(2,)``.
        front_radius: Radius of the front bone there, pixels.
        back_radius: Radius of the back bone there, pixels.
    """

    front_bone: int
    back_bone: int
    point2d: np.ndarray
    front_radius: float
    back_radius: float


@dataclass(frozen=True)
class Embedding2D:
    """The 2D skeletal embedding of a gesture drawing (Gesture3D Sections 4-6).

    Attributes:
        solving: The solving skeleton the joints belong to.
        joints2d: Joint positions, pixels, shape ``(J, 2)``.
        joint_visible: Whether each joint was placed from the contours (True) or on the
            occlusion grid (False), shape ``(J,)``.
        joint_radius: Radius of the joint's circle, pixels, shape ``(J,)``.
        joint_side: Side of its originating contour each joint lies on (+1 left of the
            contour's direction, -1 right, 0 grid), shape ``(J,)``.
        joint_segments: Per joint, the contour samples its circle matched, ``(k, 2)`` arrays.
        bone_segments: Per solving bone, the contour pieces matched to it, each ``(k, 2)``.
        bone_segment_sides: Parallel to ``bone_segments``: +1 for pieces left of the bone
            (head to tail direction), -1 for pieces on its right.
        occlusions: Detected occlusions (may be empty; the 3D step can detect its own).
        contours: The preprocessed contours (resampled strokes), each ``(k, 2)``, pixels.
        contour_normals: Unit left normals of ``contours``, each ``(k, 2)``.
        bridges: Gestalt bridges as ``(stroke_a, end_a, stroke_b, end_b)`` with ends 0
            (start) or 1 (end), shape ``(b, 4)`` int.
        epsilon: Resampling step, pixels (2% of the drawing's bounding-box diagonal).
        coverage: Fraction of contour samples matched to some bone or joint, in ``[0, 1]``.
        e_match: The minimized matching energy (Eq. 4).
        terms: Summed terms of ``e_match`` (``"unary"``, ``"pairwise"``, ``"triplet"``,
            ``"overlap"``) and counts.
        timings: Seconds per stage (``"preprocess"``, ``"candidates"``, ``"mrf"``, ...).
        warnings: Human-readable notes (skipped joints, unmet constraints).
        body_up: Which way the character's up points in the drawing (``"up"``,
            ``"left"``, ``"down"``, ``"right"``: ``depth.start.BODY_UPS``), as the fit was
            told; the 3D step starts from the bind pose rolled the same way.
    """

    solving: SolvingSkeleton
    joints2d: np.ndarray
    joint_visible: np.ndarray
    joint_radius: np.ndarray
    bone_segments: tuple[tuple[np.ndarray, ...], ...]
    bone_segment_sides: tuple[tuple[int, ...], ...]
    occlusions: tuple[Occlusion, ...]
    contours: tuple[np.ndarray, ...]
    contour_normals: tuple[np.ndarray, ...]
    coverage: float
    e_match: float
    terms: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    joint_side: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    joint_segments: tuple[np.ndarray, ...] = ()
    bridges: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), int))
    epsilon: float = 0.0
    warnings: tuple[str, ...] = ()
    body_up: str = "up"

    def bone_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Head and tail of every solving bone in the drawing, each ``(m, 2)`` pixels."""
        s = self.solving
        return self.joints2d[s.head_joint], self.joints2d[s.tail_joint]

    def joint_index(self, bone_name_end: str) -> int:
        """Index of the joint displayed as ``bone_name_end`` (e.g. ``"forearm.L tail"``)."""
        return self.solving.joint_bones.index(bone_name_end)
