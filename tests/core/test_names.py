"""Bone names: the side conventions of real rigs."""

from __future__ import annotations

import pytest

from gesture_pose.core.names import mirror_name, side_of


@pytest.mark.parametrize("name,side,mirror", [
    ("thigh.L", "L", "thigh.R"),                                   # Blender
    ("hip_l", "L", "hip_r"),                                       # Unreal
    ("Arm-R", "R", "Arm-L"),
    ("DEF-thigh.L.001", "L", "DEF-thigh.R.001"),                   # Rigify duplicates
    ("Bip01 L Thigh", "L", "Bip01 R Thigh"),                       # 3ds Max Biped
    ("ValveBiped.Bip01_R_Foot", "R", "ValveBiped.Bip01_L_Foot"),
    ("L_Thigh", "L", "R_Thigh"),
    ("arm_joint_L_1", "L", "arm_joint_R_1"),                       # Khronos RiggedFigure
    ("mixamorig:LeftUpLeg", "L", "mixamorig:RightUpLeg"),          # Mixamo
    ("RightHand", "R", "LeftHand"),
    ("upperarm_left", "L", "upperarm_right"),
    ("spine", None, None),
    ("Root", None, None),                                          # no lone L/R token
    ("Lid", None, None),
    ("Bone.001", None, None),
])
def test_side_conventions(name, side, mirror):
    assert side_of(name) == side
    assert mirror_name(name) == mirror
    if mirror is not None:
        assert mirror_name(mirror) == name
        assert side_of(mirror) == {"L": "R", "R": "L"}[side]
