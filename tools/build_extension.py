"""Build the gesture_pose Blender extension zip(s), with the Python wheels it needs.

Steps:

1. Download the wheels of the bundled packages (:data:`BUNDLED_PACKAGES`, pinned in
   ``requirements.txt``) for each target platform into a cache (``build/wheels/<platform>``);
   a cached wheel is never downloaded again. A platform without a wheel for every package is
   skipped with a note.
2. Stage ``build/ext_src``: ``blender_manifest.toml`` (plus the generated ``platforms`` and
   ``wheels`` lists), the contents of ``gesture_pose/`` (its ``__init__.py`` becomes the zip
   root) and ``wheels/*.whl``.
3. Run Blender's ``blender_ext.py`` (shipped in the ``bpy`` wheel, run with plain Python):
   ``validate``, then ``build`` (``--split-platforms`` for more than one platform), then
   ``validate`` on every zip it wrote.

Bundled packages: ``scipy`` and ``osqp``, plus ``Jinja2`` and ``MarkupSafe`` because
``osqp/interface.py`` imports jinja2 at module level (for code generation, but ``import osqp``
fails without it). osqp's other declared dependencies are not needed to import osqp and
solve: ``joblib`` is only used by ``osqp.nn`` and ``setuptools`` is never imported. numpy
ships with Blender and is not bundled.

Usage::

    python tools/build_extension.py [--platforms linux-x64,windows-x64] [--output-dir dist]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
PACKAGE_DIR = REPO_ROOT / "gesture_pose"
MANIFEST_PATH = REPO_ROOT / "blender_manifest.toml"
REQUIREMENTS_PATH = REPO_ROOT / "requirements.txt"
PYPROJECT_PATH = REPO_ROOT / "pyproject.toml"
DEFAULT_OUTPUT_DIR = REPO_ROOT / "dist"
DEFAULT_STAGE_DIR = REPO_ROOT / "build" / "ext_src"
DEFAULT_CACHE_DIR = REPO_ROOT / "build" / "wheels"

#: Blender's Python version (Blender 5.0 ships CPython 3.11).
PYTHON_VERSION = "3.11"

#: Distributions bundled as wheels, by normalized name; versions come from requirements.txt.
BUNDLED_PACKAGES: tuple[str, ...] = ("scipy", "osqp", "jinja2", "markupsafe")

#: pip ``--platform`` tags per Blender platform, most preferred first. pip expands
#: ``macosx_X_Y`` to older macOS versions and ``manylinux2014`` to its aliases, so listing
#: the oldest version first picks the most compatible wheel (scipy's arm64 wheel still needs
#: macOS 12).
PLATFORM_TAGS: dict[str, tuple[str, ...]] = {
    "linux-x64": (
        *(f"manylinux_2_{minor}_x86_64" for minor in range(28, 16, -1)),
        "manylinux2014_x86_64",
    ),
    "windows-x64": ("win_amd64",),
    "macos-arm64": tuple(f"macosx_{major}_0_arm64" for major in range(11, 16)),
    "macos-x64": tuple(f"macosx_{major}_0_x86_64" for major in range(11, 16)),
}

DEFAULT_PLATFORMS: tuple[str, ...] = tuple(PLATFORM_TAGS)

#: Where the bpy wheel keeps the extension command line tool, below its package directory.
BLENDER_EXT_GLOB = "*/scripts/addons_core/bl_pkg/cli/blender_ext.py"

#: Index probed to tell "no wheel for this platform" from "no network".
INDEX_URL = "https://pypi.org/simple/"


class BuildError(Exception):
    """The extension could not be built; the message says why."""


class WheelDownloadError(BuildError):
    """pip could not download a wheel (no wheel for the platform, or no network)."""


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build` produced.

    Attributes:
        zips: Paths of the extension zips written.
        wheels: Wheel file names bundled, per Blender platform.
        skipped: Platforms skipped, with the reason.
    """

    zips: tuple[Path, ...]
    wheels: dict[str, tuple[str, ...]]
    skipped: dict[str, str]


def normalize_name(name: str) -> str:
    """Return a distribution name normalized as in PEP 503 (``MarkupSafe`` -> ``markupsafe``).

    Args:
        name: Distribution name as written in a requirement or wheel file name.

    Returns:
        Lower-case name with runs of ``-``, ``_`` and ``.`` replaced by ``-``.
    """
    return re.sub(r"[-_.]+", "-", name).lower()


def read_pins(requirements_text: str) -> dict[str, str]:
    """Parse ``name==version`` pins from requirements text.

    Args:
        requirements_text: Contents of a requirements file; comments and blank lines ignored.

    Returns:
        Mapping of normalized distribution name to pinned version.
    """
    pins: dict[str, str] = {}
    for line in requirements_text.splitlines():
        line = line.split("#", 1)[0].strip()
        match = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)\s*==\s*([^\s;]+)", line)
        if match:
            pins[normalize_name(match.group(1))] = match.group(2)
    return pins


def bundled_requirements(pins: dict[str, str]) -> tuple[tuple[str, str], ...]:
    """Return ``(name, version)`` for each bundled package.

    Args:
        pins: Pins from :func:`read_pins`.

    Returns:
        One ``(normalized name, version)`` pair per entry of :data:`BUNDLED_PACKAGES`.

    Raises:
        BuildError: A bundled package is not pinned.
    """
    missing = [name for name in BUNDLED_PACKAGES if name not in pins]
    if missing:
        raise BuildError(f"requirements.txt must pin {', '.join(missing)} (name==version)")
    return tuple((name, pins[name]) for name in BUNDLED_PACKAGES)


def parse_platforms(text: str) -> tuple[str, ...]:
    """Parse a comma-separated list of Blender platforms.

    Args:
        text: For example ``"linux-x64,windows-x64"``.

    Returns:
        The platforms, in the given order, without duplicates.

    Raises:
        BuildError: A platform is unknown or the list is empty.
    """
    platforms = tuple(dict.fromkeys(p.strip() for p in text.split(",") if p.strip()))
    unknown = [p for p in platforms if p not in PLATFORM_TAGS]
    if unknown or not platforms:
        raise BuildError(
            f"unknown platform(s) {unknown or text!r}; choose from {', '.join(PLATFORM_TAGS)}"
        )
    return platforms


def current_platform() -> str:
    """Return the Blender platform name of this machine (``linux-x64`` etc.).

    Raises:
        BuildError: This machine is not one of :data:`PLATFORM_TAGS`.
    """
    system = {"darwin": "macos"}.get(platform.system().lower(), platform.system().lower())
    machine = platform.machine().lower()
    machine = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64"}.get(machine, machine)
    name = f"{system}-{machine}"
    if name not in PLATFORM_TAGS:
        raise BuildError(f"no extension build for this platform ({name})")
    return name


def wheel_name_version(filename: str) -> tuple[str, str]:
    """Return the normalized distribution name and version of a wheel file name.

    Args:
        filename: For example ``"MarkupSafe-3.0.4-cp311-cp311-win_amd64.whl"``.

    Returns:
        ``("markupsafe", "3.0.4")``.
    """
    name, version = filename.split("-")[:2]
    return normalize_name(name), version


def find_cached_wheel(directory: Path, name: str, version: str) -> Path | None:
    """Return the wheel of ``name==version`` in ``directory``, if there is one.

    Args:
        directory: Wheel cache of one platform.
        name: Normalized distribution name.
        version: Exact version.

    Returns:
        The wheel path, or None.
    """
    if not directory.is_dir():
        return None
    for path in sorted(directory.glob("*.whl")):
        if wheel_name_version(path.name) == (name, version):
            return path
    return None


def pip_download_command(name: str, version: str, platform_name: str, dest: Path) -> list[str]:
    """Return the pip command that downloads one wheel for one Blender platform.

    Args:
        name: Distribution name.
        version: Exact version.
        platform_name: Blender platform, a key of :data:`PLATFORM_TAGS`.
        dest: Download directory.

    Returns:
        The command line (runs pip with the current interpreter).
    """
    command = [
        sys.executable,
        *"-m pip download --no-deps --only-binary=:all: --implementation cp --quiet".split(),
        *("--python-version", PYTHON_VERSION, "--timeout", "30", "--retries", "2"),
        *("--dest", str(dest)),
    ]
    for tag in PLATFORM_TAGS[platform_name]:
        command += ["--platform", tag]
    return [*command, f"{name}=={version}"]


def download_wheel(name: str, version: str, platform_name: str, cache_dir: Path) -> Path:
    """Return the cached wheel of ``name==version`` for a platform, downloading it if needed.

    The download goes to a temporary directory first, so an interrupted or concurrent run
    never leaves a partial wheel in the cache.

    Args:
        name: Normalized distribution name.
        version: Exact version.
        platform_name: Blender platform, a key of :data:`PLATFORM_TAGS`.
        cache_dir: Cache root; wheels go to ``cache_dir / platform_name``.

    Returns:
        Path of the wheel in the cache.

    Raises:
        WheelDownloadError: pip failed (no such wheel, or no network).
    """
    platform_dir = cache_dir / platform_name
    cached = find_cached_wheel(platform_dir, name, version)
    if cached is not None:
        return cached
    cache_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache_dir, prefix=".download-") as tmp:
        command = pip_download_command(name, version, platform_name, Path(tmp))
        proc = subprocess.run(command, capture_output=True, text=True, check=False)
        found = find_cached_wheel(Path(tmp), name, version)
        if proc.returncode != 0 or found is None:
            errors = [
                line
                for line in (proc.stdout + proc.stderr).splitlines()
                if "is ignored: it is neither a file nor a directory" not in line
            ]
            raise WheelDownloadError(
                f"pip could not download {name}=={version} for {platform_name}:\n"
                + "\n".join(errors[-10:])
            )
        platform_dir.mkdir(exist_ok=True)
        target = platform_dir / found.name
        os.replace(found, target)
    return target


def index_reachable(url: str = INDEX_URL, timeout: float = 10.0) -> bool:
    """Return whether the package index answers (used to tell a missing wheel from no network).

    Args:
        url: Index URL.
        timeout: Seconds to wait.

    Returns:
        True if an HTTP response came back.
    """
    try:
        with urllib.request.urlopen(urllib.request.Request(url, method="HEAD"), timeout=timeout):
            return True
    except urllib.error.HTTPError:
        return True
    except (OSError, ValueError):
        return False


def find_blender_ext() -> Path:
    """Locate ``blender_ext.py`` inside the installed bpy package, without importing bpy.

    Returns:
        Path of ``blender_ext.py``.

    Raises:
        BuildError: bpy is not installed or does not contain the tool.
    """
    spec = importlib.util.find_spec("bpy")
    locations = list(spec.submodule_search_locations or []) if spec else []
    for location in locations:
        matches = sorted(Path(location).glob(BLENDER_EXT_GLOB))
        if matches:
            return matches[-1]
    raise BuildError(
        "blender_ext.py not found: install bpy (`make venv`) or pass --blender-ext PATH"
    )


def manifest_with_build_fields(
    manifest_text: str, platforms: Sequence[str], wheels: Sequence[str]
) -> str:
    """Return the manifest text with top-level ``platforms`` and ``wheels`` lists added.

    The lines go before the first table header so they stay top-level keys.

    Args:
        manifest_text: Source ``blender_manifest.toml``, which must not set either key.
        platforms: Blender platforms, e.g. ``["linux-x64"]``.
        wheels: Wheel paths relative to the extension root, e.g. ``["./wheels/x.whl"]``.

    Returns:
        The new manifest text.

    Raises:
        BuildError: The source manifest already sets ``platforms`` or ``wheels``.
    """
    existing = tomllib.loads(manifest_text)
    for key in ("platforms", "wheels"):
        if key in existing:
            raise BuildError(f"blender_manifest.toml must not set {key!r}: the build writes it")

    def toml_list(items: Sequence[str]) -> str:
        return "[\n" + "".join(f'    "{item}",\n' for item in items) + "]\n"

    generated = (
        "\n# Written by tools/build_extension.py.\n"
        f"platforms = {toml_list(platforms)}"
        f"wheels = {toml_list(wheels)}\n"
    )
    lines = manifest_text.splitlines(keepends=True)
    index = next((i for i, line in enumerate(lines) if re.match(r"\s*\[", line)), len(lines))
    if index == len(lines) and lines and not lines[-1].endswith("\n"):
        lines[-1] += "\n"
    result = "".join(lines[:index]) + generated + "".join(lines[index:])
    tomllib.loads(result)  # Fails loudly if the insertion broke the TOML.
    return result


def stage_source(
    stage_dir: Path,
    platforms: Sequence[str],
    wheels: Iterable[Path],
    manifest_path: Path = MANIFEST_PATH,
    package_dir: Path = PACKAGE_DIR,
) -> Path:
    """Write the extension source tree: manifest, package contents and wheels.

    Args:
        stage_dir: Directory to (re)create; its previous contents are removed.
        platforms: Blender platforms the extension supports.
        wheels: Wheel files to copy into ``stage_dir / "wheels"`` (duplicates allowed).
        manifest_path: Source manifest.
        package_dir: The ``gesture_pose`` package; its contents become the extension root.

    Returns:
        ``stage_dir``.
    """
    if stage_dir.exists():
        shutil.rmtree(stage_dir)
    shutil.copytree(package_dir, stage_dir, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    wheel_dir = stage_dir / "wheels"
    wheel_dir.mkdir()
    names: list[str] = []
    for wheel in wheels:
        if wheel.name not in names:
            shutil.copy2(wheel, wheel_dir / wheel.name)
            names.append(wheel.name)
    manifest = manifest_with_build_fields(
        manifest_path.read_text(encoding="utf-8"),
        platforms,
        [f"./wheels/{name}" for name in sorted(names)],
    )
    (stage_dir / manifest_path.name).write_text(manifest, encoding="utf-8")
    return stage_dir


def run_blender_ext(blender_ext: Path, *args: str) -> str:
    """Run ``blender_ext.py`` with the current interpreter.

    Args:
        blender_ext: Path from :func:`find_blender_ext`.
        *args: Sub-command and its arguments.

    Returns:
        The tool's standard output.

    Raises:
        BuildError: The tool failed.
    """
    proc = subprocess.run(
        [sys.executable, str(blender_ext), *args], capture_output=True, text=True, check=False
    )
    if proc.returncode != 0:
        raise BuildError(
            f"blender_ext.py {' '.join(args)} failed:\n{proc.stdout}{proc.stderr}".rstrip()
        )
    return proc.stdout


def zip_names(extension_id: str, version: str, platforms: Sequence[str]) -> tuple[str, ...]:
    """Return the file names ``blender_ext.py build`` writes.

    Args:
        extension_id: Manifest ``id``.
        version: Manifest ``version``.
        platforms: Platforms built; more than one means one zip per platform.

    Returns:
        ``("<id>-<version>.zip",)`` for one platform, else
        ``"<id>-<version>-<platform with _>.zip"`` per platform.
    """
    if len(platforms) == 1:
        return (f"{extension_id}-{version}.zip",)
    return tuple(f"{extension_id}-{version}-{p.replace('-', '_')}.zip" for p in platforms)


def check_versions(
    manifest_path: Path = MANIFEST_PATH, pyproject_path: Path = PYPROJECT_PATH
) -> tuple[str, str]:
    """Return the manifest's ``(id, version)``, checking the version matches pyproject.toml.

    Args:
        manifest_path: ``blender_manifest.toml``.
        pyproject_path: ``pyproject.toml``; skipped if missing.

    Returns:
        ``(id, version)`` from the manifest.

    Raises:
        BuildError: The two versions differ.
    """
    manifest = tomllib.loads(manifest_path.read_text(encoding="utf-8"))
    if pyproject_path.exists():
        project = tomllib.loads(pyproject_path.read_text(encoding="utf-8")).get("project", {})
        if project.get("version", manifest["version"]) != manifest["version"]:
            raise BuildError(
                f"version mismatch: blender_manifest.toml {manifest['version']} vs "
                f"pyproject.toml {project['version']}"
            )
    return manifest["id"], manifest["version"]


def build(
    platforms: Sequence[str] = DEFAULT_PLATFORMS,
    output_dir: Path = DEFAULT_OUTPUT_DIR,
    stage_dir: Path = DEFAULT_STAGE_DIR,
    cache_dir: Path = DEFAULT_CACHE_DIR,
    blender_ext: Path | None = None,
    log: Callable[[str], None] = print,
) -> BuildResult:
    """Download wheels, stage the source, validate and build the extension zip(s).

    Args:
        platforms: Blender platforms to build for.
        output_dir: Where the zips go (created if missing).
        stage_dir: Staging directory (recreated).
        cache_dir: Wheel cache root.
        blender_ext: ``blender_ext.py`` to use; found in the bpy package if None.
        log: Progress printer.

    Returns:
        The zips written, wheels per platform and skipped platforms.

    Raises:
        WheelDownloadError: A download failed and the package index is unreachable.
        BuildError: No platform could be built, or Blender's tool rejected the package.
    """
    blender_ext = blender_ext or find_blender_ext()
    extension_id, version = check_versions()
    requirements = bundled_requirements(read_pins(REQUIREMENTS_PATH.read_text(encoding="utf-8")))
    cache_dir.mkdir(parents=True, exist_ok=True)

    wheels: dict[str, tuple[Path, ...]] = {}
    skipped: dict[str, str] = {}
    for platform_name in platforms:
        try:
            found = tuple(download_wheel(*req, platform_name, cache_dir) for req in requirements)
        except WheelDownloadError as err:
            if not index_reachable():
                raise WheelDownloadError(f"package index {INDEX_URL} unreachable; {err}") from err
            skipped[platform_name] = str(err)
            log(f"note: skipping {platform_name}, no wheel for it: {err}")
            continue
        wheels[platform_name] = found
    built = [p for p in platforms if p in wheels]
    if not built:
        raise BuildError("no platform has all the wheels; nothing built")

    stage_source(stage_dir, built, [w for p in built for w in wheels[p]])
    log(run_blender_ext(blender_ext, "validate", str(stage_dir)).strip())
    output_dir.mkdir(parents=True, exist_ok=True)
    args = ["build", "--source-dir", str(stage_dir), "--output-dir", str(output_dir)]
    if len(built) > 1:
        args.append("--split-platforms")
    log(run_blender_ext(blender_ext, *args).strip())

    zips = tuple(output_dir / name for name in zip_names(extension_id, version, built))
    for path in zips:
        if not path.is_file():
            raise BuildError(f"blender_ext.py build did not write {path}")
        run_blender_ext(blender_ext, "validate", str(path))
    return BuildResult(
        zips=zips,
        wheels={p: tuple(w.name for w in wheels[p]) for p in built},
        skipped=skipped,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point.

    Args:
        argv: Arguments without the program name; ``sys.argv[1:]`` if None.

    Returns:
        Process exit status.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--platforms",
        default=",".join(DEFAULT_PLATFORMS),
        help=f"comma-separated Blender platforms (default: {','.join(DEFAULT_PLATFORMS)})",
    )
    parser.add_argument("--output-dir", type=Path, default=DEFAULT_OUTPUT_DIR)
    parser.add_argument("--stage-dir", type=Path, default=DEFAULT_STAGE_DIR)
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR)
    parser.add_argument("--blender-ext", type=Path, default=None, help="blender_ext.py to use")
    args = parser.parse_args(argv)
    try:
        result = build(
            platforms=parse_platforms(args.platforms),
            output_dir=args.output_dir,
            stage_dir=args.stage_dir,
            cache_dir=args.cache_dir,
            blender_ext=args.blender_ext,
        )
    except BuildError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    for platform_name, names in result.wheels.items():
        print(f"{platform_name}: {', '.join(names)}")
    for path in result.zips:
        print(f"built {path} ({path.stat().st_size / 2**20:.1f} MiB)")
    for platform_name in result.skipped:
        print(f"skipped {platform_name} (no wheel)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
