"""gesture_pose.core must run without Blender: numpy, scipy, osqp and the standard library only.

The modules are read with ``ast`` (never imported), so a forbidden import fails here even in
code paths no other test reaches.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "gesture_pose"
CORE = f"{PACKAGE}.core"
CORE_DIR = REPO_ROOT / PACKAGE / "core"

BLENDER_MODULES = frozenset({"bpy", "mathutils", "bmesh", "bpy_extras"})
ALLOWED_THIRD_PARTY = frozenset({"numpy", "scipy", "osqp"})


def core_modules() -> list[Path]:
    return sorted(p for p in CORE_DIR.rglob("*.py") if "__pycache__" not in p.parts)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO_ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def resolve(path: Path, module: str | None, level: int) -> str:
    """Absolute name of the module an import statement in ``path`` refers to."""
    if level == 0:
        return module or ""
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package.pop()
    if level - 1 >= len(package):
        return "<beyond top-level package>"
    base = package[: len(package) - (level - 1)]
    return ".".join(base + ([module] if module else []))


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` for every import in a file.

    ``from X import a`` yields ``X.a`` as well as ``X`` (``a`` may be a submodule), and
    ``importlib.import_module("X")`` / ``__import__("X")`` calls with a literal count too.
    """
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = resolve(path, node.module, node.level)
            found.append((node.lineno, target))
            found += [(node.lineno, f"{target}.{alias.name}") for alias in node.names]
        elif (
            isinstance(node, ast.Call)
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
            and (
                (isinstance(node.func, ast.Name) and node.func.id == "__import__")
                or (isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
            )
        ):
            found.append((node.lineno, node.args[0].value))
    return found


def violation(name: str) -> str | None:
    """Why importing ``name`` from core is forbidden, or None if it is allowed."""
    top = name.split(".")[0]
    if name.startswith("<"):
        return "relative import beyond the top-level package"
    if top in BLENDER_MODULES:
        return "Blender module"
    if top == PACKAGE:
        if name == CORE or name.startswith(CORE + "."):
            return None
        if name == PACKAGE:
            return None  # `from .. import x` also yields `gesture_pose.x`, checked separately.
        return "reaches outside gesture_pose.core"
    if top in ALLOWED_THIRD_PARTY or top in sys.stdlib_module_names:
        return None
    return "third-party module other than numpy, scipy, osqp (not bundled in the extension)"


def test_core_has_modules() -> None:
    assert CORE_DIR.is_dir(), f"{CORE_DIR} is missing"
    assert core_modules(), f"no Python modules under {CORE_DIR}: the purity test would be vacuous"


@pytest.mark.parametrize("path", core_modules(), ids=lambda p: str(p.relative_to(CORE_DIR)))
def test_core_module_imports_no_blender(path: Path) -> None:
    problems = [
        f"{path.relative_to(REPO_ROOT)}:{line}: {name} ({reason})"
        for line, name in imported_modules(path)
        if (reason := violation(name))
    ]
    assert not problems, "forbidden imports in gesture_pose.core:\n" + "\n".join(problems)


@pytest.mark.parametrize("path", core_modules(), ids=lambda p: str(p.relative_to(CORE_DIR)))
def test_core_module_imports_package_relatively(path: Path) -> None:
    # Absolute `gesture_pose...` imports break once installed as bl_ext.<repo>.gesture_pose.
    tree = ast.parse(path.read_text(encoding="utf-8"))
    absolute = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names = [node.module or ""]
        else:
            continue
        if any(name.split(".")[0] == PACKAGE for name in names):
            absolute.append(node.lineno)
    assert not absolute, f"{path.name}: use relative imports on lines {absolute}"


@pytest.mark.parametrize(
    ("source", "module", "expected"),
    [
        ("import bpy", "gesture_pose/core/a.py", "Blender module"),
        ("from mathutils import Vector", "gesture_pose/core/a.py", "Blender module"),
        ("import bpy_extras.view3d_utils", "gesture_pose/core/a.py", "Blender module"),
        ("from bmesh.types import BMesh", "gesture_pose/core/x/b.py", "Blender module"),
        ("from ..blender import read", "gesture_pose/core/a.py", "outside"),
        ("from ... import blender", "gesture_pose/core/x/b.py", "outside"),
        ("from .. import blender", "gesture_pose/core/a.py", "outside"),
        ("from ..... import x", "gesture_pose/core/a.py", "beyond"),
        ("import importlib\nimportlib.import_module('bpy')", "gesture_pose/core/a.py", "Blender"),
        ("import torch", "gesture_pose/core/a.py", "third-party"),
        ("from .. import skeleton", "gesture_pose/core/x/b.py", None),
        ("from .rotations import rodrigues", "gesture_pose/core/a.py", None),
        (
            "import numpy as np\nfrom scipy import sparse\nimport osqp",
            "gesture_pose/core/a.py",
            None,
        ),
        ("from __future__ import annotations\nimport dataclasses", "gesture_pose/core/a.py", None),
    ],
)
def test_checker_on_examples(tmp_path: Path, monkeypatch, source, module, expected) -> None:
    path = tmp_path / module
    path.parent.mkdir(parents=True)
    path.write_text(source)
    monkeypatch.setattr(sys.modules[__name__], "REPO_ROOT", tmp_path)
    reasons = [r for _, name in imported_modules(path) if (r := violation(name))]
    if expected is None:
        assert reasons == []
    else:
        assert reasons and expected in reasons[0], reasons
