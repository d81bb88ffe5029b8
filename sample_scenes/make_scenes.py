"""Save the sample scenes: humanoid, tentacle, quadruped, and one scene per posing mode.

Run headless with the project's venv::

    .venv/bin/python sample_scenes/make_scenes.py [outdir]

``outdir`` defaults to this folder. Each file starts from an empty factory scene and holds
one character (armature + skinned mesh), a sun light, a camera framing the character (the
scene camera), a Grease Pencil object named ``Sketch`` with the character's example
line-of-action strokes at frame 1, and the scene property ``gesture_pose_sample``. The
files are saved compressed; building is deterministic.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402

from sample_scenes import builders  # noqa: E402


@dataclass(frozen=True)
class SceneRecipe:
    """How to build one sample scene.

    Attributes:
        name: Sample name, file stem and value of the ``gesture_pose_sample`` property.
        build: Character builder returning ``(armature_obj, mesh_obj)``.
        strokes: Example stroke generator ``(armature_obj, camera_obj) -> strokes``.
        direction: From the character toward the camera.
        resolution: Render resolution ``(width, height)``.
        margin: Camera framing margin (room for strokes that leave the rest silhouette).
    """

    name: str
    build: Callable
    strokes: Callable
    direction: tuple[float, float, float]
    resolution: tuple[int, int]
    margin: float


RECIPES = (
    SceneRecipe("humanoid", builders.build_humanoid, builders.example_strokes_humanoid,
                (0.0, -1.0, 0.0), (960, 960), 1.5),
    SceneRecipe("tentacle", builders.build_tentacle, builders.example_strokes_tentacle,
                (0.0, -1.0, 0.0), (960, 960), 1.6),
    SceneRecipe("quadruped", builders.build_quadruped, builders.example_strokes_quadruped,
                (1.0, -0.35, 0.15), (1280, 960), 1.3),
)


def build_scene(recipe: SceneRecipe) -> None:
    """Build one sample scene in a fresh, empty file.

    Args:
        recipe: What to build.
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.frame_current = 1
    scene.render.engine = 'BLENDER_WORKBENCH'
    arm_obj, _mesh_obj = recipe.build()
    builders.add_light()
    cam = builders.add_camera(arm_obj, direction=recipe.direction,
                              resolution=recipe.resolution, margin=recipe.margin)
    builders.add_grease_pencil("Sketch", recipe.strokes(arm_obj, cam))
    scene["gesture_pose_sample"] = recipe.name
    bpy.context.view_layer.objects.active = arm_obj


def save_scene(recipe: SceneRecipe, outdir: Path) -> Path:
    """Build a sample scene and save it compressed as ``<outdir>/<name>.blend``.

    Args:
        recipe: What to build.
        outdir: Destination folder (created if missing).

    Returns:
        The saved file's path.
    """
    outdir.mkdir(parents=True, exist_ok=True)
    build_scene(recipe)
    path = outdir / f"{recipe.name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)
    return path


def main(argv: list[str]) -> int:
    """Save every sample scene and print sizes and timings.

    Args:
        argv: Command-line arguments after the script name: ``[outdir]``.

    Returns:
        Process exit code.
    """
    outdir = Path(argv[0]) if argv else Path(__file__).resolve().parent
    start = time.perf_counter()
    savers = [lambda out, r=recipe: save_scene(r, out) for recipe in RECIPES]
    savers += [lambda out, name=name, save=save: save(out / f"{name}.blend")
               for name, save in mode_scenes()]
    for saver in savers:
        t0 = time.perf_counter()
        path = saver(outdir)
        size_kb = path.stat().st_size / 1024.0
        print(f"{path}: {size_kb:.0f} KiB in {time.perf_counter() - t0:.2f} s")
    print(f"total {time.perf_counter() - start:.2f} s")
    return 0


def mode_scenes() -> list[tuple[str, Callable[[Path], Path]]]:
    """Scenes that belong to one posing mode: ``(file stem, saver(path) -> path)``."""
    from sample_scenes import abstraction_builders, stick_builders

    return [("abstraction", abstraction_builders.save_abstraction_scene),
            ("stick", stick_builders.save_stick_scene)]


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
