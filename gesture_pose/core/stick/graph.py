"""From strokes drawn in any order to a stick figure matched to the character's joints.

Each stroke is split into straight segments at its corners (Douglas-Peucker); segment
endpoints closer than the snapping radius (pixels) merge into one node and an endpoint
near the middle of another segment splits it (a T-junction, such as arms drawn from a
point on the spine line). Very short strokes are contact dots (the contact-point drawing
style of Section 4.1.2). The resulting graph must be a tree; it is matched to the
character's stick model (:class:`~.figure.CharacterFigure`) by topology: every
embedding of the model's tree into the drawn tree is enumerated (optional hand and foot
tips may be missing). Embeddings that differ only by exchanging a left/right pair are
resolved with the front-view sign test: seen from the front, the character's left limbs
are on the image's right of the spine. Any other ambiguity is reported as an error.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..exceptions import InputError
from .figure import CharacterFigure, is_humanoid

#: Default snapping radius in pixels.
SNAP_RADIUS = 20.0


@dataclass(frozen=True)
class DrawnGraph:
    """The drawing as an undirected graph.

    Attributes:
        nodes: Node positions in pixels, shape ``(k, 2)``.
        edges: Node index pairs, shape ``(e, 2)``.
        contacts: Contact dots in pixels, shape ``(c, 2)``.
    """

    nodes: np.ndarray
    edges: np.ndarray
    contacts: np.ndarray

    def degrees(self) -> np.ndarray:
        """Degree of every node, shape ``(k,)``."""
        return np.bincount(self.edges.ravel(), minlength=len(self.nodes))


@dataclass(frozen=True)
class StickFigure:
    """A drawing matched to a character's stick joints.

    Attributes:
        joint_names: The character's stick joint names (figure order).
        points: Joint positions in pixels, shape ``(J, 2)``; NaN where not drawn.
        present: Which joints were drawn, shape ``(J,)``.
        parents: Parent joint per joint, shape ``(J,)``.
        contacts: Contact dots in pixels, shape ``(c, 2)``.
        ambiguous_sides: Pairs (``"arms"``, ``"legs"``) whose left/right guess was weak.
    """

    joint_names: tuple[str, ...]
    points: np.ndarray
    present: np.ndarray
    parents: np.ndarray
    contacts: np.ndarray
    ambiguous_sides: tuple[str, ...] = ()

    def drawn_edges(self) -> np.ndarray:
        """Edges ``(parent, child)`` whose both ends were drawn, shape ``(e, 2)``."""
        child = np.flatnonzero((self.parents >= 0) & self.present)
        return np.stack([self.parents[child], child], 1).reshape(-1, 2)

    def with_points(self, points: np.ndarray) -> StickFigure:
        """A copy with new joint positions, shape ``(J, 2)``."""
        return StickFigure(self.joint_names, np.asarray(points, float), self.present,
                           self.parents, self.contacts, self.ambiguous_sides)

    def swapped(self, pair: str) -> StickFigure:
        """A copy with the left and right ``"arms"`` or ``"legs"`` exchanged."""
        keys = {"arms": ("elbow", "wrist", "hand"), "legs": ("knee", "ankle", "toe")}[pair]
        pts, present = self.points.copy(), self.present.copy()
        for k in keys:
            i, j = self.joint_names.index(f"{k}.L"), self.joint_names.index(f"{k}.R")
            pts[[i, j]] = pts[[j, i]]
            present[[i, j]] = present[[j, i]]
        return StickFigure(self.joint_names, pts, present, self.parents, self.contacts,
                           tuple(a for a in self.ambiguous_sides if a != pair))


def simplify(points: np.ndarray, tol: float) -> np.ndarray:
    """Indices of the Douglas-Peucker corners of a polyline (ends included).

    Args:
        points: Polyline in pixels, shape ``(n, 2)``.
        tol: Largest allowed distance from the simplified line, pixels.

    Returns:
        Sorted indices into ``points``, shape ``(m,)``, ``m >= 2``.
    """
    keep = {0, len(points) - 1}
    stack = [(0, len(points) - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        d = points[b] - points[a]
        rel = points[a + 1:b] - points[a]
        nd = np.linalg.norm(d)
        dist = (np.abs(d[0] * rel[:, 1] - d[1] * rel[:, 0]) / nd if nd > 1e-9
                else np.linalg.norm(rel, axis=1))
        k = int(np.argmax(dist))
        if dist[k] > tol:
            keep.add(a + 1 + k)
            stack += [(a, a + 1 + k), (a + 1 + k, b)]
    return np.array(sorted(keep))


def _segments(strokes: Sequence[np.ndarray], snap: float) -> tuple[np.ndarray, np.ndarray]:
    """Straight segments ``(s, 2, 2)`` and contact dots ``(c, 2)`` from strokes."""
    segs, dots = [], []
    for raw in strokes:
        pts = np.asarray(raw, float).reshape(-1, 2)
        if len(pts) == 0:
            continue
        length = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() if len(pts) > 1 else 0.0
        extent = np.linalg.norm(pts.max(0) - pts.min(0))
        if extent < 0.75 * snap:
            dots.append(pts.mean(0))
            continue
        corners = pts[simplify(pts, max(3.0, 0.05 * length))]
        segs += [corners[i:i + 2] for i in range(len(corners) - 1)]
    return (np.array(segs).reshape(-1, 2, 2), np.array(dots).reshape(-1, 2))


def build_graph(strokes: Sequence[np.ndarray], snap_radius: float = SNAP_RADIUS) -> DrawnGraph:
    """Turn strokes (any order, any direction) into a graph of nodes and segments.

    Args:
        strokes: Polylines in pixels, each ``(n_i, 2)``.
        snap_radius: Endpoints closer than this (pixels) merge; an endpoint this close to
            another segment's interior splits it.

    Returns:
        The graph.

    Raises:
        InputError: No segment was drawn.
    """
    segs, dots = _segments(strokes, snap_radius)
    if len(segs) == 0:
        raise InputError("The sketch has no stick lines: draw the figure with straight "
                         "strokes (spine, head, arms, legs).")
    ends = segs.reshape(-1, 2)
    # Merge endpoints (single linkage within the snapping radius).
    dist = np.linalg.norm(ends[:, None] - ends[None], axis=2)
    close = dist < snap_radius
    close[np.arange(len(ends)) // 2 * 2, np.arange(len(ends)) // 2 * 2 + 1] = False
    close[np.arange(len(ends)) // 2 * 2 + 1, np.arange(len(ends)) // 2 * 2] = False
    n_nodes, label = connected_components(coo_matrix(close), directed=False)
    nodes = np.stack([ends[label == k].mean(0) for k in range(n_nodes)])
    edges = label.reshape(-1, 2)
    # T-junctions: a node close to the interior of a segment of another piece of the
    # drawing joins it there (joining pieces that are already connected would make a loop,
    # e.g. where a drawn arm crosses a leg).
    changed = True
    while changed:
        changed = False
        n = len(nodes)
        _, piece = connected_components(
            coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)),
            directed=False)
        a, b = nodes[edges[:, 0]], nodes[edges[:, 1]]
        d = b - a
        L2 = np.maximum((d * d).sum(1), 1e-12)
        t = np.einsum("ked,ed->ke", nodes[:, None] - a[None], d) / L2
        foot = a[None] + np.clip(t, 0, 1)[..., None] * d[None]
        gap = np.linalg.norm(nodes[:, None] - foot, axis=2)
        inner = (t > 0.05) & (t < 0.95) & (gap < snap_radius)
        inner &= piece[:, None] != piece[edges[:, 0]][None, :]
        hits = np.argwhere(inner)
        if len(hits):
            k, e = hits[np.argmin(gap[hits[:, 0], hits[:, 1]])]
            u, v = edges[e]
            edges = np.concatenate([np.delete(edges, e, 0), [[u, k], [k, v]]])
            changed = True
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    return DrawnGraph(nodes, edges, dots)


def _neighbors(graph: DrawnGraph) -> list[list[int]]:
    out: list[list[int]] = [[] for _ in range(len(graph.nodes))]
    for u, v in graph.edges:
        out[u].append(int(v))
        out[v].append(int(u))
    return out


def _check_tree(graph: DrawnGraph, snap_radius: float) -> None:
    n = len(graph.nodes)
    n_comp, _ = connected_components(
        coo_matrix((np.ones(len(graph.edges)), (graph.edges[:, 0], graph.edges[:, 1])),
                   shape=(n, n)), directed=False)
    if n_comp > 1:
        raise InputError(f"The stick figure falls apart into {n_comp} pieces: make the "
                         f"strokes touch (ends within {snap_radius:.0f} px snap together).")
    if len(graph.edges) != n - 1:
        raise InputError("The stick figure has a closed loop: draw it as a tree (for a "
                         "head draw one line from the neck, not a circle).")


def _embeddings(t_children, optional, t, d, d_parent, nbrs) -> list[dict[int, int]]:
    """All ways to map template subtree ``t`` onto drawn subtree ``d`` (``d`` fixed)."""
    kids_t = t_children[t]
    kids_d = [k for k in nbrs[d] if k != d_parent]
    if len(kids_d) > len(kids_t):
        return []
    out = []
    for chosen in itertools.permutations(kids_t, len(kids_d)):
        if any(not optional[k] for k in kids_t if k not in chosen):
            continue
        partial = [{t: d}]
        for tk, dk in zip(chosen, kids_d, strict=True):
            subs = _embeddings(t_children, optional, tk, dk, d, nbrs)
            partial = [{**p, **s} for p in partial for s in subs]
            if not partial:
                break
        out += partial
    return out


def _side_value(points: np.ndarray, base: np.ndarray, up: np.ndarray) -> float:
    """Mean image-right offset of ``points`` from ``base`` across the spine axis ``up``."""
    rel = points - base
    return float(np.mean(rel[:, 0] * up[1] - rel[:, 1] * up[0]))


#: Each left/right pair of a humanoid drawing: its joints and the joint it hangs from.
SIDE_PAIRS = (("arms", ("elbow", "wrist", "hand"), "neck"),
              ("legs", ("knee", "ankle", "toe"), "pelvis"))


def side_offsets(stick: StickFigure) -> dict[str, float]:
    """Per pair of a humanoid drawing, how far its left limb lies right of its right one.

    The front-view sign test's value: the mean image-right offset (pixels, across the
    drawn pelvis-neck axis) of the drawn left joints from the joint the pair hangs from,
    less the right ones'. Positive when the labels say the character faces the viewer.

    Args:
        stick: A humanoid drawing (joints named as in
            :data:`~gesture_pose.core.stick.figure.HUMANOID_JOINTS`).

    Returns:
        ``{"arms": value, "legs": value}`` in pixels.
    """
    names, pts = stick.joint_names, stick.points
    pelvis, neck = pts[names.index("pelvis")], pts[names.index("neck")]
    up = (neck - pelvis) / max(np.linalg.norm(neck - pelvis), 1e-9)
    out = {}
    for pair, keys, base in SIDE_PAIRS:
        vals = {}
        for s in "LR":
            idx = [names.index(f"{k}.{s}") for k in keys if f"{k}.{s}" in names]
            idx = [i for i in idx if stick.present[i]]
            vals[s] = _side_value(pts[idx], pts[names.index(base)], up)
        out[pair] = vals["L"] - vals["R"]
    return out


#: Lengths tell matches apart when the best one's drawing scale is below this fraction
#: of the next one's.
LENGTH_MARGIN = 0.8


def _drawing_scales(graph: DrawnGraph, figure: CharacterFigure, matches: list[dict],
                    lengths: np.ndarray) -> np.ndarray:
    """Per match, the largest drawn length over 3D length of its edges (pixels per unit).

    Foreshortening only shortens a drawn edge, so a match needs at least this scale; a
    wrong match puts long drawn lines on short bones and needs a larger one.
    """
    out = np.zeros(len(matches))
    for k, m in enumerate(matches):
        ratios = [np.linalg.norm(graph.nodes[m[t]] - graph.nodes[m[int(p)]]) / lengths[t]
                  for t, p in enumerate(figure.joint_parents)
                  if p >= 0 and t in m and int(p) in m and lengths[t] > 1e-9]
        out[k] = max(ratios, default=0.0)
    return out


def match_figure(graph: DrawnGraph, figure: CharacterFigure, facing: str = "front",
                 snap_radius: float = SNAP_RADIUS, lengths: np.ndarray | None = None
                 ) -> StickFigure:
    """Match a drawn tree to the character's stick joints.

    Args:
        graph: The drawing (see :func:`build_graph`).
        figure: The character's stick model.
        facing: ``"front"`` (the character faces the viewer, its left on the image's
            right) or ``"back"``.
        snap_radius: Snapping radius in pixels (for messages).
        lengths: Optional 3D length of each stick edge by its child joint, ``(J,)``. When
            the drawing fits in ways that differ by more than a left/right exchange, the
            way needing the smallest drawing scale (:func:`_drawing_scales`) is taken if
            it is below ``LENGTH_MARGIN`` times the next way's (a quadruped's 3-bone neck
            and 3-bone front legs differ in their bones' lengths).

    Returns:
        The matched stick figure.

    Raises:
        InputError: The drawing is not a tree or does not match the character's topology,
            or several non-symmetric matches exist.
    """
    _check_tree(graph, snap_radius)
    nbrs = _neighbors(graph)
    J = figure.n_joints
    t_children = [list(np.flatnonzero(figure.joint_parents == j)) for j in range(J)]
    matches = []
    for root in range(len(graph.nodes)):
        for emb in _embeddings(t_children, figure.optional, 0, root, -1, nbrs):
            if len(emb) == len(graph.nodes):
                matches.append(emb)
    if not matches:
        deg = graph.degrees()
        raise InputError(
            f"The drawing ({len(graph.nodes)} nodes, branch degrees "
            f"{sorted(deg[deg > 2].tolist(), reverse=True)}) does not match the character: "
            "draw a spine from the pelvis to the neck, one head line and two arms from the "
            "neck (upper arm and forearm, bent at the elbow), two legs from the pelvis "
            "(thigh and shin, bent at the knee); hand and foot lines are optional.")
    names = figure.joint_names
    keys = [tuple(sorted((names[t], d) for t, d in m.items())) for m in matches]
    matches = [matches[i] for i in sorted({k: i for i, k in enumerate(keys)}.values())]
    # Canonical form up to left/right exchange: side suffixes removed.
    def unsided(m):
        return tuple(sorted((names[t].split(".")[0], d) for t, d in m.items()))
    classes = [frozenset(unsided(m)) for m in matches]
    if len(set(classes)) > 1 and lengths is not None:
        scale = _drawing_scales(graph, figure, matches, np.asarray(lengths, float))
        best = {c: min(scale[k] for k in range(len(matches)) if classes[k] == c)
                for c in set(classes)}
        first, second = sorted(best.values())[:2]
        if first < LENGTH_MARGIN * second:
            keep = min(best, key=best.get)
            matches = [m for m, c in zip(matches, classes, strict=True) if c == keep]
            classes = [keep] * len(matches)
    if len(set(classes)) > 1:
        swaps = sorted({names[t] for m in matches for t, d in m.items()
                        if any(m2.get(t) != d for m2 in matches)})
        raise InputError(
            f"The drawing matches the character in {len(matches)} different ways: the "
            f"joints {swaps[:8]} could be exchanged. Draw those limbs with different "
            "numbers of segments (bend elbows and knees, keep the head one line) so that "
            "they can be told apart.")
    m = matches[0]
    points = np.full((J, 2), np.nan)
    for t, d in m.items():
        points[t] = graph.nodes[d]
    present = np.isfinite(points[:, 0])
    fig = StickFigure(names, points, present, figure.joint_parents, graph.contacts)
    if not is_humanoid(figure):
        # Left/right pairs of a non-humanoid are told apart by topology only.
        sided = len(matches) > 1
        return StickFigure(names, points, present, figure.joint_parents, graph.contacts,
                           ("limbs",) if sided else ())
    spine = np.linalg.norm(points[figure.joint("neck")] - points[figure.joint("pelvis")])
    sign = 1.0 if facing == "front" else -1.0
    ambiguous = []
    for pair, value in side_offsets(fig).items():
        # Left limbs should be on the image's right (positive side value) from the front.
        if sign * value < 0:
            fig = fig.swapped(pair)
        if abs(value) < 0.1 * spine:
            ambiguous.append(pair)
    return StickFigure(fig.joint_names, fig.points, fig.present, fig.parents, fig.contacts,
                       tuple(ambiguous))


def stick_figure_from_strokes(strokes: Sequence[np.ndarray], figure: CharacterFigure,
                              snap_radius: float = SNAP_RADIUS,
                              facing: str = "front",
                              lengths: np.ndarray | None = None) -> StickFigure:
    """Strokes in pixels -> matched stick figure (:func:`build_graph` + :func:`match_figure`)."""
    return match_figure(build_graph(strokes, snap_radius), figure, facing, snap_radius,
                        lengths)
