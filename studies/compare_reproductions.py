"""Compare the CSVs of two reproduction output directories column by column.

Usage::

    python studies/compare_reproductions.py OLD_DIR NEW_DIR [--rtol 1e-9] [--ignore REGEX]

Every ``*.csv`` under OLD_DIR (the sweep ``cache/`` folders excluded) is read beside the file
of the same relative path under NEW_DIR, rows matched by position.  Each shared column gets a
verdict:

* ``identical``: every entry equal (numbers bit for bit, NaN equal to NaN, text equal);
* ``rounding``: numbers equal to ``rtol`` (relative to max(|a|, |b|), absolute below 1e-300);
* ``different``: anything else, with the largest relative difference and the first row that differs.

Columns holding lists of numbers (the record series, written as ``[...]``) are compared entry
by entry.  Wall-time columns (``seconds``, ``wall``, ... matched by ``--ignore``) are skipped.
Columns present in only one file and a changed row count are reported, never hidden.

``--points`` also compares the sweep caches (``cache/<sweep>/*.json``): the points are matched
by their parameters (the file names are code-keyed hashes and differ between trees) and every
field of each point's result (series, final densities, verdicts) gets a verdict the same way.
The output is one line per (file, column); the exit status is 0 whatever the verdicts.
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

IGNORE = r"(^|_)(seconds|wall|wall_s|time_s|elapsed)($|_)"


def _as_numbers(x: object) -> np.ndarray | None:
    """The entry as a flat float array (a number, or a list written as text), or None for text."""
    if isinstance(x, bool):
        return np.array([float(x)])
    if isinstance(x, (int, float, np.integer, np.floating)):
        return np.array([float(x)])
    if isinstance(x, str) and x.startswith("["):
        try:
            v = ast.literal_eval(x.replace("nan", "None").replace("inf", "1e999"))
        except (ValueError, SyntaxError):
            return None
        try:
            return np.array([np.nan if e is None else e for e in np.ravel(v)], dtype=float)
        except (TypeError, ValueError):
            return None
    return None


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |a - b| / max(|a|, |b|) over entries, NaN matching NaN; inf where NaN meets a number."""
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if np.any(nan_a != nan_b):
        return math.inf
    a, b = a[~nan_a], b[~nan_b]
    if a.size == 0:
        return 0.0
    if np.any(np.isinf(a) | np.isinf(b)):
        return 0.0 if np.array_equal(a, b) else math.inf
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-300)
    return float(np.max(np.abs(a - b) / scale))


def compare_column(old: pd.Series, new: pd.Series, rtol: float) -> tuple[str, float, int | None]:
    """(verdict, largest relative difference, first differing row) of two aligned columns."""
    worst, first = 0.0, None
    for i, (a, b) in enumerate(zip(old, new, strict=True)):
        if (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)) or a == b:
            continue
        na, nb = _as_numbers(a), _as_numbers(b)
        if na is None or nb is None or na.shape != nb.shape:
            r = math.inf  # text that differs, or series of different lengths
        else:
            r = _rel(na, nb)
            if r == 0.0 and np.array_equal(na, nb, equal_nan=True):
                continue
        if first is None and r > 0.0:
            first = i
        worst = max(worst, r)
    if first is None:
        return "identical", 0.0, None
    return ("rounding" if worst <= rtol else "different"), worst, first


def compare_files(old: Path, new: Path, rtol: float, ignore: str) -> list[str]:
    """One report line per column (and per structural difference) of the two CSVs."""
    a, b = pd.read_csv(old), pd.read_csv(new)
    lines = []
    only_old = [c for c in a.columns if c not in b.columns]
    only_new = [c for c in b.columns if c not in a.columns]
    if only_old:
        lines.append(f"  columns only in old: {only_old}")
    if only_new:
        lines.append(f"  columns only in new: {only_new}")
    if len(a) != len(b):
        lines.append(f"  ROWS differ: old {len(a)}, new {len(b)}; comparing the first {min(len(a), len(b))}")
    n = min(len(a), len(b))
    for c in a.columns:
        if c not in b.columns:
            continue
        if re.search(ignore, c):
            lines.append(f"  {c:28s} skipped (wall time)")
            continue
        verdict, worst, row = compare_column(a[c].iloc[:n], b[c].iloc[:n], rtol)
        detail = "" if verdict == "identical" else f" max rel {worst:.3g} (first at row {row})"
        lines.append(f"  {c:28s} {verdict}{detail}")
    return [f"{old.name}: {n} rows", *lines]


def _flatten(x: object) -> np.ndarray | str:
    """Nested lists / dicts of numbers as one float array; anything holding text as its JSON."""
    try:
        if isinstance(x, dict):
            return np.concatenate([np.atleast_1d(_flatten(x[k])) for k in sorted(x)]) if x else np.zeros(0)
        v = np.array(x, dtype=float)
        return v.ravel()
    except (TypeError, ValueError):
        return json.dumps(x, sort_keys=True)


def _load_points(folder: Path) -> dict[str, dict]:
    out = {}
    for f in sorted(folder.glob("*.json")):
        d = json.loads(f.read_text())
        out[json.dumps(d["point"], sort_keys=True)] = d["result"]
    return out


def compare_points(old: Path, new: Path, rtol: float, ignore: str) -> list[str]:
    """One line per (point, result field) of two sweep caches, points matched by parameters."""
    a, b = _load_points(old), _load_points(new)
    lines = [f"cache {old.name}: {len(a)} points old, {len(b)} new"]
    for key in sorted(a):
        if key not in b:
            lines.append(f"  point {key}: MISSING in new")
            continue
        ra, rb = a[key], b[key]
        lines.append(f"  point {key}")
        for field in sorted(set(ra) | set(rb)):
            if field not in ra or field not in rb:
                lines.append(f"    {field:26s} only in {'new' if field in rb else 'old'}")
                continue
            if re.search(ignore, field):
                continue
            fa, fb = _flatten(ra[field]), _flatten(rb[field])
            if isinstance(fa, str) or isinstance(fb, str) or fa.shape != fb.shape:
                same = json.dumps(ra[field], sort_keys=True) == json.dumps(rb[field], sort_keys=True)
                size = "" if isinstance(fa, str) or isinstance(fb, str) else f" (length {fa.size} vs {fb.size})"
                lines.append(f"    {field:26s} {'identical' if same else 'different' + size}")
                continue
            r = _rel(fa, fb)
            same = np.array_equal(fa, fb, equal_nan=True)
            verdict = "identical" if same else "rounding" if r <= rtol else "different"
            lines.append(f"    {field:26s} {verdict}" + ("" if verdict == "identical" else f" max rel {r:.3g}"))
    lines += [f"  point {key}: only in new" for key in sorted(set(b) - set(a))]
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--rtol", type=float, default=1e-9, help="relative difference still called rounding")
    ap.add_argument("--ignore", default=IGNORE, help="regex of column names to skip (wall times)")
    ap.add_argument("--points", action="store_true", help="also compare the sweep caches point by point")
    args = ap.parse_args(argv)
    olds = sorted(p for p in args.old.rglob("*.csv") if "cache" not in p.relative_to(args.old).parts)
    if not olds:
        raise SystemExit(f"no CSV under {args.old}")
    for p in olds:
        q = args.new / p.relative_to(args.old)
        if not q.exists():
            print(f"{p.relative_to(args.old)}: MISSING in {args.new}")
            continue
        print("\n".join(compare_files(p, q, args.rtol, args.ignore)))
    news = {p.relative_to(args.new) for p in args.new.rglob("*.csv") if "cache" not in p.relative_to(args.new).parts}
    for extra in sorted(news - {p.relative_to(args.old) for p in olds}):
        print(f"{extra}: only in {args.new}")
    if args.points:
        for folder in sorted(args.old.glob("cache/*")):
            if (args.new / "cache" / folder.name).is_dir():
                print("\n".join(compare_points(folder, args.new / "cache" / folder.name, args.rtol, args.ignore)))


if __name__ == "__main__":
    main()
