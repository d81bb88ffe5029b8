"""The stick-figure sample scene: the humanoid with a chair, a stool, a table and a floor.

Furniture is made of boxes in an ``Environment`` collection. Known poses (sitting on the
chair, standing, leaning on the table) are set with :func:`builders.apply_rotations`;
stick figures are made by projecting such a pose's joints through the scene camera (with
optional pixel noise, hands and feet left out) and drawing one straight stroke per stick
edge into a Grease Pencil object, on a plane between the camera and the character.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gesture_pose.blender.read_view import camera_from_object  # noqa: E402
from sample_scenes import builders  # noqa: E402

X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)

#: Chair seat: x, y extent and top height (the seat is 5 cm thick).
CHAIR_SEAT = ((-0.25, 0.25), (-0.12, 0.38), 0.45)

#: Poses (armature-space rotations relative to the posed parent, degrees) and root offsets.
STICK_POSES: dict[str, tuple[dict, dict]] = {
    "sit": ({"thigh.L": (X, -82.0), "thigh.R": (X, -82.0), "shin.L": (X, 84.0),
             "shin.R": (X, 84.0), "spine": (X, -6.0), "upper_arm.L": (X, -35.0),
             "forearm.L": (X, -55.0), "upper_arm.R": (X, -20.0), "forearm.R": (X, -70.0),
             "head": (X, 10.0)},
            {"pelvis": (0.0, 0.12, 0.45 + 0.105 - 0.93)}),
    "stand": ({"upper_arm.L": (X, -30.0), "forearm.L": (X, -45.0), "upper_arm.R": (Y, 25.0),
               "forearm.R": (X, -30.0), "thigh.L": (X, -15.0), "shin.L": (X, 16.0),
               "spine": (Y, 5.0)}, {"pelvis": (0.0, -0.9, 0.0)}),
    "lie": ({"pelvis": (X, -90.0), "thigh.L": (X, -45.0), "shin.L": (X, 91.0),
             "foot.L": (X, 45.0), "thigh.R": (X, 2.0),
             "upper_arm.L": (Y, -30.0), "upper_arm.R": (X, -60.0), "forearm.R": (X, -40.0),
             "head": (X, -15.0)},
            {"pelvis": (0.4, -1.4, 0.11 - 0.93)}),
    "lean": ({"pelvis": (X, 50.0), "thigh.L": (X, -50.0), "thigh.R": (X, -50.0),
              "upper_arm.L": (Y, 35.0), "upper_arm.R": (Y, -35.0), "forearm.L": (X, -50.0),
              "forearm.R": (X, -50.0), "head": (X, -25.0)},
             {"pelvis": (-1.3, 0.45, 0.0)}),
}

#: Joints pinned (eye ray through the drawn joint, nearest surface) for each pose.
STICK_PINS: dict[str, tuple[str, ...]] = {
    "sit": ("ankle.L", "ankle.R"), "stand": ("ankle.L", "ankle.R"),
    "lie": ("pelvis", "ankle.L", "ankle.R"),
    "lean": ("ankle.L", "ankle.R", "wrist.L", "wrist.R")}

#: Stick joint -> (bone, use tail) on the sample humanoid.
STICK_JOINTS = {
    "pelvis": ("pelvis", False), "neck": ("neck", False), "head": ("head", True),
    "elbow.L": ("forearm.L", False), "wrist.L": ("hand.L", False),
    "hand.L": ("hand.L", True), "elbow.R": ("forearm.R", False),
    "wrist.R": ("hand.R", False), "hand.R": ("hand.R", True),
    "knee.L": ("shin.L", False), "ankle.L": ("foot.L", False), "toe.L": ("toe.L", True),
    "knee.R": ("shin.R", False), "ankle.R": ("foot.R", False), "toe.R": ("toe.R", True),
}
STICK_EDGES = [("pelvis", "neck"), ("neck", "head"), ("neck", "elbow.L"),
               ("elbow.L", "wrist.L"), ("wrist.L", "hand.L"), ("neck", "elbow.R"),
               ("elbow.R", "wrist.R"), ("wrist.R", "hand.R"), ("pelvis", "knee.L"),
               ("knee.L", "ankle.L"), ("ankle.L", "toe.L"), ("pelvis", "knee.R"),
               ("knee.R", "ankle.R"), ("ankle.R", "toe.R")]


def _box(lo: Sequence[float], hi: Sequence[float]) -> tuple[list, list]:
    """Vertices and quad faces of an axis-aligned box."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    f = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return v, f


def add_boxes(name: str, boxes: Sequence[tuple[Sequence[float], Sequence[float]]],
              collection: bpy.types.Collection) -> bpy.types.Object:
    """One mesh object made of several boxes, linked to ``collection``."""
    verts, faces = [], []
    for lo, hi in boxes:
        v, f = _box(lo, hi)
        faces += [tuple(i + len(verts) for i in q) for q in f]
        verts += v
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    collection.objects.link(obj)
    return obj


def add_furniture(name: str = "Environment") -> bpy.types.Collection:
    """Floor, chair (seat 45 cm, backrest), stool (65 cm) and table (78.5 cm)."""
    coll = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(coll)
    add_boxes("Floor", [((-4, -4, -0.05), (4, 4, 0.0))], coll)
    (x0, x1), (y0, y1), top = CHAIR_SEAT
    legs = [((x, y, 0.0), (x + 0.04, y + 0.04, top - 0.05)) for x in (x0, x1 - 0.04)
            for y in (y0, y1 - 0.04)]
    add_boxes("Chair", [((x0, y0, top - 0.05), (x1, y1, top)),
                        ((x0, y1, top), (x1, y1 + 0.05, top + 0.5))] + legs, coll)
    add_boxes("Stool", [((1.05, 0.05, 0.0), (1.4, 0.4, 0.65))], coll)
    t = 0.785
    table_legs = [((x, y, 0.0), (x + 0.05, y + 0.05, t - 0.04)) for x in (-1.9, -0.75)
                  for y in (-0.55, 0.1)]
    add_boxes("Table", [((-1.9, -0.55, t - 0.04), (-0.7, 0.15, t))] + table_legs, coll)
    return coll


def pose_stick_humanoid(arm: bpy.types.Object, name: str) -> None:
    """Put the humanoid in one of :data:`STICK_POSES` (``"rest"`` clears the pose)."""
    if name == "rest":
        builders.reset_pose(arm)
        return
    rotations, offsets = STICK_POSES[name]
    builders.apply_rotations(arm, rotations, offsets)


def stick_joints(arm: bpy.types.Object) -> dict[str, np.ndarray]:
    """World positions of the humanoid's stick joints in its current pose."""
    heads_tails = builders.joint_positions(arm)
    return {j: heads_tails[b][1 if tail else 0] for j, (b, tail) in STICK_JOINTS.items()}


def stick_strokes(arm: bpy.types.Object, camera_obj: bpy.types.Object, noise_px: float = 0.0,
                  seed: int = 0, ends: bool = False, depth_fraction: float = 0.5
                  ) -> list[np.ndarray]:
    """World strokes of the current pose's stick figure as seen by the camera.

    Args:
        arm: The posed humanoid.
        camera_obj: The scene camera.
        noise_px: Standard deviation of the pixel noise added to every joint.
        seed: Noise seed.
        ends: Also draw the hands and feet.
        depth_fraction: Where the drawing plane lies between the camera and the pelvis.

    Returns:
        One straight 8-point stroke per stick edge, world space.
    """
    cam = camera_from_object(camera_obj, bpy.context.scene)
    joints = stick_joints(arm)
    names = list(joints)
    px = cam.project(np.array([joints[n] for n in names]))
    px += np.random.default_rng(seed).normal(scale=noise_px, size=px.shape)
    pix = dict(zip(names, px, strict=True))
    depth = depth_fraction * float(cam.depth(joints["pelvis"][None])[0])
    out = []
    for a, b in STICK_EDGES:
        if not ends and b in ("hand.L", "hand.R", "toe.L", "toe.R"):
            continue
        out.append(cam.unproject_at_depth(np.linspace(pix[a], pix[b], 8), depth))
    return out


def build_stick_scene(pose: str = "sit", noise_px: float = 1.5, seed: int = 0,
                      ) -> dict[str, bpy.types.ID]:
    """Humanoid, furniture, sun, camera and a Grease Pencil stick figure of ``pose``.

    The character is left in its rest pose after the stick figure is drawn.

    Returns:
        ``{"armature", "mesh", "camera", "sketch", "environment"}``.
    """
    arm, mesh = builders.build_humanoid()
    env = add_furniture()
    builders.add_light()
    target = {"lean": (-1.2, 0.0, 0.8), "lie": (0.3, -1.3, 0.3)}.get(pose, (0.0, -0.2, 0.8))
    cam = builders.add_camera(target, direction=(0.45, -1.0, 0.35), distance=5.0,
                              resolution=(960, 720))
    pose_stick_humanoid(arm, pose)
    sketch = builders.add_grease_pencil("Sketch", stick_strokes(arm, cam, noise_px, seed))
    pose_stick_humanoid(arm, "rest")
    return {"armature": arm, "mesh": mesh, "camera": cam, "sketch": sketch,
            "environment": env}


def add_example_sketches(arm: bpy.types.Object, camera_obj: bpy.types.Object,
                         poses: Sequence[str]) -> list[bpy.types.Object]:
    """Hidden Grease Pencil objects ``Sketch_<pose>`` holding other example figures.

    Show one (and hide *Sketch*) to pose the character from it. The character is left at
    rest.
    """
    out = []
    for pose in poses:
        pose_stick_humanoid(arm, pose)
        gp = builders.add_grease_pencil(f"Sketch_{pose}", stick_strokes(arm, camera_obj, 1.0))
        gp.hide_set(True)
        gp.hide_render = True
        out.append(gp)
    pose_stick_humanoid(arm, "rest")
    return out


def save_stick_scene(path: str | Path, pose: str = "sit") -> Path:
    """Build the stick sample scene in an empty file and save it (compressed).

    The visible *Sketch* holds ``pose``; the other example poses are hidden sketches.
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = build_stick_scene(pose)
    add_example_sketches(sc["armature"], sc["camera"], [p for p in STICK_POSES if p != pose])
    bpy.context.scene["gesture_pose_sample"] = "stick"
    path = Path(path)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)
    return path


def render_png(path: str | Path, size: tuple[int, int] = (480, 360)) -> Path:
    """Render the scene camera's view with Workbench (strokes included) to a PNG."""
    scene = bpy.context.scene
    old = (scene.render.resolution_x, scene.render.resolution_y,
           scene.render.resolution_percentage)
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "OBJECT"
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    scene.render.engine = "BLENDER_WORKBENCH"
    bpy.ops.render.render(write_still=True)
    (scene.render.resolution_x, scene.render.resolution_y,
     scene.render.resolution_percentage) = old
    return Path(path)


def render_stick_images(outdir: str | Path, pose: str = "sit") -> list[Path]:
    """Pictures for the docs: the drawing over the scene, then the solved pose.

    Builds the sample scene, pins the joints of :data:`STICK_PINS`, runs Pose Stick
    Figure and renders before and after (``stick_<pose>_input.png``,
    ``stick_<pose>_result.png``).
    """
    outdir = Path(outdir)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    import gesture_pose

    if not hasattr(bpy.types.Scene, "gesture_pose_stick"):
        gesture_pose.register()
    sc = build_stick_scene(pose)
    colours = {"Floor": (0.8, 0.8, 0.8, 1), "Chair": (0.55, 0.35, 0.2, 1),
               "Stool": (0.3, 0.45, 0.6, 1), "Table": (0.5, 0.4, 0.3, 1)}
    for obj in sc["environment"].objects:
        obj.color = colours.get(obj.name, (0.7, 0.7, 0.7, 1))
    sc["mesh"].color = (0.9, 0.75, 0.6, 1)
    arm, sketch = sc["armature"], sc["sketch"]
    sketch.scale = (1.0, 1.0, 1.0)
    out = [render_png(outdir / f"stick_{pose}_input.png")]
    with bpy.context.temp_override(active_object=arm, object=arm, selected_objects=[arm]):
        for joint in STICK_PINS[pose]:
            bpy.ops.gesture_pose.pin_joint(armature=arm.name, sketch=sketch.name, joint=joint)
        bpy.ops.gesture_pose.pose_stick_figure(armature=arm.name, sketch=sketch.name)
    out.append(render_png(outdir / f"stick_{pose}_result.png"))
    return out
