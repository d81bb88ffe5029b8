"""Input checks of abstraction posing: strokes far away, parts seen end-on, unseen bones.

A drawing only says something about what it is drawn over. Three checks run before (and
after) the solve of :mod:`.solver`:

- **far strokes**: a stroke whose nearest point lies farther from the character's projected
  bounding box (abstraction points and representative vertices) than :data:`FAR_FRACTION`
  times the box's larger side is refused, naming the stroke. Matching it would drag the
  whole rig towards it (or, with the newest-N rule, replace a good stroke);
- **end-on bones**: a bone whose projected length is below :data:`END_ON_RATIO` of its
  length seen at its depth points (within about 14 degrees) along the view axis; strokes
  matched to its points cannot tell whether it points towards or away from the view, so
  the solver warns. Curves that all project to almost nothing are refused;
- **undrawn bones**: a bone none of whose parameters moves a matched abstraction point
  (``J_x`` columns zero on the matched rows: no weight on the bone or below it) is not
  seen by the drawing (see :func:`constrained_bones`). By default the solver also keeps
  the bones above the drawn ones (the spine when only an arm is redrawn): only bones
  the matched points are weighted on, and the bones between two of them on a chain, move
  (see :func:`drawn_bones`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..camera import Camera
from ..exceptions import InputError
from ..stroke import Stroke
from .parameters import ParameterSpace

#: A stroke farther than this fraction of the character's projected size from its
#: projected bounding box is refused.
FAR_FRACTION = 0.5
#: A bone whose projected length is below this fraction of its length (in pixels at its
#: depth) points along the view axis (``sin(14.5 deg) = 0.25``).
END_ON_RATIO = 0.25
#: Matched curves (or a draw-over source) shorter than this fraction of the character's
#: projected size project to almost nothing.
TINY_FRACTION = 0.02
#: A bone is drawn on when a matched point has more than this weight on it (the point
#: moves mostly with the bone; a point blended half-half at a joint does not draw the
#: bone beyond the joint, e.g. the fingers at the end of an arm outline).
DRAWN_WEIGHT = 0.5
#: ``J_x`` columns below this fraction of the largest entry count as zero (finite
#: differences of black-box rigs leave round-off there).
SEEN_TOLERANCE = 1e-7


def stroke_name(i: int, labels: Sequence[str]) -> str:
    """A readable name of stroke ``i``: its label, or ``"stroke i+1"``."""
    return labels[i] if i < len(labels) and labels[i] else f"stroke {i + 1}"


def box_gaps(box_lo: np.ndarray, box_hi: np.ndarray, strokes: Sequence[Stroke]) -> np.ndarray:
    """Distance of each stroke's nearest point to an axis-aligned box, pixels, ``(s,)``.

    Args:
        box_lo: Lower corner ``(2,)`` pixels.
        box_hi: Upper corner ``(2,)`` pixels.
        strokes: The strokes.

    Returns:
        0 for a stroke with a point inside the box.
    """
    out = np.empty(len(strokes))
    for i, s in enumerate(strokes):
        outside = np.maximum(np.maximum(box_lo - s.points, s.points - box_hi), 0.0)
        out[i] = float(np.linalg.norm(outside, axis=1).min())
    return out


def check_strokes_near(character_px: np.ndarray, strokes: Sequence[Stroke],
                       labels: Sequence[str] = (), fraction: float = FAR_FRACTION) -> float:
    """Refuse strokes drawn far from the character.

    Args:
        character_px: Projected points of the character (abstraction points and
            representative vertices), shape ``(k, 2)`` pixels.
        strokes: The strokes to be matched.
        labels: Names of the strokes for the message (``"stroke i"`` when missing).
        fraction: Largest allowed gap, as a fraction of the box's larger side.

    Returns:
        The character's projected size (larger side of its box), pixels.

    Raises:
        InputError: A stroke's nearest point is farther than ``fraction`` times the
            character's size from its box (every such stroke is named).
    """
    pts = np.asarray(character_px, dtype=float)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        raise InputError("The character is not in the view: look at it before drawing.")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = max(float(np.max(hi - lo)), 1e-9)
    gaps = box_gaps(lo, hi, strokes)
    far = np.flatnonzero(gaps > fraction * size)
    if far.size:
        names = ", ".join(f"{stroke_name(int(i), labels)} ({gaps[i]:.0f} px away)"
                          for i in far)
        raise InputError(f"Strokes far from the character: {names}; the character is "
                         f"{size:.0f} px tall or wide in this view. Draw the new pose over "
                         "the character, or delete those strokes. Nothing was changed.")
    return size


def projected_length_ratio(camera: Camera, heads: np.ndarray, tails: np.ndarray
                           ) -> np.ndarray:
    """Projected length of segments over their length in pixels at their depth, ``(n,)``.

    1 for a segment parallel to the image plane, 0 for one along the view axis.

    Args:
        camera: The view.
        heads: Segment starts, shape ``(n, 3)`` world.
        tails: Segment ends, shape ``(n, 3)`` world.
    """
    length = np.linalg.norm(tails - heads, axis=1)
    seen = np.linalg.norm(camera.project(tails) - camera.project(heads), axis=1)
    depth = np.maximum(camera.depth(0.5 * (heads + tails)), 1e-6)
    ref = float(np.median(depth))
    ppu = camera.pixels_per_unit(ref) * (ref / depth if camera.is_perspective else 1.0)
    return seen / np.maximum(length * ppu, 1e-12)


def end_on_bones(camera: Camera, heads: np.ndarray, tails: np.ndarray, bones: np.ndarray,
                 ratio: float = END_ON_RATIO) -> np.ndarray:
    """The ``bones`` (indices) whose projection is below ``ratio`` of their length.

    Args:
        camera: The view.
        heads: Posed heads of every bone, ``(n, 3)``.
        tails: Posed tails of every bone, ``(n, 3)``.
        bones: Bones to test, ``(b,)`` int.
        ratio: Threshold of :func:`projected_length_ratio`.
    """
    bones = np.asarray(bones, dtype=int)
    if bones.size == 0:
        return bones
    r = projected_length_ratio(camera, heads[bones], tails[bones])
    return bones[r < ratio]


def end_on_message(names: Sequence[str], after: bool) -> str:
    """The warning for bones seen end-on (before or after the solve)."""
    listed = ", ".join(names)
    one = len(names) == 1
    when = ("ends up pointing" if one else "end up pointing") if after else (
        "points" if one else "point")
    it, points, its, is_ = ("it", "points", "its", "is") if one else ("they", "point",
                                                                   "their", "are")
    return (f"{listed} {when} almost along the view axis: the drawing cannot tell whether "
            f"{it} {points} towards or away from you, so {its} depth is a guess. Check "
            f"from another view, or draw from a view where {it} {is_} seen side-on.")


def constrained_bones(jac_matched: np.ndarray, space: ParameterSpace,
                      tolerance: float = SEEN_TOLERANCE) -> np.ndarray:
    """Bones with a free parameter that moves a matched abstraction point.

    A bone's rotation (scale, translation) moves the points weighted on it or on any bone
    below it; a bone with no such matched point has zero ``J_x`` columns on the matched
    rows and is not constrained by the drawing.

    Args:
        jac_matched: ``J_x`` on the matched abstraction points, shape ``(q, 3, P)``.
        space: The parameter layout of the columns.
        tolerance: Columns whose largest entry is below ``tolerance`` times the largest
            entry overall count as zero.

    Returns:
        Indices of the constrained bones, sorted, ``(b,)``.
    """
    col = np.abs(jac_matched).max(axis=(0, 1)) if jac_matched.size else np.zeros(
        space.n_params)
    seen = col > tolerance * max(float(col.max(initial=0.0)), 1e-300)
    return np.unique(space.column_bones[seen])


def drawn_bones(weights: np.ndarray, parents: np.ndarray,
                min_weight: float = DRAWN_WEIGHT) -> np.ndarray:
    """Bones the matched abstraction points are drawn on, and the bones between them.

    A bone is drawn on when a matched point has a weight of more than ``min_weight`` on it;
    a bone with a drawn bone above it and another below it (the forearm when the upper arm
    and the hand are drawn) carries drawn parts and is included too. Bones above the
    topmost drawn bone of every chain are not.

    Args:
        weights: Normalized bone weights of the matched points, shape ``(q, n)``.
        parents: Parent of every bone (parents first), shape ``(n,)``.
        min_weight: Weight a point must exceed on a bone.

    Returns:
        Sorted bone indices, ``(b,)``.
    """
    drawn = np.asarray(weights > min_weight).any(axis=0)
    n = len(parents)
    above = np.zeros(n, dtype=bool)  # a drawn bone strictly above
    for j in range(n):
        p = parents[j]
        above[j] = p >= 0 and (drawn[p] or above[p])
    below = np.zeros(n, dtype=bool)  # a drawn bone strictly below
    for j in range(n - 1, -1, -1):
        p = parents[j]
        if p >= 0 and (drawn[j] or below[j]):
            below[p] = True
    return np.flatnonzero(drawn | (above & below))


def limb_bones(bones: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """``bones`` and their ancestors up to the first bone with several children.

    The drawn bones' limb: from a forearm, the upper arm and the shoulder, but not the
    chest they branch from (nor anything above it).

    Args:
        bones: Bone indices, ``(b,)``.
        parents: Parent of every bone, ``(n,)``.

    Returns:
        Sorted bone indices.
    """
    children = np.bincount(parents[parents >= 0], minlength=len(parents))
    out = set(int(b) for b in bones)
    for b in bones:
        p = parents[b]
        while p >= 0 and children[p] == 1:
            out.add(int(p))
            p = parents[p]
    return np.array(sorted(out), dtype=int)
