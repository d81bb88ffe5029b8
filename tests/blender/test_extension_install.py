"""Build the extension zip for this platform, install it into bpy and run its operator.

The install runs in a subprocess: ``BLENDER_USER_RESOURCES`` must be set before ``import bpy``
and a test must not leave an extension installed in the pytest process. Wheels are cached
under ``build/wheels`` (shared with ``make extension``), so only the first run downloads.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tools import build_extension

pytestmark = [pytest.mark.blender, pytest.mark.slow]

EXTENSION_MODULE = "bl_ext.user_default.gesture_pose"

# Runs in a fresh interpreter: argv = [zip, result.json]. Each stage writes what it learned
# to the JSON file before the next one starts, so a crash still tells how far it got.
INSTALL_AND_RUN = r"""
import importlib, json, math, sys
zip_path, result_path = sys.argv[1:3]
result = {}

def save(**items):
    result.update(items)
    with open(result_path, "w") as fh:
        json.dump(result, fh)

import bpy

bpy.ops.wm.read_factory_settings(use_empty=True)
save(installed=sorted(bpy.ops.extensions.package_install_files(
    filepath=zip_path, repo="user_default", enable_on_install=True)))
module = importlib.import_module("EXTENSION_MODULE")
save(module_file=module.__file__,
     enabled="EXTENSION_MODULE" in bpy.context.preferences.addons,
     local_site=bpy.utils.user_resource("EXTENSIONS", path=".local")
     + "/lib/python%d.%d/site-packages" % sys.version_info[:2])
bpy.ops.gesture_pose.pose_stroke.get_rna_type()
save(operator_registered=True)

# A 3-bone vertical chain (z = 0..3), a camera looking along +y at it, and one Grease Pencil
# stroke bending to the right in the plane y = 0 (an arc of length 3, radius 3).
scene = bpy.context.scene
arm = bpy.data.armatures.new("Rig")
rig = bpy.data.objects.new("Rig", arm)
scene.collection.objects.link(rig)
bpy.context.view_layer.objects.active = rig
bpy.ops.object.mode_set(mode="EDIT")
parent = None
for i, name in enumerate(("Root", "Mid", "Tip")):
    bone = arm.edit_bones.new(name)
    bone.head, bone.tail = (0.0, 0.0, float(i)), (0.0, 0.0, float(i + 1))
    if parent is not None:
        bone.parent, bone.use_connect = parent, True
    parent = bone
bpy.ops.object.mode_set(mode="OBJECT")

cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
scene.collection.objects.link(cam)
cam.location, cam.rotation_euler = (0.0, -10.0, 1.5), (math.pi / 2, 0.0, 0.0)
scene.camera = cam
scene.render.resolution_x = scene.render.resolution_y = 1000

gp = bpy.data.grease_pencils.new("Sketch")
sketch = bpy.data.objects.new("Sketch", gp)
scene.collection.objects.link(sketch)
drawing = gp.layers.new("Lines", set_active=True).frames.new(scene.frame_current).drawing
n = 32
drawing.add_strokes([n])
points = []
for k in range(n):
    angle = k / (n - 1)
    points += [3.0 - 3.0 * math.cos(angle), 0.0, 3.0 * math.sin(angle)]
drawing.attributes["position"].data.foreach_set("vector", points)
drawing.attributes.new("radius", "FLOAT", "POINT").data.foreach_set("value", [0.01] * n)
drawing.attributes.new("opacity", "FLOAT", "POINT").data.foreach_set("value", [1.0] * n)

for ob in (rig, sketch):
    ob.select_set(True)
bpy.context.view_layer.objects.active = rig
bpy.context.view_layer.update()
before = [pb.matrix_basis.copy() for pb in rig.pose.bones]
with bpy.context.temp_override(active_object=rig, object=rig,
                               selected_objects=[rig, sketch],
                               selected_editable_objects=[rig, sketch]):
    status = bpy.ops.gesture_pose.pose_stroke(
        armature=rig.name, sketch=sketch.name, insert_keys=True)
save(operator_result=sorted(status))
bpy.context.view_layer.update()
save(rotation_change=max(
    max(abs(a - b) for row_a, row_b in zip(m0.to_3x3(), pb.matrix_basis.to_3x3())
        for a, b in zip(row_a, row_b))
    for m0, pb in zip(before, rig.pose.bones)))
""".replace("EXTENSION_MODULE", EXTENSION_MODULE)

# Imports the bundled packages from the extensions' site-packages (ahead of the venv's
# copies; only numpy comes from the venv, as it comes from Blender) and solves a tiny QP.
BUNDLED_WHEELS_WORK = r"""
import sys
sys.path.insert(0, sys.argv[1])
import jinja2, markupsafe, numpy as np, osqp, scipy, scipy.sparse as sp
for module in (jinja2, markupsafe, osqp, scipy):
    assert module.__file__.startswith(sys.argv[1]), module.__file__
solver = osqp.OSQP()
solver.setup(sp.csc_matrix([[4.0, 1.0], [1.0, 2.0]]), np.array([1.0, 1.0]),
             sp.csc_matrix([[1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]),
             np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.7, 0.7]), verbose=False)
res = solver.solve()
assert res.info.status == "solved", res.info.status
assert np.allclose(res.x, [0.3, 0.7], atol=1e-2), res.x
"""


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build the extension for this platform only (wheels from the build/wheels cache)."""
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("bpy is not installed (it provides blender_ext.py and the install target)")
    tmp = tmp_path_factory.mktemp("extension")
    try:
        result = build_extension.build(
            platforms=(build_extension.current_platform(),),
            output_dir=tmp / "dist",
            stage_dir=tmp / "ext_src",
            log=lambda message: None,
        )
    except build_extension.WheelDownloadError as err:
        if build_extension.index_reachable():
            raise
        pytest.skip(f"package index unreachable, cannot download the wheels: {err}")
    (zip_path,) = result.zips
    return zip_path


def run_python(code: str, *args: str, env: dict[str, str] | None = None, timeout: float = 300):
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        check=False,
    )


def test_zip_holds_manifest_package_and_wheels(extension_zip: Path) -> None:
    import zipfile

    names = zipfile.ZipFile(extension_zip).namelist()
    assert "blender_manifest.toml" in names
    assert "__init__.py" in names
    assert "core/__init__.py" in names
    wheels = {build_extension.wheel_name_version(Path(n).name)[0] for n in names if ".whl" in n}
    assert wheels == set(build_extension.BUNDLED_PACKAGES)
    assert not [n for n in names if "__pycache__" in n]


def test_installed_extension_poses_the_rig(extension_zip: Path, tmp_path: Path) -> None:
    result_path = tmp_path / "result.json"
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "user_resources")}
    proc = run_python(INSTALL_AND_RUN, str(extension_zip), str(result_path), env=env)
    result = json.loads(result_path.read_text()) if result_path.exists() else {}
    log = f"result: {result}\nstdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}"

    assert result.get("installed") == ["FINISHED"], log
    assert result.get("enabled"), log
    assert str(tmp_path / "user_resources") in result.get("module_file", ""), log
    assert result.get("operator_registered"), log
    assert result.get("operator_result") == ["FINISHED"], log
    assert result.get("rotation_change", 0.0) > 1e-3, log
    assert proc.returncode == 0, log

    wheels = run_python(BUNDLED_WHEELS_WORK, result["local_site"])
    assert wheels.returncode == 0, f"bundled wheels do not work:\n{wheels.stderr[-3000:]}"
