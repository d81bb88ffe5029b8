"""`make bench`: run every ``bench/bench_*.py`` and print its tables.

Each module exposes ``run(quick: bool) -> list[tuple[str, list[str], list[list]]]``: a
table title, its column headers and its rows. ``--quick`` asks for smaller runs (used by
the tests that check the benchmarks still run); ``--only NAME`` runs the modules whose
name contains NAME.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

Table = tuple[str, list[str], list[list]]


def format_cell(value: object) -> str:
    """Numbers get 3 significant digits (or are shown as integers); the rest as text."""
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if value != value:  # NaN
            return "-"
        return f"{value:.3g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value)


def format_table(title: str, headers: list[str], rows: list[list]) -> str:
    """A Markdown table with a title line."""
    cells = [[format_cell(v) for v in row] for row in rows]
    widths = [max([len(h)] + [len(r[i]) for r in cells]) for i, h in enumerate(headers)]
    line = "| " + " | ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = ["| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |"
            for r in cells]
    return "\n".join([f"### {title}", "", line, sep, *body, ""])


def bench_modules(only: str | None) -> list[Path]:
    """Benchmark module files, sorted by name, filtered by ``only``."""
    files = sorted(HERE.glob("bench_*.py"))
    return [f for f in files if only is None or only in f.stem]


def load(path: Path):
    """Import a benchmark module from its file."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    """Run the benchmarks and print their tables; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="small runs")
    parser.add_argument("--only", help="run modules whose name contains this")
    args = parser.parse_args(argv)
    for path in bench_modules(args.only):
        t0 = time.perf_counter()
        tables: list[Table] = load(path).run(args.quick)
        for title, headers, rows in tables:
            print(format_table(title, headers, rows), flush=True)
        print(f"({path.stem}: {time.perf_counter() - t0:.1f} s)\n", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
