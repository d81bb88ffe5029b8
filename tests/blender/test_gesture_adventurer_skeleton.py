"""The 2D fit's solving skeleton of a real glTF character, the Quaternius Adventurer.

Read from ``../shared/eval-assets`` (skipped when absent) as the add-on reads it: its
bones have token lengths, so the reader gives the joint skeleton.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gesture_pose.blender.read_armature import read_armature
from gesture_pose.core.gesture.solving import solving_skeleton

bpy = pytest.importorskip("bpy")

ADVENTURER = (Path(__file__).resolve().parents[3] / "shared" / "eval-assets"
              / "humanoid_quaternius_adventurer" / "Adventurer_cmu40poses.glb")


@pytest.mark.skipif(not ADVENTURER.exists(), reason="eval assets absent")
def test_the_adventurers_end_caps_are_its_feet_and_head_not_its_crotch(bpy_blank):
    bpy.ops.import_scene.gltf(filepath=str(ADVENTURER))
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    arm.data.pose_position = "REST"
    bpy.context.view_layer.update()
    sol = solving_skeleton(read_armature(arm).skeleton)
    names = list(sol.joint_bones)
    # Spine, head, arms to the hands and legs to the feet; the fingers, the neck and the
    # shoulders are shorter than 2 resampling steps and follow their parents.
    assert sol.n_joints == 23
    assert {"Neck", "Shoulder.L", "Shoulder.R", "Index2.L"} <= {
        read_armature(arm).skeleton.names[e] for e in sol.excluded}
    # The joint skeleton's Hips runs from the crotch up to the abdomen, the legs hung from
    # its top: its head is inside the body, not an end cap (it still ends its chain).
    hips = names.index("Hips head")
    assert sol.joint_parent[hips] == -1 and sol.limb_ends[hips] and not sol.terminal[hips]
    ends = {names[j] for j in np.flatnonzero(sol.terminal)}
    assert ends == {"Foot.L tail", "Foot.R tail", "Head tail"}
