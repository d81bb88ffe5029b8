"""Bone names: telling the left and right counterparts of a bone apart.

A side is written as a separate token of the name, in one of the conventions rigs use:

- a suffix: ``thigh.L``, ``thigh_l``, ``thigh-R`` (Blender, Unreal);
- a suffix followed by a number: ``DEF-thigh.L.001`` (Rigify's duplicates);
- a prefix or a word inside: ``L_Thigh``, ``Bip01 L Thigh``, ``ValveBiped.Bip01_R_Foot``;
- the words ``Left``/``Right``, also inside a name (``mixamorig:LeftUpLeg``), or
  ``left``/``right`` as a token (``upperarm_left``).

A single ``L``/``R`` (either case) counts only as a whole token between separators
(``.``, ``-``, ``_``, ``:``, space, or the ends of the name), so ``Lid`` or ``Root`` have no
side. The last side token wins (``L_arm.R`` is a right bone), as in the suffix convention.
"""

from __future__ import annotations

import re

#: Separators between the tokens of a bone name.
_TOKEN = re.compile(r"[^.\-_: ]+")
#: Side tokens and their counterparts.
_SIDES = {"L": "R", "R": "L", "l": "r", "r": "l", "Left": "Right", "Right": "Left",
          "left": "right", "right": "left", "LEFT": "RIGHT", "RIGHT": "LEFT"}


def _side_token(name: str) -> re.Match | None:
    """The last token of ``name`` that names a side, or None."""
    found = None
    for m in _TOKEN.finditer(name):
        if m.group() in _SIDES:
            found = m
    return found


def mirror_name(name: str) -> str | None:
    """The left/right counterpart of a bone name (conventions: the module's docstring).

    Returns:
        The mirrored name, or None when the name has no side.
    """
    m = _side_token(name)
    if m is not None:
        return name[:m.start()] + _SIDES[m.group()] + name[m.end():]
    for x, y in (("Left", "Right"), ("Right", "Left")):
        if x in name:
            return name.replace(x, y, 1)
    return None


def side_of(name: str) -> str | None:
    """The side of a bone name: ``"L"``, ``"R"`` or None (the spine, a tail).

    Conventions: the module's docstring.
    """
    m = _side_token(name)
    if m is not None:
        return m.group()[0].upper()
    for word in ("Left", "Right"):
        if word in name:
            return word[0]
    return None
