"""Blender side of the stick-figure mode: environment meshes, stored pins and suggestions.

The environment is read in bulk from the evaluated meshes (modifiers applied) into one
:class:`~gesture_pose.core.stick.environment.Environment`. Pins, left/right swaps and the
last solve's suggestions live on the scene as JSON custom properties, so re-solving keeps
the pins and "Next Suggestion" needs no new solve; both survive saving the file.
"""

from __future__ import annotations

import json

import bpy
import numpy as np

from ..core.exceptions import InputError
from ..core.skeleton import Pose
from ..core.stick.environment import Environment
from ..core.stick.pins import EnvPinSpec, LimbPinSpec
from .read_mesh import meshes_of

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
                      poses: list[Pose], energies: list[float], frame: int) -> None:
    """Keep the suggestions of the last solve (local rotations and translations)."""
    scene[SUGGESTIONS_PROPERTY] = json.dumps({
        "armature": armature, "names": list(names), "frame": int(frame), "current": 0,
        "energies": [float(e) for e in energies],
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
