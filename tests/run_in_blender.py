"""Run the test suite inside a real Blender instead of the ``bpy`` module.

Usage (from the repository root, Blender 5.0 or newer)::

    blender -b --factory-startup --python tests/run_in_blender.py -- [pytest arguments]

Blender's bundled Python runs pytest. pytest itself is taken from the project's
``.venv`` (created by ``make test``) when Blender's Python does not have it; Blender's own
``bpy`` stays the one imported. The exit code is pytest's.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _pytest_args() -> list[str]:
    argv = sys.argv
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    return extra or ["-q", str(ROOT / "tests")]


def _ensure_pytest() -> None:
    try:
        import pytest  # noqa: F401
    except ImportError:
        venv = ROOT / ".venv" / "lib"
        for site in sorted(venv.glob("python3.*/site-packages")):
            sys.path.append(str(site))  # after Blender's paths: Blender's bpy wins


def main() -> int:
    """Run pytest with the arguments after ``--``."""
    sys.path.insert(0, str(ROOT))
    _ensure_pytest()
    import pytest

    return int(pytest.main(_pytest_args()))


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.exit(code)
