"""The pure helpers of ``bench/eval_assets.py`` on hand-made data (no shared assets needed)."""

from __future__ import annotations

import numpy as np

from bench.eval_assets import bvh_joint_positions, kabsch_rotation
from gesture_pose.core.rotations import exp_map

_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Spine
  {
    OFFSET 0 2 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT Neck
    {
      OFFSET 0.000001 0 -0.000002
      CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
      End Site
      {
        OFFSET 0 1 0
      }
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.008333
1 2 3 90 0 0 0 0 0 0 0 0 90 0 0
"""


def test_bvh_joint_positions_composes_offsets_channels_and_rotations() -> None:
    joints = bvh_joint_positions(_BVH)
    # Root at its position channels, turned 90 degrees about Z: +Y becomes -X.
    np.testing.assert_allclose(joints["Hips"], [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(joints["Spine"], [-1, 2, 3], atol=1e-12)
    # Neck's position channels (zeros) replace its offset; it sits on Spine.
    np.testing.assert_allclose(joints["Neck"], joints["Spine"], atol=1e-12)
    # Neck turns 90 degrees about its local X, taking the end site's +Y to +Z, which the
    # root's turn about Z leaves in place (the rotations compose parent first).
    np.testing.assert_allclose(joints["Neck_end"], [-1, 2, 4], atol=1e-12)


def test_kabsch_rotation_recovers_a_rotation_and_stays_proper() -> None:
    rng = np.random.default_rng(0)
    truth = exp_map(np.array([0.3, -1.2, 0.7]))
    src = rng.normal(size=(8, 3))
    src /= np.linalg.norm(src, axis=1, keepdims=True)
    np.testing.assert_allclose(kabsch_rotation(src, src @ truth.T), truth, atol=1e-12)
    # Mirrored targets: the best proper rotation, never a reflection.
    r = kabsch_rotation(src, src * [1, 1, -1])
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) > 0.0
