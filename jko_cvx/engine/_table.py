"""The diagnostics records of a run (one dict per accepted step) as a table, without pandas.

A run keeps its diagnostics as the loop recorded them, a list of dicts; ``Run.diagnostics``
builds the :class:`pandas.DataFrame` on first use.  The default ``jko-cvx run`` never needs the
table: it writes ``diagnostics.csv`` and reads columns for its figures and summary through the
two functions here, which give what pandas gives (tested against it, bit for bit) for the
records the loop writes (numbers and missing values), and hand any other record to pandas.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["column", "csv_text", "unknown_column"]

_PLAIN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")  # a header cell pandas writes unquoted

Rows = Sequence[Mapping[str, Any]]


def _columns(rows: Rows) -> list[str]:
    """The keys of ``rows`` in order of first appearance (``pandas.DataFrame(rows).columns``)."""
    return list(dict.fromkeys(k for r in rows for k in r))


_INT64 = (-(2**63), 2**63)


def _is_int(x: Any) -> bool:
    """A Python int or NumPy int64 that int64 holds (pandas' int64 cell); not a bool, not another width."""
    return type(x) in (int, np.int64) and _INT64[0] <= x < _INT64[1]


def _kind(values: list[Any]) -> str | None:
    """``"int"`` (every value an int64 integer), ``"float"`` (float64 numbers, int64 integers and missing values
    None; not None alone), or None: anything else (booleans, text, other widths, integers beyond int64) is
    pandas' to decide."""
    if values and all(_is_int(x) for x in values):
        return "int"
    numbers = all(x is None or type(x) in (float, np.float64) or _is_int(x) for x in values)
    return "float" if numbers and any(x is not None for x in values) else None  # all None: pandas' object column


def _float_cell(x: Any) -> str:
    """A float as pandas writes it: empty for a missing value, else the shortest repr that reads back exactly."""
    if x is None:
        return ""
    x = float(x)
    return "" if math.isnan(x) else repr(x)


def csv_text(rows: Rows) -> str:
    """``pandas.DataFrame(rows).to_csv(index=False)``, written without pandas where the records are numbers.

    Columns of int64 integers (Python ``int``, ``numpy.int64``) as integers; columns of float64
    numbers (``float``, ``numpy.float64``, such integers) with missing values (None, NaN, an absent
    key) as floats, the missing cells empty.  A column of anything else (booleans, text, other
    widths, integers beyond int64, None alone), a single column, or a header that is not a plain
    name makes the whole table pandas' (imported then).
    """
    rows = list(rows)
    names = _columns(rows)
    cols = [[r.get(c) for r in rows] for c in names]
    kinds = [_kind(values) for values in cols]
    # one column: pandas quotes an empty cell (a blank line would read as no row)
    plain = len(names) > 1 and all(isinstance(c, str) and _PLAIN_NAME.fullmatch(c) for c in names)
    if not plain or None in kinds:
        import pandas as pd

        return pd.DataFrame(rows).to_csv(index=False)
    cells = [[str(int(x)) for x in values] if kind == "int" else [_float_cell(x) for x in values]
             for values, kind in zip(cols, kinds, strict=True)]  # fmt: skip
    lines = [",".join(names), *(",".join(row) for row in zip(*cells, strict=True))]
    return os.linesep.join(lines) + os.linesep


def unknown_column(name: str, names) -> KeyError:
    """The error for a diagnostics column ``name`` the table does not have, naming the ones it has."""
    return KeyError(f"no diagnostics column {name!r}; the columns are {', '.join(map(str, names))}")


def column(rows: Rows, name: str) -> np.ndarray:
    """``pandas.DataFrame(rows)[name].to_numpy()`` without pandas where the column holds numbers.

    int64 for a column of int64 integers, float64 (NaN for a missing value) for float64 numbers with
    such integers, as :func:`csv_text` decides; any other column is pandas'.  A name no record holds
    is refused, naming the columns there are.
    """
    rows = list(rows)
    names = _columns(rows)
    if name not in names:
        raise unknown_column(name, names)
    values = [r.get(name) for r in rows]
    kind = _kind(values)
    if kind == "int":
        return np.array([int(x) for x in values], dtype=np.int64)
    if kind == "float":
        return np.array([np.nan if x is None else float(x) for x in values], dtype=np.float64)
    import pandas as pd

    return pd.DataFrame(rows)[name].to_numpy()
