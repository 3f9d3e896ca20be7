"""Regenerate ``studies/results/reproduce/summary.md``: the pages' quoted numbers, from the result files.

The pages: ``studies/README.md`` and the documentation's guides, ``docs/guides/*.md``.

The claims live with the tests (``tests/readme_claims.py``, checked by ``tests/docs/test_quoted_numbers.py``);
this script writes their values into ``summary.md`` in the results directory they read.

Run: ``python studies/readme_claims.py [--results DIR]`` (default: ``studies/results/reproduce``; a
directory laid out like it, with the study scripts' files in its parent).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=ROOT / "studies" / "results" / "reproduce")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))  # the claims are a module of the tests package
    from tests.readme_claims import write_summary

    write_summary(args.results)
    print(f"wrote {args.results / 'summary.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
