"""Blender side of the stick-figure mode: reading a solve's inputs and writing its outputs.

The armature, view and drawing are read once into a :class:`StickScene`; the environment
is read in bulk from the evaluated meshes (modifiers applied) into one
:class:`~gesture_pose.core.stick.environment.Environment`. Pins, left/right swaps and the
last solve's suggestions live on the scene as JSON custom properties, so re-solving keeps
the pins and "Next Suggestion" needs no new solve; both survive saving the file.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, replace

import bpy
import numpy as np

from ..core.camera import Camera
from ..core.exceptions import InputError
from ..core.skeleton import Pose
from ..core.stick.edit import GLOBAL_RADIUS, drag_node
from ..core.stick.environment import Environment
from ..core.stick.figure import CharacterFigure, character_figure
from ..core.stick.graph import SNAP_RADIUS, StickFigure, stick_figure_from_strokes
from ..core.stick.pins import EnvPinSpec, LimbPinSpec
from ..core.stick.solve import StickInput, StickResult, solve_stick
from .read_armature import ArmatureData, read_armature
from .read_mesh import meshes_of, read_skinned_meshes
from .read_strokes import read_sketch, write_strokes
from .read_view import camera_from_context
from .write_pose import apply_pose

PINS_PROPERTY = "gesture_pose_stick_pins"
SWAPS_PROPERTY = "gesture_pose_stick_swaps"
SUGGESTIONS_PROPERTY = "gesture_pose_stick_suggestions"


def _mesh_arrays(obj, depsgraph) -> tuple[np.ndarray, np.ndarray]:
    """World vertices ``(V, 3)`` and triangles ``(T, 3)`` of an evaluated object."""
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    try:
        mesh.calc_loop_triangles()
        v = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", v)
        t = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int64)
        mesh.loop_triangles.foreach_get("vertices", t)
    finally:
        ev.to_mesh_clear()
    m = np.array(ev.matrix_world, dtype=float)
    v = v.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    return v, t.reshape(-1, 3)


def environment_objects(context, armature: bpy.types.Object,
                        collection: str = "") -> list[bpy.types.Object]:
    """Meshes the character interacts with.

    Args:
        context: Blender context.
        armature: The character (its deformed meshes are excluded).
        collection: Name of a collection holding the environment; empty: every visible
            mesh of the scene that is not the character.

    Returns:
        Mesh objects, sorted by name.

    Raises:
        InputError: The named collection does not exist.
    """
    own = set(meshes_of(armature))
    if collection:
        coll = bpy.data.collections.get(collection)
        if coll is None:
            raise InputError(f"No collection named '{collection}': pick the collection "
                             "holding the furniture and floor, or leave it empty.")
        objs = [o for o in coll.all_objects if o.type == "MESH"]
    else:
        objs = [o for o in context.scene.objects if o.type == "MESH" and o.visible_get()]
    return sorted((o for o in objs if o not in own and o.parent != armature),
                  key=lambda o: o.name)


def read_environment(objects: list[bpy.types.Object], depsgraph) -> Environment | None:
    """One :class:`Environment` from mesh objects (None when there are none)."""
    if not objects:
        return None
    verts, tris, ids, offset = [], [], [], 0
    for k, obj in enumerate(objects):
        v, t = _mesh_arrays(obj, depsgraph)
        verts.append(v)
        tris.append(t + offset)
        ids.append(np.full(len(t), k))
        offset += len(v)
    return Environment(np.concatenate(verts), np.concatenate(tris), np.concatenate(ids),
                       tuple(o.name for o in objects))


# -- pins ------------------------------------------------------------------------------


def read_pins(scene: bpy.types.Scene) -> tuple[tuple[EnvPinSpec, ...], tuple[LimbPinSpec, ...]]:
    """Pins stored on the scene."""
    raw = json.loads(scene.get(PINS_PROPERTY, "{}") or "{}")
    env = tuple(EnvPinSpec(p["joint"], np.array(p["point"]), np.array(p["normal"]),
                           p.get("object", "")) for p in raw.get("env", []))
    limb = tuple(LimbPinSpec(p["joint"], tuple(p["limb"]), float(p["s"]))
                 for p in raw.get("limb", []))
    return env, limb


def write_pins(scene: bpy.types.Scene, env: tuple[EnvPinSpec, ...],
               limb: tuple[LimbPinSpec, ...]) -> None:
    """Store pins on the scene (one pin per joint: later pins replace earlier ones)."""
    seen, env_out, limb_out = set(), [], []
    for p in reversed(limb):
        if p.joint not in seen:
            seen.add(p.joint)
            limb_out.append({"joint": p.joint, "limb": list(p.limb), "s": p.s})
    for p in reversed(env):
        if p.joint not in seen:
            seen.add(p.joint)
            env_out.append({"joint": p.joint, "point": [float(c) for c in p.point],
                            "normal": [float(c) for c in p.normal], "object": p.object_name})
    scene[PINS_PROPERTY] = json.dumps({"env": env_out[::-1], "limb": limb_out[::-1]})


def remove_pin(scene: bpy.types.Scene, joint: str | None = None) -> int:
    """Remove the pins of ``joint`` (all pins when None); returns how many were removed."""
    env, limb = read_pins(scene)
    keep_env = tuple(p for p in env if joint is not None and p.joint != joint)
    keep_limb = tuple(p for p in limb if joint is not None and p.joint != joint)
    write_pins(scene, keep_env, keep_limb)
    return len(env) + len(limb) - len(keep_env) - len(keep_limb)


# -- left/right swaps and suggestions -----------------------------------------------------


def read_swaps(scene: bpy.types.Scene) -> set[str]:
    """Limb pairs (``"arms"``, ``"legs"``) whose left/right guess the user flipped."""
    return set(json.loads(scene.get(SWAPS_PROPERTY, "[]") or "[]"))


def toggle_swap(scene: bpy.types.Scene, pair: str) -> set[str]:
    """Flip the stored swap of ``pair``; returns the new set."""
    swaps = read_swaps(scene) ^ {pair}
    scene[SWAPS_PROPERTY] = json.dumps(sorted(swaps))
    return swaps


def store_suggestions(scene: bpy.types.Scene, armature: str, names: tuple[str, ...],
                      poses: list[Pose], scores: list[float], frame: int) -> None:
    """Keep the suggestions of the last solve: local rotations, translations, scores.

    The scores are the suggestions' plausibility (the order they are stepped through).
    """
    scene[SUGGESTIONS_PROPERTY] = json.dumps({
        "armature": armature, "names": list(names), "frame": int(frame), "current": 0,
        "scores": [float(e) for e in scores],
        "rotations": [np.asarray(p.rotations).round(10).tolist() for p in poses],
        "translations": [np.asarray(p.translations).round(10).tolist() for p in poses]})


def read_suggestions(scene: bpy.types.Scene) -> dict:
    """The stored suggestions (empty dict when there are none)."""
    return json.loads(scene.get(SUGGESTIONS_PROPERTY, "{}") or "{}")


def set_current_suggestion(scene: bpy.types.Scene, index: int) -> None:
    """Remember which suggestion is shown."""
    data = read_suggestions(scene)
    data["current"] = int(index)
    scene[SUGGESTIONS_PROPERTY] = json.dumps(data)


# -- reading, solving and writing ---------------------------------------------------------


@dataclass(frozen=True)
class StickScene:
    """What the stick operators read from Blender, once.

    Attributes:
        armature: The armature's data.
        camera: The view the figure was drawn in.
        figure: The character's stick model.
        stick: The matched drawing, user swaps applied.
        sketch_depth: Mean view depth of the drawn strokes (to write edits back).
    """

    armature: ArmatureData
    camera: Camera
    figure: CharacterFigure
    stick: StickFigure
    sketch_depth: float


def read_stick_scene(context, arm_obj, sketch_obj, snap_radius: float = SNAP_RADIUS,
                     facing: str = "front") -> StickScene:
    """Read the armature, view and drawing, and match the drawing to the character."""
    data = read_armature(arm_obj)
    camera = camera_from_context(context)
    strokes = read_sketch(sketch_obj, context.scene.frame_current)
    if not strokes:
        raise InputError(f"'{sketch_obj.name}' has no strokes at this frame: draw a stick "
                         "figure (spine, head, arms, legs) over the scene.")
    for s in strokes:
        if not np.all(np.isfinite(s.points_world)):
            raise InputError(f"Stroke {s.index} of layer '{s.layer_name}' has NaN or infinite "
                             "coordinates: delete it and draw it again.")
    pts = [camera.project(s.points_world) for s in strokes]
    if not all(np.all(np.isfinite(p)) for p in pts):
        raise InputError("Part of the drawing is behind the view: draw in front of the "
                         "camera.")
    figure, _ = character_figure(data.skeleton, data.ik_limits, data.roles)
    stick = stick_figure_from_strokes(pts, figure, snap_radius, facing,
                                      figure.edge_lengths(data.skeleton))
    for pair in sorted(read_swaps(context.scene)):
        stick = stick.swapped(pair)
    depth = float(np.mean(np.concatenate([camera.depth(s.points_world) for s in strokes])))
    return StickScene(data, camera, figure, stick, depth)


def base_pose(data: ArmatureData, figure: CharacterFigure) -> tuple[Pose, list[int]]:
    """Current pose with the solved bones at rest, and the solved bones."""
    solved = sorted({figure.root_bone} | {int(b) for g in figure.groups for b in g.bones})
    rot = data.pose.rotations.copy()
    rot[solved] = np.eye(3)
    trans = data.pose.translations.copy()
    trans[figure.root_bone] = 0.0
    return Pose(rot, trans), solved


def solve_scene(context, op, arm_obj, sketch_obj) -> tuple[StickResult, list[str]]:
    """Solve from the scene with an operator's settings and write the best pose.

    Args:
        context: Blender context.
        op: The operator (its ``snap_radius``, ``facing``, ``environment``, ``seed``,
            ``suggestions``, ``use_contact`` and ``insert_keys`` are used).
        arm_obj: The armature.
        sketch_obj: The Grease Pencil object.

    Returns:
        ``(result, names of the bones written)``; the suggestions are stored on the scene.
    """
    scene = context.scene
    st = read_stick_scene(context, arm_obj, sketch_obj, op.snap_radius, op.facing)
    data = st.armature
    depsgraph = context.evaluated_depsgraph_get()
    try:
        mesh = read_skinned_meshes(arm_obj, data.skeleton, depsgraph)
        verts, weights = mesh.rest_vertices, mesh.weights
    except InputError:
        verts = weights = None
    env = read_environment(environment_objects(context, arm_obj, op.environment), depsgraph)
    env_pins, limb_pins = read_pins(scene)
    base, solved = base_pose(data, st.figure)
    inp = StickInput(
        skeleton=data.skeleton, camera=st.camera, stick=st.stick, environment=env,
        mesh_vertices=verts, mesh_weights=weights, ik_limits=data.ik_limits, roles=data.roles,
        base_pose=base, env_pins=env_pins, limb_pins=limb_pins, seed=op.seed,
        n_suggestions=op.suggestions, facing=op.facing, use_contact=op.use_contact)
    result = solve_stick(inp)
    if data.warnings:  # the reader's notes (an imported rig's locks and limits dropped)
        result = replace(result, warnings=(*data.warnings, *result.warnings))
    best = result.suggestions[0]
    written = apply_pose(arm_obj, data, best.pose, bones=solved, insert_keys=op.insert_keys,
                         frame=scene.frame_current, location_bones=[st.figure.root_bone])
    store_suggestions(scene, arm_obj.name, data.skeleton.names,
                      [s.pose for s in result.suggestions],
                      [s.score for s in result.suggestions], scene.frame_current)
    return result, written


def write_stick(sketch_obj, stick: StickFigure, camera: Camera, depth: float, frame: int,
                clear: Sequence[str] = ()) -> None:
    """Replace the active layer's strokes by one straight stroke per drawn stick edge.

    Args:
        sketch_obj: The Grease Pencil sketch.
        stick: The figure to write.
        camera: The view it was drawn in.
        depth: Depth of the written strokes from the camera.
        frame: Scene frame whose drawing is written.
        clear: Other layers whose strokes at ``frame`` were part of the figure: emptied,
            so that the figure is drawn once.
    """
    edges = stick.drawn_edges()
    lines = [camera.unproject_at_depth(np.linspace(stick.points[a], stick.points[b], 8),
                                       depth) for a, b in edges]
    layer = sketch_obj.data.layers.active or sketch_obj.data.layers[0]
    write_strokes(sketch_obj, layer.name, lines, frame=frame, replace=True)
    for name in clear:
        if name != layer.name:
            write_strokes(sketch_obj, name, [], frame=frame, replace=True)


#: Strokes saved per layer: ``{layer name: (world points per stroke, radii per stroke)}``.
SavedStrokes = dict[str, tuple[list[np.ndarray], list[np.ndarray]]]


def _sketch_strokes(sketch_obj, frame: int) -> SavedStrokes:
    """Every visible layer's strokes at ``frame`` (the active layer always, maybe empty)."""
    active = (sketch_obj.data.layers.active or sketch_obj.data.layers[0]).name
    saved: SavedStrokes = {active: ([], [])}
    for s in read_sketch(sketch_obj, frame):
        lines, radii = saved.setdefault(s.layer_name, ([], []))
        lines.append(s.points_world.copy())
        radii.append(np.asarray(s.radius, float).copy())
    return saved


def _restore_strokes(sketch_obj, frame: int, saved: SavedStrokes) -> None:
    """Write back strokes saved by :func:`_sketch_strokes`: points and per-point radii.

    A layer that had no stroke is emptied again.
    """
    for layer_name, (lines, radii) in saved.items():
        if not lines:
            write_strokes(sketch_obj, layer_name, [], frame=frame, replace=True)
            continue
        layer = write_strokes(sketch_obj, layer_name, lines, frame=frame, replace=True,
                              radius=float(np.mean(np.concatenate(radii))))
        attr = layer.get_frame_at(frame).drawing.attributes.get("radius")
        if attr is not None:
            attr.data.foreach_set("value", np.concatenate(radii).astype(np.float32))


class StickDragSession:
    """Dragging drawn stick joints (Section 4.2), independent of the viewport's events.

    The modal Edit Stick Figure operator only passes its events to :meth:`handle`, which
    turns them into :meth:`press`, :meth:`move`, :meth:`release` and :meth:`cancel`; the
    session holds the armature, the sketch, the matched drawing and the view. A drag
    shorter than
    ``global_radius`` pixels moves one joint, a longer one the chain from the pelvis
    (:func:`~gesture_pose.core.stick.edit.drag_node`); every move rewrites the sketch's
    active layer as one straight stroke per drawn stick edge, release poses the character
    again (keyed at the current frame when ``settings.insert_keys``), and cancel puts the
    strokes back as they were before the drag.

    Args:
        context: Blender context (its view is the one the figure is read in).
        settings: An object with the solve settings of :func:`solve_scene` (``snap_radius``,
            ``facing``, ``environment``, ``seed``, ``suggestions``, ``use_contact``,
            ``insert_keys``), e.g. the operator.
        arm_obj: The armature.
        sketch_obj: The Grease Pencil object holding the stick figure.
        global_radius: Drags longer than this (pixels) move the chain.
        pick_radius: A press farther than this (pixels) from every drawn joint picks none.

    Raises:
        InputError: The drawing cannot be read or does not match the character.
    """

    def __init__(self, context, settings, arm_obj, sketch_obj,
                 global_radius: float = GLOBAL_RADIUS, pick_radius: float = 25.0) -> None:
        if sketch_obj is None or sketch_obj.type != "GREASEPENCIL":
            raise InputError("Edit Stick Figure needs a Grease Pencil sketch: pick one.")
        self.settings = settings
        self.armature = arm_obj
        self.sketch = sketch_obj
        self.global_radius = float(global_radius)
        self.pick_radius = float(pick_radius)
        self.frame = context.scene.frame_current
        st = read_stick_scene(context, arm_obj, sketch_obj, settings.snap_radius,
                              settings.facing)
        self.camera, self.depth, self.stick = st.camera, st.sketch_depth, st.stick
        self.joint: int | None = None
        self._start: StickFigure | None = None
        self._saved: SavedStrokes | None = None
        self.moved = False

    @property
    def dragging(self) -> bool:
        """Whether a joint is being dragged."""
        return self.joint is not None

    def press(self, xy) -> str | None:
        """Pick the drawn joint nearest to ``xy`` (pixels, ``(2,)``); its name or None."""
        d = np.linalg.norm(self.stick.points - np.asarray(xy, float), axis=1)
        d[~self.stick.present] = np.inf
        j = int(np.argmin(d))
        if not d[j] < self.pick_radius:
            self.joint = None
            return None
        self.joint, self._start, self.moved = j, self.stick, False
        self._saved = _sketch_strokes(self.sketch, self.frame)
        return self.stick.joint_names[j]

    def move(self, xy) -> bool:
        """Drag the picked joint to ``xy`` (pixels) and rewrite the strokes; False if none."""
        if self.joint is None:
            return False
        self.stick = drag_node(self._start, self.joint, np.asarray(xy, float),
                               self.global_radius)
        write_stick(self.sketch, self.stick, self.camera, self.depth, self.frame,
                    clear=[name for name, (lines, _) in self._saved.items() if lines])
        self.moved = True
        return True

    def release(self, context=None) -> StickResult | None:
        """End the drag and pose the character from the edited drawing.

        Returns:
            The solve's result; None when no joint was dragged (nothing is posed).
        """
        if self.joint is None or not self.moved:
            self.joint = self._start = self._saved = None
            return None
        self.joint = self._start = self._saved = None
        result, _ = solve_scene(context or bpy.context, self.settings, self.armature,
                                self.sketch)
        return result

    def handle(self, kind: str, value: str, xy, context=None) -> str:
        """One viewport event: what the modal operator returns for it.

        Left mouse press picks a joint, mouse moves drag it, release poses the character;
        Esc during a drag cancels the drag, otherwise Esc ends the editing; right mouse
        cancels a drag in progress and ends the editing.

        Args:
            kind: Blender's event type (``"LEFTMOUSE"``, ``"MOUSEMOVE"``, ``"ESC"``, ...).
            value: Its value (``"PRESS"``, ``"RELEASE"``, ...).
            xy: Mouse position in the region, pixels, ``(2,)``.
            context: Blender context for the solve on release (the current one if None).

        Returns:
            ``"RUNNING_MODAL"``, ``"FINISHED"`` or ``"PASS_THROUGH"``.

        Raises:
            InputError: Posing from the edited drawing failed (the editing goes on).
        """
        if kind in {"ESC", "RIGHTMOUSE"} and value == "PRESS":
            if self.cancel() and kind == "ESC":
                return "RUNNING_MODAL"
            return "FINISHED"
        if kind == "LEFTMOUSE" and value == "PRESS":
            self.press(xy)
            return "RUNNING_MODAL"
        if kind == "MOUSEMOVE" and self.dragging:
            self.move(xy)
            return "RUNNING_MODAL"
        if kind == "LEFTMOUSE" and value == "RELEASE" and self.dragging:
            self.release(context)
            return "RUNNING_MODAL"
        return "PASS_THROUGH"

    def cancel(self) -> bool:
        """Abort the drag: the strokes and the drawing go back to before it (False: none)."""
        if self.joint is None:
            return False
        _restore_strokes(self.sketch, self.frame, self._saved)
        self.stick = self._start
        self.joint = self._start = self._saved = None
        return True
