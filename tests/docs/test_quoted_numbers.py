"""Every number studies/README.md and docs/guides quote comes from a shipped result file (``tests/readme_claims.py``),
and each claim reads exactly the files it declares, from the directory it is given."""

import builtins
import io
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ..readme_claims import CLAIMS, claim_values, within, write_summary

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "studies" / "results" / "reproduce"


def _normalise(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def _copy(files, tmp_path: Path) -> Path:
    """``files`` (relative to the shipped ``reproduce`` directory) copied into the same layout under tmp_path."""
    out = tmp_path / "results" / "reproduce"
    out.mkdir(parents=True)
    for name in files:
        (out / name).write_bytes((SHIPPED / name).read_bytes())
    return out


@pytest.fixture(scope="module")
def values():
    return claim_values(SHIPPED)


@pytest.mark.parametrize("claim", CLAIMS, ids=lambda c: c.key)
def test_the_readme_quotes_the_result_files(claim, values):
    readme = _normalise((ROOT / claim.readme).read_text())
    quote = _normalise(claim.quote.format(*values[claim.key]))
    assert quote in readme, f"{claim.readme} should say: {quote!r} (from {', '.join(claim.files)})"


def test_the_shipped_summary_is_current(tmp_path):
    out = _copy({name for c in CLAIMS for name in c.files}, tmp_path)  # the shipped layout: some files one level up
    write_summary(out)
    assert (out / "summary.md").read_text() == (SHIPPED / "summary.md").read_text()


def test_tolerance_counts_an_entry_at_the_printed_tolerance_as_within():
    df = pd.DataFrame({"T_b": [0.2725000000000002, 0.2950000000000002, np.nan], "paper": [0.2425, 0.2475, 0.28]})
    assert within(df, 0.03).tolist() == [True, False, False]


@pytest.mark.parametrize(
    ("key", "name", "column", "change"),
    [
        ("tab_g2bu.tridiagonal_fix", "tab_g2bu.csv", "max_f", lambda x: 2 * x),
        ("inhom_gamma1p5.rounding", "inhom_gamma1p5_resolution.csv", "t(sigma_v < 0.05)", lambda x: x + 0.5),
    ],
)
def test_a_claim_comparing_two_files_reads_both_from_the_given_directory(key, name, column, change, tmp_path):
    (claim,) = (c for c in CLAIMS if c.key == key)
    assert name in claim.files
    out = _copy(claim.files, tmp_path)
    d = pd.read_csv(out / name)
    d[column] = change(d[column])
    d.to_csv(out / name, index=False)
    assert claim_values(out, [claim])[key] != claim_values(SHIPPED, [claim])[key]


def test_every_claim_reads_exactly_the_files_it_declares(monkeypatch, tmp_path):
    """Each claim computed in a directory holding only its declared files, every file opened recorded."""
    opened: list[Path] = []
    real_open = builtins.open

    def recording_open(file, *args, **kwargs):
        if isinstance(file, (str, Path)):
            opened.append(Path(file).resolve())
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", recording_open)
    monkeypatch.setattr(io, "open", recording_open)
    for i, claim in enumerate(CLAIMS):
        out = _copy(claim.files, tmp_path / str(i))
        opened.clear()
        claim_values(out, [claim])
        assert set(opened) == {(out / name).resolve() for name in claim.files}, claim.key
    assert all(not Path(name).is_absolute() for c in CLAIMS for name in c.files)
