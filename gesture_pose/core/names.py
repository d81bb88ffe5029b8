"""Bone names: telling the left and right counterparts of a bone apart."""

from __future__ import annotations


def mirror_name(name: str) -> str | None:
    """The left/right counterpart of a bone name.

    Sides are suffixes (``.L``/``.R``, ``_L``/``_R``, ``-L``/``-R``, lower case too) or the
    words ``Left``/``Right`` (as in Mixamo rigs).

    Returns:
        The mirrored name, or None when the name has no side.
    """
    for sep in ".-_":
        for a, b in (("L", "R"), ("l", "r")):
            for x, y in ((a, b), (b, a)):
                if name.endswith(sep + x):
                    return name[:-1] + y
    for x, y in (("Left", "Right"), ("Right", "Left")):
        if x in name:
            return name.replace(x, y, 1)
    return None


def side_of(name: str) -> str | None:
    """The side of a bone name: ``"L"``, ``"R"`` or None (the spine, a tail).

    The same conventions as :func:`mirror_name`: ``.L``/``_l``/``-L`` suffixes and the
    words ``Left``/``Right``.
    """
    for sep in ".-_":
        for side in "LR":
            if name.endswith(sep + side) or name.endswith(sep + side.lower()):
                return side
    for word in ("Left", "Right"):
        if word in name:
            return word[0]
    return None
