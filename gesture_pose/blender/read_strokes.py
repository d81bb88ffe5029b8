"""Read sketches (Grease Pencil v3 or curve objects) as world polylines, and write overlays.

Grease Pencil strokes are read in bulk from the drawing's ``position`` attribute and its
``curve_offsets`` (stroke ``i`` spans points ``offsets[i]:offsets[i+1]``); the world point
is ``object.matrix_world @ layer.matrix_local @ p``. Curve objects (e.g. SVG imports) are
evaluated to a mesh whose outline edges are chained back into polylines.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import bpy
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, depth_first_order

from ..core.camera import Camera
from ..core.exceptions import InputError
from ..core.stroke import Stroke

#: Blender's radius of a Grease Pencil point when the drawing has no radius attribute.
DEFAULT_RADIUS = 0.01
#: Values of Grease Pencil attributes for new strokes when the drawing already has them.
NEW_STROKE_DEFAULTS = {"radius": DEFAULT_RADIUS, "opacity": 1.0, "hardness": 1.0,
                       "aspect_ratio": 1.0, "u_scale": 1.0}
#: Name of the material :func:`write_strokes` creates when a sketch has none.
OVERLAY_MATERIAL = "gesture_pose ink"


@dataclass(frozen=True)
class SketchStroke:
    """One drawn stroke in world space.

    Attributes:
        points_world: Points, shape ``(n, 3)``, world units.
        layer_name: Grease Pencil layer name (the curve object's name for curves).
        index: Index of the stroke in its drawing (of the polyline for curves).
        radius: Point radii in the sketch object's local units, shape ``(n,)``.
    """

    points_world: np.ndarray
    layer_name: str
    index: int
    radius: np.ndarray


def _transform(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply a 4x4 affine ``matrix`` to points ``(n, 3)``."""
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def _layer_visible(layer) -> bool:
    """Whether a layer and every group containing it are shown."""
    node = layer
    while node is not None:
        if node.hide:
            return False
        node = node.parent_group
    return True


def _drawing(layer, frame: int | None):
    """The drawing in effect at ``frame`` (the scene's current frame when None), or None."""
    key = layer.current_frame() if frame is None else layer.get_frame_at(int(frame))
    return None if key is None else key.drawing


def _point_attribute(drawing, name: str, width: int, n_points: int) -> np.ndarray | None:
    """A point attribute as ``(n_points, width)`` float array, or None if absent."""
    attr = drawing.attributes.get(name)
    if attr is None:
        return None
    out = np.empty(n_points * width, dtype=np.float64)
    attr.data.foreach_get("vector" if width == 3 else "value", out)
    return out.reshape(n_points, width)


def drawing_arrays(drawing) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bulk-read a drawing.

    Args:
        drawing: A ``GreasePencilDrawing``.

    Returns:
        ``(positions (P, 3), offsets (S + 1,), radius (P,))`` in layer space.
    """
    n_strokes = len(drawing.strokes)
    if n_strokes == 0:
        return np.zeros((0, 3)), np.zeros(1, dtype=np.int64), np.zeros(0)
    offsets = np.empty(n_strokes + 1, dtype=np.int64)
    drawing.curve_offsets.foreach_get("value", offsets)
    n_points = int(offsets[-1])
    positions = _point_attribute(drawing, "position", 3, n_points)
    radius = _point_attribute(drawing, "radius", 1, n_points)
    radius = np.full(n_points, DEFAULT_RADIUS) if radius is None else radius[:, 0]
    return positions, offsets, radius


def _read_grease_pencil(sketch_obj, frame: int | None) -> list[SketchStroke]:
    world = np.array(sketch_obj.matrix_world, dtype=float)
    out: list[SketchStroke] = []
    for layer in sketch_obj.data.layers:
        drawing = _drawing(layer, frame) if _layer_visible(layer) else None
        if drawing is None or len(drawing.strokes) == 0:
            continue
        positions, offsets, radius = drawing_arrays(drawing)
        pts = _transform(positions, world @ np.array(layer.matrix_local, dtype=float))
        for i, (a, b) in enumerate(zip(offsets[:-1], offsets[1:], strict=True)):
            out.append(SketchStroke(pts[a:b], layer.name, i, radius[a:b]))
    return out


def chain_edges(edges: np.ndarray, n_vertices: int) -> list[np.ndarray]:
    """Chain the edges of a graph of paths and cycles into vertex sequences.

    Args:
        edges: Vertex index pairs, shape ``(e, 2)``; every vertex has degree 1 or 2.
        n_vertices: Number of vertices.

    Returns:
        One vertex index array per connected component, ordered from the endpoint with
        the lower index (closed loops repeat their first vertex at the end), components
        ordered by their lowest vertex index.
    """
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if edges.size == 0:
        return []
    ones = np.ones(len(edges))
    graph = coo_matrix((ones, (edges[:, 0], edges[:, 1])), shape=(n_vertices, n_vertices))
    graph = (graph + graph.T).tocsr()
    _, labels = connected_components(graph, directed=False)
    degree = np.bincount(edges.ravel(), minlength=n_vertices)
    used = np.flatnonzero(degree > 0)
    chains = []
    for comp in np.unique(labels[used]):
        verts = np.flatnonzero(labels == comp)
        ends = verts[degree[verts] == 1]
        start = int(ends.min()) if ends.size else int(verts.min())
        order = depth_first_order(graph, start, directed=False, return_predecessors=False)
        chains.append(order if ends.size else np.append(order, order[0]))
    chains.sort(key=lambda c: int(c.min()))
    return chains


def _read_curve(curve_obj) -> list[SketchStroke]:
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = curve_obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        n_v, n_e, n_l = len(mesh.vertices), len(mesh.edges), len(mesh.loops)
        co = np.empty(n_v * 3)
        mesh.vertices.foreach_get("co", co)
        edges = np.empty(n_e * 2, dtype=np.int64)
        mesh.edges.foreach_get("vertices", edges)
        loop_edges = np.empty(n_l, dtype=np.int64)
        mesh.loops.foreach_get("edge_index", loop_edges)
    finally:
        evaluated.to_mesh_clear()
    edges = edges.reshape(-1, 2)
    # Filled 2D curves are triangulated: their outline is the edges used by one face.
    outline = np.bincount(loop_edges, minlength=n_e) <= 1
    pts = _transform(co.reshape(-1, 3), np.array(curve_obj.matrix_world, dtype=float))
    chains = chain_edges(edges[outline], n_v)
    return [SketchStroke(pts[c], curve_obj.name, i, np.full(len(c), DEFAULT_RADIUS))
            for i, c in enumerate(chains)]


def read_sketch(sketch_obj: bpy.types.Object, frame: int | None = None) -> list[SketchStroke]:
    """Read every visible stroke of a sketch object in world space.

    Args:
        sketch_obj: A Grease Pencil (v3, type ``'GREASEPENCIL'``) or curve object.
        frame: Scene frame whose drawings to read; the current frame when None (Grease
            Pencil only: the drawing of the last key at or before the frame).

    Returns:
        Strokes in layer order, then drawing order (the latest stroke last).

    Raises:
        InputError: The object is neither Grease Pencil nor a curve.
    """
    if sketch_obj is None:
        raise InputError("No sketch: pick a Grease Pencil object in the Gesture Pose panel.")
    if sketch_obj.type == "GREASEPENCIL":
        return _read_grease_pencil(sketch_obj, frame)
    if sketch_obj.type == "CURVE":
        return _read_curve(sketch_obj)
    raise InputError(f"'{sketch_obj.name}' is a {sketch_obj.type.lower()} object: the sketch "
                     "must be a Grease Pencil or curve object.")


def strokes_to_2d(strokes: Sequence[SketchStroke | np.ndarray], camera: Camera) -> list[Stroke]:
    """Project world strokes to pixel strokes.

    Args:
        strokes: Sketch strokes or world polylines ``(n, 3)``.
        camera: The view the strokes were drawn in.

    Returns:
        Core strokes in pixels, one per input stroke.

    Raises:
        InputError: A stroke has NaN points, lies (partly) behind the camera or is a single
            point.
    """
    out = []
    for k, s in enumerate(strokes):
        pts = s.points_world if isinstance(s, SketchStroke) else np.asarray(s, dtype=float)
        where = (f"Stroke {s.index} of layer '{s.layer_name}'"
                 if isinstance(s, SketchStroke) else f"Stroke {k}")
        if not np.all(np.isfinite(pts)):
            raise InputError(f"{where} has NaN or infinite coordinates: delete it and "
                             "draw it again.")
        pix = camera.project(pts.reshape(-1, 3))
        if not np.all(np.isfinite(pix)):
            raise InputError(f"{where} lies behind the view: draw it in front of the "
                             "camera or change the view.")
        if len(pix) < 2 or np.linalg.norm(np.ptp(pix, axis=0)) < 1e-9:
            raise InputError(f"{where} is a single point in this view: draw a longer "
                             "stroke or delete it.")
        out.append(Stroke(pix))
    return out


def _frame_key(layer, frame: int):
    """The key frame of ``layer`` exactly at ``frame``, created when missing."""
    for key in layer.frames:
        if key.frame_number == frame:
            return key
    return layer.frames.new(frame)


def _require_gp(sketch_obj) -> None:
    if sketch_obj is None or sketch_obj.type != "GREASEPENCIL":
        raise InputError("Strokes can only be written to or removed from a Grease Pencil "
                         "object: pick one as the sketch.")


def remove_strokes(sketch_obj: bpy.types.Object, layer_name: str, indices: Sequence[int],
                   frame: int | None = None) -> int:
    """Delete strokes from the drawing of a layer (never through ``bpy.ops``).

    Args:
        sketch_obj: Grease Pencil object.
        layer_name: Layer holding the strokes.
        indices: Stroke indices in the drawing, as in :class:`SketchStroke`.
        frame: Scene frame (the current frame when None).

    Returns:
        Number of strokes removed.

    Raises:
        InputError: Not Grease Pencil, unknown layer, no drawing or an index out of range.
    """
    _require_gp(sketch_obj)
    layer = sketch_obj.data.layers.get(layer_name)
    if layer is None:
        raise InputError(f"'{sketch_obj.name}' has no layer '{layer_name}'.")
    idx = sorted({int(i) for i in indices})
    if not idx:
        return 0
    drawing = _drawing(layer, frame)
    count = 0 if drawing is None else len(drawing.strokes)
    if idx[0] < 0 or idx[-1] >= count:
        raise InputError(f"Layer '{layer_name}' has {count} strokes at this frame; cannot "
                         f"remove strokes {idx}.")
    drawing.remove_strokes(indices=idx)
    return len(idx)


def _material_index(sketch_obj, material, color) -> int:
    """Slot index of the material new strokes use, creating a material if needed."""
    gp = sketch_obj.data
    if material is None:
        if color is None and len(gp.materials):
            return 0
        material = None if color is not None else bpy.data.materials.get(OVERLAY_MATERIAL)
        if material is None:
            material = bpy.data.materials.new(OVERLAY_MATERIAL)
    if not material.is_grease_pencil:
        bpy.data.materials.create_gpencil_data(material)
    if color is not None:
        rgba = tuple(float(c) for c in color)
        material.grease_pencil.color = rgba[:3] + (rgba[3] if len(rgba) > 3 else 1.0,)
    for i, slot in enumerate(gp.materials):
        if slot == material:
            return i
    gp.materials.append(material)
    return len(gp.materials) - 1


def _fill_new(drawing, name: str, value: float, starts: dict[str, int],
              create: tuple[str, str, float] | None = None) -> None:
    """Set attribute ``name`` of the elements added last to ``value``.

    Args:
        drawing: The drawing.
        name: Scalar (FLOAT or INT) attribute name.
        value: Value for the new points or strokes.
        starts: First new element per domain (``'POINT'``, ``'CURVE'``).
        create: ``(data_type, domain, value for old elements)`` to create a missing
            attribute; a missing attribute is left alone when None.
    """
    attr = drawing.attributes.get(name)
    created = attr is None
    if created:
        if create is None:
            return
        attr = drawing.attributes.new(name, create[0], create[1])
    if attr.data_type not in {"FLOAT", "INT"}:
        return
    data = np.empty(len(attr.data), dtype=np.int32 if attr.data_type == "INT" else np.float32)
    attr.data.foreach_get("value", data)
    start = starts[attr.domain]
    if created:
        data[:start] = create[2]
    data[start:] = value
    attr.data.foreach_set("value", data)


def write_strokes(sketch_obj: bpy.types.Object, layer_name: str,
                  polylines_world: Sequence[np.ndarray], frame: int | None = None,
                  replace: bool = True, material: bpy.types.Material | None = None,
                  color: Sequence[float] | None = None, radius: float | None = None):
    """Create or replace the strokes of a layer (e.g. a "gesture_pose fit" overlay).

    Args:
        sketch_obj: Grease Pencil object (the layer is created when missing).
        layer_name: Layer to write into.
        polylines_world: World polylines, each ``(n_i, 3)`` with ``n_i >= 1``.
        frame: Scene frame of the key to write (the current frame when None).
        replace: Remove the key's existing strokes first.
        material: Material for the new strokes; the object's first material when None, a
            created "gesture_pose ink" material if it has none.
        color: RGB(A) colour given to ``material``, or to a new material when
            ``material`` is None.
        radius: Point radius in the object's local units (Blender's default when None).

    Returns:
        The ``GreasePencilLayer`` written.

    Raises:
        InputError: Not a Grease Pencil object or an empty polyline.
    """
    _require_gp(sketch_obj)
    lines = [np.asarray(p, dtype=float).reshape(-1, 3) for p in polylines_world]
    if any(len(p) == 0 for p in lines):
        raise InputError("Cannot write an empty stroke: every polyline needs a point.")
    gp = sketch_obj.data
    layer = gp.layers.get(layer_name) or gp.layers.new(layer_name, set_active=False)
    key = _frame_key(layer, bpy.context.scene.frame_current if frame is None else int(frame))
    drawing = key.drawing
    if replace and len(drawing.strokes):
        drawing.remove_strokes()
    n_strokes_old = len(drawing.strokes)
    old_pos, _, _ = drawing_arrays(drawing)
    if not lines:
        return layer
    mat_index = _material_index(sketch_obj, material, color)
    drawing.add_strokes([len(p) for p in lines])
    to_local = np.linalg.inv(np.array(sketch_obj.matrix_world) @ np.array(layer.matrix_local))
    new_pos = _transform(np.concatenate(lines), to_local)
    drawing.attributes["position"].data.foreach_set(
        "vector", np.concatenate([old_pos, new_pos]).astype(np.float32).ravel())
    starts = {"POINT": len(old_pos), "CURVE": n_strokes_old}
    # Existing attributes give new elements 0: a radius or opacity of 0 hides the stroke.
    for name, value in NEW_STROKE_DEFAULTS.items():
        _fill_new(drawing, name, value, starts)
    if radius is not None:
        _fill_new(drawing, "radius", radius, starts, ("FLOAT", "POINT", DEFAULT_RADIUS))
    _fill_new(drawing, "material_index", mat_index, starts,
              ("INT", "CURVE", 0) if mat_index else None)
    return layer
