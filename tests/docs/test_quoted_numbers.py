"""Every number studies/README.md quotes comes from a shipped result file (``jko_cvx.studies.reproduce.summary``)."""

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jko_cvx.studies.reproduce.summary import CLAIMS, RESULTS, claim_values, reproduce_summary, within

ROOT = Path(__file__).resolve().parents[2]


def _normalise(text: str) -> str:
    return re.sub(r"\s+", " ", text)


@pytest.fixture(scope="module")
def values():
    return claim_values(RESULTS)


@pytest.mark.parametrize("claim", CLAIMS, ids=lambda c: c.key)
def test_the_readme_quotes_the_result_files(claim, values):
    readme = _normalise((ROOT / claim.readme).read_text())
    quote = _normalise(claim.quote.format(*values[claim.key]))
    assert quote in readme, f"{claim.readme} should say: {quote!r} (from {claim.file})"


def test_the_shipped_summary_is_current(tmp_path):
    out = tmp_path / "results" / "reproduce"  # the shipped layout: some files sit one level up
    out.mkdir(parents=True)
    for c in {c.file for c in CLAIMS}:
        (out / c).write_bytes((RESULTS / c).read_bytes())
    reproduce_summary(out)
    assert (out / "summary.md").read_text() == (RESULTS / "summary.md").read_text()


def test_tolerance_counts_an_entry_at_the_printed_tolerance_as_within():
    df = pd.DataFrame({"T_b": [0.2725000000000002, 0.2950000000000002, np.nan], "paper": [0.2425, 0.2475, 0.28]})
    assert within(df, 0.03).tolist() == [True, False, False]
