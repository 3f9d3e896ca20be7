"""The results pages are rendered from the result files, whole, with the provenance each records.

``docs/_ext/jko_results.py`` writes the pages at build time; here its renderer runs directly into
temporary directories (no Sphinx build: that is ``test_docs_build.py``'s), on the shipped
``studies/results`` and on small results directories written by the tests.
"""

from __future__ import annotations

import csv
import itertools
import re
import shutil
import sys
from pathlib import Path

import pytest

pytest.importorskip("tabulate")  # pandas.DataFrame.to_markdown

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
RESULTS = ROOT / "studies" / "results"
sys.path.insert(0, str(DOCS / "_ext"))
import jko_results as results  # noqa: E402

from jko_cvx.environment import environment_line, record_csv, write_markdown  # noqa: E402

Entry, Page = results.Entry, results.Page


@pytest.fixture(scope="module")
def shipped(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """The pages rendered from the shipped results: (output directory, page name -> Markdown)."""
    out = tmp_path_factory.mktemp("generated")
    results.write_pages(RESULTS, out)
    return out, {p.name: (out / f"{p.name}.md").read_text() for p in results.PAGES}


def _separator(line: str) -> bool:
    return re.fullmatch(r"\|(\s*:?-+:?\s*\|)+\s*", line) is not None


def _data_rows(lines: list[str]) -> list[str]:
    """The rows below the separator line of every Markdown table in ``lines``."""
    rows, inside = [], False
    for line in lines:
        if _separator(line):
            inside = True
        elif inside and line.startswith("|"):
            rows.append(line)
        else:
            inside = False
    return rows


def test_the_build_reads_this_checkouts_results():
    assert results.results_dir() == RESULTS


def test_every_listed_file_exists_and_appears_on_its_page(shipped):
    out, pages = shipped
    assert len(results.sources()) >= 90  # every page of the issue, each with its files
    for page in results.PAGES:
        for rel in page.files():
            assert (RESULTS / rel).is_file(), rel
            assert f"`studies/results/{rel}`" in pages[page.name], (page.name, rel)
        for entry in page.entries:
            for rel in (*entry.figures, *entry.data):
                assert (out / "files" / rel).read_bytes() == (RESULTS / rel).read_bytes(), rel
            for fig in entry.figures:
                assert f"```{{figure}} files/{fig}\n" in pages[page.name], fig


def test_every_report_table_row_and_every_table_column_is_on_the_page(shipped):
    """A report's data rows appear verbatim (up to escaped ``|``; rows with raw ``<`` are escaped, so left out); a
    printed CSV's column names and row count are those of the file."""
    _, pages = shipped
    for page in results.PAGES:
        text = pages[page.name]
        for entry in page.entries:
            path = RESULTS / entry.file
            if path.suffix == ".md":
                lines = path.read_text().splitlines()
                rows = _data_rows(lines)
                assert rows or "|" not in path.read_text(), entry.file
                flat = text.replace("\\|", "|")  # a '|' the report left unescaped in a cell is escaped
                missing = [r for r in rows if "<" not in r and r not in text and r not in flat]
                assert not missing, (entry.file, missing[:2])
            elif path.suffix == ".csv":
                with path.open(newline="") as fh:
                    header, *body = list(csv.reader(fh))
                section = text.split(f"`studies/results/{entry.file}`", 1)[1].split("\n## ", 1)[0]
                table = [s for s in section.splitlines() if s.startswith("|")]
                assert len(table) == len(body) + 2, entry.file
                for name in header:
                    assert name.replace("|", r"\|") in table[0], (entry.file, name)


def test_pages_have_one_title_and_consecutive_heading_levels(shipped):
    """MyST warns on a jump in heading levels (the build runs with -W); each page has one title."""
    _, pages = shipped
    for name, text in pages.items():
        levels = [len(m.group(1)) for m in re.finditer(r"^(#+) ", text, re.M)]
        assert levels[0] == 1 and levels.count(1) == 1, name
        jumps = [(a, b) for a, b in itertools.pairwise(levels) if b > a + 1]
        assert not jumps, (name, jumps)


def test_results_index_lists_every_page():
    text = (DOCS / "results" / "index.md").read_text()
    toctree = text.split("```{toctree}", 1)[1].split("```", 1)[0]
    entries = [s.strip() for s in toctree.splitlines() if s.strip() and not s.startswith(":")]
    assert entries == [f"generated/{p.name}" for p in results.PAGES]
    assert "results/index" in (DOCS / "index.md").read_text()


def test_environment_lines_of_the_shipped_reports_appear(shipped):
    """Reports written by jko_cvx.environment.write_markdown carry the environment under the title."""
    _, pages = shipped
    seen = 0
    for page in results.PAGES:
        for entry in page.entries:
            if entry.file.endswith(".md"):
                for line in (RESULTS / entry.file).read_text().splitlines()[:5]:
                    if line.startswith("*Environment:"):
                        seen += 1
                        assert f"`studies/results/{entry.file}`: {line}" in pages[page.name], entry.file
    assert seen >= 5  # tab_bu, tab_bu_tb2, tab_g2bu_control, discrimination, conclusions


# ---- small results directories written here ------------------------------------------------------

ENV = {
    "jko_cvx": "9.9.9",
    "git_commit": "feedc0ffee0123456789abcdef0123456789abcd",
    "jko_cvx_modified": False,
    "python": "3.11.0",
    "numpy": "2.0.0",
    "machine": "Linux test x86_64",
    "cpu_count": 2,
    "blas": [{"internal_api": "openblas", "version": "0.3.0", "architecture": "Haswell", "num_threads": 1}],
}


def _write_results(folder: Path) -> Page:
    """A results directory of each kind of file, and the page that renders it."""
    write_markdown(folder / "env_report.md", "# Env report\n\n| a | b |\n|--:|--:|\n| 1 | 2.5 |\n", env=ENV)
    (folder / "line_report.md").write_text(
        "# Line report\n\nmeasured 2031-01-02 03:04 UTC, code 0123456789ab; OPENBLAS_NUM_THREADS=1\n\n"
        "## Part\n\n#### Deep part\n\n| x |\n|--:|\n| 7 |\n"
    )
    (folder / "bare_report.md").write_text(
        "# Bare report\n\nNo record of when.\n\n| x | y |\n|:--|--:|\n| u<v | 3 |\n\n"
        "| case | median |x - y| |\n|:--|--:|\n| a | 0.5 |\n"
    )
    (folder / "no_commit.md").write_text("# No commit\n\nmeasured 2031-05-06, one BLAS thread\n")
    (folder / "mixed.md").write_text(
        "# Mixed\n\nCases: one bump. Measured on one BLAS\nthread, 2031-02-03. More text.\n\n| x |\n|--:|\n| 1 |\n"
    )
    (folder / "table.csv").write_text("what,value\nalpha,1.25\nbeta|gamma,2.5\n")
    (folder / "columns.csv").write_text("date,commit,threads,value\n2031-01-01 10:00,abc1234,1,3.5\n")
    (folder / "recorded.csv").write_text("value\n4.5\n")
    record_csv(folder / "recorded.csv", env=ENV)
    (folder / "record.json").write_text(
        '{"t": 0.5, "code": {"git_commit": "0badcafe0badcafe", "jko_cvx_modified": true}}'
    )
    shutil.copy(RESULTS / "cost_growth.png", folder / "figure.png")
    return Page(
        "test",
        "Test page",
        "Every kind of file.",
        (
            Entry("env_report.md", figures=("figure.png",), data=("recorded.csv",)),
            Entry("line_report.md"),
            Entry("bare_report.md", data=("table.csv",)),
            Entry("no_commit.md"),
            Entry("mixed.md"),
            Entry("table.csv", title="A table"),
            Entry("columns.csv", title="Columns"),
            Entry("record.json", title="A record"),
        ),
    )


def _render(folder: Path, page: Page, out: Path) -> str:
    results.write_pages(folder, out, pages=(page,))
    return (out / "test.md").read_text()


def _provenance(text: str, rel: str) -> str:
    (line,) = [s for s in text.splitlines() if s.startswith(f"> **Provenance** of `studies/results/{rel}`")]
    return line


def test_provenance_each_file_records_and_not_recorded_where_none(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    page = _write_results(folder)
    text = _render(folder, page, tmp_path / "out")

    assert environment_line(ENV) in _provenance(text, "env_report.md")
    assert "feedc0ffee01" in environment_line(ENV)
    line = "measured 2031-01-02 03:04 UTC, code 0123456789ab; OPENBLAS_NUM_THREADS=1"
    assert _provenance(text, "line_report.md").endswith(f": {line}.")
    assert text.count(line) == 1  # moved into the provenance block, not repeated in the body
    assert _provenance(text, "bare_report.md").endswith(f": {results.NOT_RECORDED}")
    assert _provenance(text, "no_commit.md").endswith("It records no code commit.")
    mixed = _provenance(text, "mixed.md")  # the sentences that record, the paragraph left whole
    assert mixed.endswith(": Measured on one BLAS thread, 2031-02-03. It records no code commit.")
    assert "Cases: one bump. Measured on one BLAS\nthread, 2031-02-03. More text." in text
    assert _provenance(text, "table.csv").endswith(f": {results.NOT_RECORDED}")
    cols = _provenance(text, "columns.csv")
    assert "`2031-01-01 10:00`" in cols and "`abc1234`" in cols and "It records no" not in cols
    json_line = _provenance(text, "record.json")
    assert "0badcafe0badcafe" in json_line and "It records no date and no thread setting." in json_line
    recorded = [
        s
        for s in text.splitlines()
        if "- `studies/results/recorded.csv` (1 rows, 1 columns; {download}`download <files/recorded.csv>`)" in s
    ]
    assert len(recorded) == 1 and environment_line(ENV) in recorded[0] and "written 20" in recorded[0]
    caption = text.split("```{figure} files/figure.png", 1)[1].split("```", 1)[0]
    assert "`studies/results/figure.png`" in caption and results.NOT_RECORDED in caption


def test_report_rendering_escapes_and_shifts(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    text = _render(folder, _write_results(folder), tmp_path / "out")
    assert "## Line report\n" in text and "### Part\n" in text and "#### Deep part\n" in text
    assert r"| u\<v | 3 |" in text  # raw '<' would be read as HTML
    assert r"beta\|gamma" in text  # a '|' in a CSV cell would split the row
    assert r"| case | median \|x - y\| |" in text  # so does one a report left unescaped


def test_a_changed_value_changes_the_page(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    page = _write_results(folder)
    before = _render(folder, page, tmp_path / "out")
    assert "98765.4" not in before and "| 2.5 |" in before
    (folder / "table.csv").write_text("what,value\nalpha,1.25\nbeta|gamma,98765.4\n")
    (folder / "env_report.md").write_text((folder / "env_report.md").read_text().replace("| 1 | 2.5 |", "| 1 | 31.5 |"))
    after = _render(folder, page, tmp_path / "out")
    assert "98765.4" in after and "| 1 | 31.5 |" in after and "| 1 | 2.5 |" not in after


def test_a_changed_shipped_csv_changes_its_page(tmp_path):
    """The same on a copy of a shipped table: the page follows the file, not a typed copy."""
    name = "bench_verify_conic.csv"
    (page,) = [p for p in results.PAGES if name in p.files()]
    folder = tmp_path / "results"
    for rel in page.files():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(RESULTS / rel, folder / rel)
    with (folder / name).open(newline="") as fh:
        rows = list(csv.reader(fh))
    col = rows[0].index("median_s")
    rows[1][col] = "4242.125"
    with (folder / name).open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    results.write_pages(folder, tmp_path / "out", pages=(page,))
    assert "4242.12" in (tmp_path / "out" / f"{page.name}.md").read_text()


def test_a_missing_file_fails_naming_it_and_stale_files_go(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    page = _write_results(folder)
    out = tmp_path / "out"
    (out / "files").mkdir(parents=True)
    (out / "old_page.md").write_text("# Old\n")
    (out / "files" / "old.png").write_bytes(b"")
    _render(folder, page, out)
    assert sorted(p.name for p in out.rglob("*") if p.is_file()) == [
        "figure.png",
        "recorded.csv",
        "table.csv",
        "test.md",
    ]
    (folder / "table.csv").unlink()
    with pytest.raises(FileNotFoundError, match=r"table\.csv"):
        results.write_pages(folder, out, pages=(page,))


def test_every_result_file_is_on_a_page_or_set_aside_with_a_reason():
    """A new result file shows up in the docs, or its omission is stated (``UNSHOWN``)."""
    shown = set(results.sources())
    files = {
        p.relative_to(RESULTS).as_posix() for d in (RESULTS, RESULTS / "reproduce") for p in d.iterdir() if p.is_file()
    }
    assert not files - shown - set(results.UNSHOWN), sorted(files - shown - set(results.UNSHOWN))
    assert set(results.UNSHOWN) <= files and not set(results.UNSHOWN) & shown
