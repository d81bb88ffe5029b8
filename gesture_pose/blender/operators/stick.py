"""Stick-figure posing in an environment (Lin et al. 2012) in the Gesture Pose sidebar.

Operators: Pose Stick Figure (solve and key), Pin Joint (to a surface under the drawn
joint or to a limb; stored on the scene), Swap Sides (flip a left/right guess and solve
again), Next Suggestion (step through the distinct solutions of the last solve) and the
modal Edit Stick Figure (drag drawn joints, locally or along their chain).
"""

from __future__ import annotations

import time

import bpy
import numpy as np

from ...core.exceptions import GesturePoseError, InputError
from ...core.skeleton import Pose
from ...core.stick.edit import GLOBAL_RADIUS
from ...core.stick.figure import HUMANOID_JOINTS, character_figure
from ...core.stick.graph import SNAP_RADIUS
from ...core.stick.pins import EnvPinSpec, LimbPinSpec, limb_parameter, pin_candidates
from ..operator_utils import (
    GesturePoseOperatorMixin,
    nothing_to_do,
    report_result,
    resolve_armature,
    resolve_sketch,
)
from ..panel import GesturePoseSubPanel
from ..read_armature import read_armature
from ..stick_io import (
    StickDragSession,
    base_pose,
    environment_objects,
    read_environment,
    read_pins,
    read_stick_scene,
    read_suggestions,
    remove_pin,
    set_current_suggestion,
    solve_scene,
    toggle_swap,
    write_pins,
)
from ..write_pose import apply_pose

HUMANOID_JOINT_NAMES = tuple(n for n, _, _ in HUMANOID_JOINTS)


#: The last armature's stick joints and edges, keyed by its bones (see :func:`figure_edges`).
_FIGURE_CACHE: dict[bytes, tuple[tuple[str, ...], tuple[str, ...]]] = {}


def _bones_key(arm) -> bytes:
    """What the matched figure depends on: the bones' names, parents and rest positions."""
    bones = arm.data.bones
    ends = np.zeros((2, 3 * len(bones)), np.float32)
    bones.foreach_get("head_local", ends[0])
    bones.foreach_get("tail_local", ends[1])
    names = "|".join(f"{b.name}<{b.parent.name if b.parent else ''}" for b in bones)
    return arm.name.encode() + b"/" + names.encode() + ends.tobytes()


def figure_edges(context, armature: str = "") -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The stick joints of the character and its edges as ``"parent,child"``.

    From the armature named ``armature`` (else the one the panel or selection gives), by
    the same matching Pose Stick Figure uses; the humanoid's joints when none is found.
    The Pin Joint search calls this on every keystroke, so the last armature's answer is
    kept until its bones change (reading an imported rig's skin takes a noticeable time).
    """
    try:
        arm = resolve_armature(context, armature)
        key = _bones_key(arm)
        if key not in _FIGURE_CACHE:
            data = read_armature(arm)
            figure, _ = character_figure(data.skeleton, data.ik_limits, data.roles)
            _FIGURE_CACHE.clear()
            _FIGURE_CACHE[key] = (figure.joint_names,
                                  _edges(figure.joint_names, figure.joint_parents))
    except GesturePoseError:
        edges = tuple(f"{p},{n}" for n, p, _ in HUMANOID_JOINTS if p)
        return HUMANOID_JOINT_NAMES, edges
    return _FIGURE_CACHE[key]


def _edges(names: tuple[str, ...], parents: np.ndarray) -> tuple[str, ...]:
    """Stick edges as ``"parent,child"``; ``parents`` is ``(J,)`` with -1 at the root."""
    return tuple(f"{names[p]},{n}" for n, p in zip(names, parents.tolist(), strict=True)
                 if p >= 0)


def _matching(options: tuple[str, ...], edit_text: str) -> list[str]:
    text = edit_text.lower()
    return [o for o in options if text in o.lower()]


def _search_joints(self, context, edit_text: str) -> list[str]:
    """Search callback of the joint fields: the character's stick joints."""
    return _matching(figure_edges(context, getattr(self, "armature", ""))[0], edit_text)


def _search_limbs(self, context, edit_text: str) -> list[str]:
    """Search callback of the limb field: the character's stick edges."""
    return _matching(figure_edges(context, getattr(self, "armature", ""))[1], edit_text)

FACING_ITEMS = [("front", "Front", "The drawn character faces the viewer"),
                ("back", "Back", "The drawn character turns its back to the viewer")]


class _StickSolveProps:
    """Properties shared by the operators that solve."""

    armature: bpy.props.StringProperty(name="Armature", description="Armature to pose "
                                       "(empty: the one picked in the panel or selected)")
    sketch: bpy.props.StringProperty(name="Sketch", description="Grease Pencil object "
                                     "holding the stick figure (empty: automatic)")
    environment: bpy.props.StringProperty(name="Environment", description="Collection of "
                                          "the furniture and floor (empty: visible meshes "
                                          "that are not the character)")
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0,
                                description="Random seed of the genetic search")
    suggestions: bpy.props.IntProperty(name="Suggestions", default=3, min=1, max=8,
                                       description="Distinct solutions to keep")
    snap_radius: bpy.props.FloatProperty(name="Snap Radius", default=SNAP_RADIUS, min=1.0,
                                         subtype="PIXEL", description="Stroke ends closer "
                                         "than this join")
    facing: bpy.props.EnumProperty(name="Facing", items=FACING_ITEMS, default="front")
    use_contact: bpy.props.BoolProperty(name="Contact Dot", default=False, description=(
        "Sit where a drawn dot touches the seat instead of under the pelvis"))
    insert_keys: bpy.props.BoolProperty(name="Insert Keys", default=True)


class GESTUREPOSE_OT_pose_stick_figure(_StickSolveProps, GesturePoseOperatorMixin,
                                       bpy.types.Operator):
    """Pose the character from a drawn stick figure, sitting or standing in the scene."""

    bl_idname = "gesture_pose.pose_stick_figure"
    bl_label = "Pose Stick Figure"
    bl_description = ("Pose the character in 3D so that it matches the drawn stick figure, "
                      "sits where drawn, keeps balance and avoids the furniture")
    bl_options = {"REGISTER", "UNDO"}

    def run(self, context: bpy.types.Context) -> set[str]:
        """Read, solve, write and key the best suggestion."""
        t0 = time.perf_counter()
        arm = resolve_armature(context, self.armature)
        sketch = resolve_sketch(context, self.sketch, arm)
        result, written = solve_scene(context, self, arm, sketch)
        for w in result.warnings:
            self.report({"WARNING"}, w)
        where = "seated" if result.seat is not None else "not seated"
        report_result(self, f"Posed {len(written)} bones from the stick figure ({where}) in "
                            f"{time.perf_counter() - t0:.2f} s; {len(result.suggestions)} "
                            "suggestion(s), Next Suggestion steps through them")
        return {"FINISHED"}


class GESTUREPOSE_OT_swap_sides(_StickSolveProps, GesturePoseOperatorMixin,
                                bpy.types.Operator):
    """Exchange the drawn left and right arms or legs, then pose again."""

    bl_idname = "gesture_pose.swap_sides"
    bl_label = "Swap Sides"
    bl_description = "The left/right guess was wrong: exchange a pair of limbs and re-pose"
    bl_options = {"REGISTER", "UNDO"}

    pair: bpy.props.EnumProperty(name="Limbs", items=[("arms", "Arms", ""),
                                                      ("legs", "Legs", "")], default="arms")

    def run(self, context: bpy.types.Context) -> set[str]:
        """Toggle the stored swap and solve again."""
        arm = resolve_armature(context, self.armature)
        sketch = resolve_sketch(context, self.sketch, arm)
        swaps = toggle_swap(context.scene, self.pair)
        try:
            result, written = solve_scene(context, self, arm, sketch)
        except Exception:
            toggle_swap(context.scene, self.pair)
            raise
        report_result(self, f"Swapped the {self.pair} (swapped now: {sorted(swaps) or 'none'}"
                            f"); posed {len(written)} bones")
        return {"FINISHED"}


class GESTUREPOSE_OT_next_suggestion(GesturePoseOperatorMixin, bpy.types.Operator):
    """Show the next of the distinct solutions of the last stick-figure solve."""

    bl_idname = "gesture_pose.next_suggestion"
    bl_label = "Next Suggestion"
    bl_description = "Step through the distinct poses the last Pose Stick Figure found"
    bl_options = {"REGISTER", "UNDO"}

    step: bpy.props.IntProperty(name="Step", default=1, description="1 next, -1 previous")
    insert_keys: bpy.props.BoolProperty(name="Insert Keys", default=True)

    def run(self, context: bpy.types.Context) -> set[str]:
        """Apply the stored suggestion after the current one."""
        stored = read_suggestions(context.scene)
        if not stored or not stored.get("rotations"):
            return nothing_to_do(self, "no suggestions yet; run Pose Stick Figure first.")
        arm = bpy.data.objects.get(stored["armature"])
        if arm is None or arm.type != "ARMATURE":
            raise InputError(f"The armature '{stored['armature']}' of the last solve is gone: "
                             "run Pose Stick Figure again.")
        data = read_armature(arm)
        if tuple(stored["names"]) != data.skeleton.names:
            raise InputError("The armature's bones changed since the last solve: run Pose "
                             "Stick Figure again.")
        n = len(stored["rotations"])
        k = (int(stored.get("current", 0)) + self.step) % n
        pose = Pose(np.array(stored["rotations"][k]), np.array(stored["translations"][k]))
        figure, _ = character_figure(data.skeleton, data.ik_limits, data.roles)
        # Only the bones a solve poses: a suggestion also holds the others' rotations at
        # the time of the solve, which the user may have changed since.
        _, solved = base_pose(data, figure)
        written = apply_pose(arm, data, pose, bones=solved, insert_keys=self.insert_keys,
                             frame=context.scene.frame_current,
                             location_bones=[figure.root_bone])
        set_current_suggestion(context.scene, k)
        scores = stored.get("scores", stored.get("energies", [float("nan")] * n))
        report_result(self, f"Suggestion {k + 1} of {n} (score {scores[k]:.4f}); "
                            f"{len(written)} bones changed")
        return {"FINISHED"}


class GESTUREPOSE_OT_pin_joint(GesturePoseOperatorMixin, bpy.types.Operator):
    """Pin a drawn joint to the surface under it or to a limb (stored on the scene)."""

    bl_idname = "gesture_pose.pin_joint"
    bl_label = "Pin Joint"
    bl_description = ("Attach a stick joint to the environment (feet on the floor, hand on "
                      "the table) or to a limb (hand on the knee); Pose Stick Figure keeps it")
    bl_options = {"REGISTER", "UNDO"}

    armature: bpy.props.StringProperty(name="Armature")
    sketch: bpy.props.StringProperty(name="Sketch")
    environment: bpy.props.StringProperty(name="Environment")
    joint: bpy.props.StringProperty(name="Joint", default="ankle.L", search=_search_joints,
                                    description="Stick joint to pin (the character's joints "
                                    "are offered as you type)")
    target: bpy.props.EnumProperty(name="Pin To", default="ENVIRONMENT", items=[
        ("ENVIRONMENT", "Environment", "The surface under the drawn joint"),
        ("LIMB", "Limb", "A point of another stick edge"),
        ("CLEAR", "Clear", "Remove this joint's pin"),
        ("CLEAR_ALL", "Clear All", "Remove every pin")])
    candidate: bpy.props.IntProperty(name="Surface", default=0, min=0, description=(
        "Which surface under the joint, nearest first (e.g. 0 the table, 1 the floor)"))
    limb: bpy.props.StringProperty(name="Limb", default="pelvis,knee.R", search=_search_limbs,
                                   description="Stick edge to pin to, as 'parent,child'")
    snap_radius: bpy.props.FloatProperty(name="Snap Radius", default=SNAP_RADIUS, min=1.0)
    facing: bpy.props.EnumProperty(name="Facing", items=FACING_ITEMS, default="front")

    def run(self, context: bpy.types.Context) -> set[str]:
        """Store, replace or clear a pin."""
        scene = context.scene
        if self.target == "CLEAR_ALL":
            report_result(self, f"Removed {remove_pin(scene)} pin(s)")
            return {"FINISHED"}
        if self.target == "CLEAR":
            report_result(self, f"Removed {remove_pin(scene, self.joint)} pin(s) of "
                                f"{self.joint}")
            return {"FINISHED"}
        arm = resolve_armature(context, self.armature)
        sketch = resolve_sketch(context, self.sketch, arm)
        st = read_stick_scene(context, arm, sketch, self.snap_radius, self.facing)
        names = st.stick.joint_names
        if self.joint not in names:
            raise InputError(f"'{self.joint}' is not a joint of this character's stick "
                             f"figure; its joints are {', '.join(names)}.")
        j = names.index(self.joint)
        if not st.stick.present[j]:
            raise InputError(f"'{self.joint}' is not in the drawing: draw it first.")
        env_pins, limb_pins = read_pins(scene)
        if self.target == "LIMB":
            if self.limb not in _edges(st.figure.joint_names, st.figure.joint_parents):
                raise InputError(f"'{self.limb}' is not an edge of the stick figure: give "
                                 "it as 'parent,child', e.g. 'pelvis,knee.R'.")
            a, b = self.limb.split(",")
            if self.joint in (a, b):
                raise InputError("A joint cannot be pinned to its own limb: pick another.")
            spec = LimbPinSpec(self.joint, (a, b), limb_parameter(st.stick, self.joint,
                                                                  (a, b)))
            write_pins(scene, env_pins, limb_pins + (spec,))
            report_result(self, f"Pinned {self.joint} to {a}-{b} at {spec.s:.2f}")
            return {"FINISHED"}
        env = read_environment(environment_objects(context, arm, self.environment),
                               context.evaluated_depsgraph_get())
        if env is None:
            raise InputError("No environment meshes to pin to: add a floor or furniture.")
        hits = pin_candidates(env, st.camera, st.stick.points[j])
        if not hits:
            raise InputError(f"No surface under '{self.joint}': draw it over the floor or "
                             "furniture.")
        names = [f"{i}: {env.object_names[h.object_index]}" for i, h in enumerate(hits)]
        if self.candidate >= len(hits):
            raise InputError(f"Surface {self.candidate} does not exist; the surfaces under "
                             f"'{self.joint}' are {', '.join(names)}.")
        hit = hits[self.candidate]
        spec = EnvPinSpec(self.joint, hit.point, hit.normal,
                          env.object_names[hit.object_index])
        write_pins(scene, env_pins + (spec,), limb_pins)
        more = f" (other surfaces: {', '.join(names)})" if len(hits) > 1 else ""
        report_result(self, f"Pinned {self.joint} to '{spec.object_name}'{more}")
        return {"FINISHED"}


class GESTUREPOSE_OT_edit_stick_figure(_StickSolveProps, bpy.types.Operator):
    """Drag the drawn joints: short drags move one joint, long ones bend its chain."""

    bl_idname = "gesture_pose.edit_stick_figure"
    bl_label = "Edit Stick Figure"
    bl_description = ("Drag stick joints in the viewport (left mouse); far drags move the "
                      "chain from the pelvis; release re-poses; Esc or right mouse ends")
    bl_options = {"REGISTER", "UNDO"}

    global_radius: bpy.props.FloatProperty(name="Global Drag", default=GLOBAL_RADIUS,
                                           min=0.0, subtype="PIXEL")

    @classmethod
    def poll(cls, context) -> bool:
        """Needs a 3D View."""
        if context.area is None or context.area.type != "VIEW_3D":
            cls.poll_message_set("Run from a 3D View")
            return False
        return True

    def invoke(self, context, event):
        """Read the drawing and start the drag session."""
        try:
            arm = resolve_armature(context, self.armature)
            sketch = resolve_sketch(context, self.sketch, arm)
            self._session = StickDragSession(context, self, arm, sketch, self.global_radius)
        except GesturePoseError as err:
            self.report({"ERROR"}, str(err))
            return {"CANCELLED"}
        context.window_manager.modal_handler_add(self)
        context.workspace.status_text_set("Drag stick joints; Esc: undo the drag or finish; "
                                          "right mouse: finish")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        """Pass the event to the drag session (:meth:`StickDragSession.handle`)."""
        xy = (event.mouse_region_x, event.mouse_region_y)
        try:
            state = self._session.handle(event.type, event.value, xy, context)
        except GesturePoseError as err:  # a failed solve on release: the editing goes on
            self.report({"ERROR"}, str(err))
            state = "RUNNING_MODAL"
        if state == "FINISHED":
            context.workspace.status_text_set(None)
        return {state}


class StickSettings(bpy.types.PropertyGroup):
    """Scene settings shown in the Stick Figure panel."""

    environment: bpy.props.PointerProperty(name="Environment", type=bpy.types.Collection,
                                           description="Furniture and floor (empty: every "
                                           "visible mesh that is not the character)")
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)
    suggestions: bpy.props.IntProperty(name="Suggestions", default=3, min=1, max=8)
    use_contact: bpy.props.BoolProperty(name="Contact Dot", default=False)
    pin_joint: bpy.props.StringProperty(name="Joint", default="ankle.L",
                                        search=_search_joints,
                                        description="Stick joint to pin")
    pin_candidate: bpy.props.IntProperty(name="Surface", default=0, min=0)


class VIEW3D_PT_gesture_pose_stick(GesturePoseSubPanel, bpy.types.Panel):
    """Stick figures in an environment."""

    bl_idname = "VIEW3D_PT_gesture_pose_stick"
    bl_label = "Stick Figure"

    def draw(self, context: bpy.types.Context) -> None:
        """Settings, solve, suggestions, pins and editing."""
        s = context.scene.gesture_pose_stick
        col = self.layout.column(align=True)
        col.prop(s, "environment")
        row = col.row(align=True)
        row.prop(s, "seed")
        row.prop(s, "suggestions")
        col.prop(s, "use_contact")
        op = col.operator(GESTUREPOSE_OT_pose_stick_figure.bl_idname, icon="ARMATURE_DATA")
        op.environment = s.environment.name if s.environment else ""
        op.seed, op.suggestions, op.use_contact = s.seed, s.suggestions, s.use_contact
        row = col.row(align=True)
        row.operator(GESTUREPOSE_OT_next_suggestion.bl_idname, text="Previous").step = -1
        row.operator(GESTUREPOSE_OT_next_suggestion.bl_idname, text="Next").step = 1
        row = col.row(align=True)
        row.operator(GESTUREPOSE_OT_swap_sides.bl_idname, text="Swap Arms").pair = "arms"
        row.operator(GESTUREPOSE_OT_swap_sides.bl_idname, text="Swap Legs").pair = "legs"
        col.separator()
        col.prop(s, "pin_joint")
        col.prop(s, "pin_candidate")
        row = col.row(align=True)
        op = row.operator(GESTUREPOSE_OT_pin_joint.bl_idname, text="Pin")
        op.joint, op.candidate, op.target = s.pin_joint, s.pin_candidate, "ENVIRONMENT"
        op = row.operator(GESTUREPOSE_OT_pin_joint.bl_idname, text="Unpin")
        op.joint, op.target = s.pin_joint, "CLEAR"
        col.operator(GESTUREPOSE_OT_edit_stick_figure.bl_idname, icon="GREASEPENCIL")


def register_extra() -> None:
    """Attach the panel's settings to the scene."""
    bpy.types.Scene.gesture_pose_stick = bpy.props.PointerProperty(type=StickSettings)


def unregister_extra() -> None:
    """Remove the panel's settings."""
    del bpy.types.Scene.gesture_pose_stick


CLASSES = (StickSettings, GESTUREPOSE_OT_pose_stick_figure, GESTUREPOSE_OT_swap_sides,
           GESTUREPOSE_OT_next_suggestion, GESTUREPOSE_OT_pin_joint,
           GESTUREPOSE_OT_edit_stick_figure, VIEW3D_PT_gesture_pose_stick)
