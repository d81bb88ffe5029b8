"""Build a core :class:`Camera` from a 3D View region or a camera object.

A 3D View gives its matrices directly (``RegionView3D.view_matrix`` and ``window_matrix``,
region size in pixels). A camera object gives ``V = matrix_world.normalized()^-1`` and the
projection ``Object.calc_matrix_camera`` for the render resolution (times its percentage)
and pixel aspect, so that projected pixels are render pixels.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core.camera import Camera
from ..core.exceptions import InputError


def render_size(scene: bpy.types.Scene) -> tuple[int, int]:
    """Render width and height in pixels (resolution times percentage)."""
    r = scene.render
    pct = r.resolution_percentage / 100.0
    return max(int(r.resolution_x * pct), 1), max(int(r.resolution_y * pct), 1)


def camera_from_object(cam_obj: bpy.types.Object, scene: bpy.types.Scene | None = None,
                       depsgraph: bpy.types.Depsgraph | None = None) -> Camera:
    """The view of a camera object, in render pixels.

    Args:
        cam_obj: Object of type ``'CAMERA'``.
        scene: Scene whose render settings give the image size (the context scene when None).
        depsgraph: Evaluated depsgraph (the context's when None).

    Returns:
        The camera.

    Raises:
        InputError: ``cam_obj`` is not a camera.
    """
    if cam_obj is None or cam_obj.type != "CAMERA":
        raise InputError("The view object must be a camera: set a scene camera.")
    scene = bpy.context.scene if scene is None else scene
    depsgraph = bpy.context.evaluated_depsgraph_get() if depsgraph is None else depsgraph
    width, height = render_size(scene)
    r = scene.render
    projection = cam_obj.calc_matrix_camera(depsgraph, x=width, y=height,
                                            scale_x=r.pixel_aspect_x, scale_y=r.pixel_aspect_y)
    view = cam_obj.matrix_world.normalized().inverted()
    return Camera(np.array(view, dtype=float), np.array(projection, dtype=float), width, height,
                  cam_obj.data.type != "ORTHO")


def camera_from_region(region, rv3d) -> Camera:
    """The view of a 3D View region, in region pixels.

    Args:
        region: The ``'WINDOW'`` region (anything with ``width`` and ``height``).
        rv3d: Its ``RegionView3D`` (anything with ``view_matrix``, ``window_matrix`` and
            ``is_perspective``).

    Returns:
        The camera.
    """
    return Camera(np.array(rv3d.view_matrix, dtype=float),
                  np.array(rv3d.window_matrix, dtype=float),
                  int(region.width), int(region.height), bool(rv3d.is_perspective))


def _view3d_region(context):
    """``(region, rv3d)`` of the context's 3D View, or ``(None, None)``.

    From the sidebar (region type ``'UI'``) the view is the area's main ``'WINDOW'`` region
    and the space's ``region_3d``.
    """
    area = getattr(context, "area", None)
    if area is None or area.type != "VIEW_3D":
        return None, None
    region = getattr(context, "region", None)
    if region is not None and region.type == "WINDOW" and context.region_data is not None:
        return region, context.region_data
    windows = [r for r in area.regions if r.type == "WINDOW"]
    if not windows:
        return None, None
    return max(windows, key=lambda r: r.width * r.height), area.spaces.active.region_3d


def camera_from_context(context) -> Camera:
    """The view the user is drawing in: the 3D View if there is one, else the scene camera.

    Args:
        context: A ``bpy.types.Context`` (or an override).

    Returns:
        The camera.

    Raises:
        InputError: No 3D View and no scene camera.
    """
    region, rv3d = _view3d_region(context)
    if region is not None and rv3d is not None:
        return camera_from_region(region, rv3d)
    scene = context.scene
    if scene.camera is None:
        raise InputError("No view: add a scene camera or run from a 3D View.")
    return camera_from_object(scene.camera, scene, context.evaluated_depsgraph_get())
