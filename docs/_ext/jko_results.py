"""The results pages, generated at build time from the files in ``studies/results/``.

Nothing on these pages is typed: at ``builder-inited`` :func:`write_pages` renders every page of
:data:`PAGES` into ``docs/results/generated/`` (ignored by git) from the result files themselves:

* a Markdown report (``.md``) is copied in, its headings moved one level down under the page's
  title (levels made consecutive) and raw ``<`` escaped, so that MyST renders it without warnings;
* a CSV table (``.csv``) is rendered with :meth:`pandas.DataFrame.to_markdown`;
* a JSON record (``.json``) is shown as a code block;
* a figure (``.png``) is copied beside the pages and shown with a caption naming its file;
* a data file (a CSV behind a report, too long to print) is listed with its size and a download link.

Each file comes with the provenance it records itself (:func:`provenance`): the report's own
environment/date/commit/threads sentences, the ``environment.json`` entry
:func:`jko_cvx.environment.record_csv` wrote beside it, the CSV's own ``date``/``commit``/``threads``
columns or the JSON record's ``code`` entry, followed by what that record lacks.  A file that
records none says so: "provenance not recorded in this file".  A file named in :data:`PAGES` but
missing from ``studies/results/`` fails the build; :data:`UNSHOWN` names the files no page renders.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

NOT_RECORDED = "provenance not recorded in this file"
"""What a page says of a file that records no date, commit, thread setting or environment."""

GENERATED = Path("results") / "generated"
"""Where the pages go, relative to the documentation's source directory."""

FILES = "files"
"""The folder beside the pages holding the copied figures and data files."""


@dataclass(frozen=True)
class Entry:
    """One section of a results page: a report, table or record, with its figures and data files.

    Paths are relative to the results directory (``studies/results``).
    """

    file: str
    """A Markdown report (``.md``), a CSV table to print (``.csv``) or a JSON record (``.json``)."""
    figures: tuple[str, ...] = ()
    """PNG figures shown under the entry's heading."""
    data: tuple[str, ...] = ()
    """CSV files behind the entry, listed with their provenance and a download link."""
    title: str | None = None
    """The section heading of a table or record (a report's heading is its own first line)."""

    def files(self) -> tuple[str, ...]:
        return (self.file, *self.figures, *self.data)


@dataclass(frozen=True)
class Page:
    """One generated page: ``results/generated/<name>.md``."""

    name: str
    title: str
    intro: str
    entries: tuple[Entry, ...]

    def files(self) -> tuple[str, ...]:
        return tuple(f for e in self.entries for f in e.files())


R = "reproduce/"

PAGES: tuple[Page, ...] = (
    Page(
        "solvers",
        "Solver comparison",
        "One collision step solved by each method (conic reference, the paper's SQP, Newton, IPOPT), "
        "against the grid size and the Fisher weight, as `studies/bench_collision.py` and "
        "`studies/bench_newton.py` measured them.",
        (
            Entry("bench_collision.md", data=("bench_collision.csv",)),
            Entry("bench_newton.csv", title="Newton against the conic reference and the SQP, per Fisher weight"),
            Entry("bench_newton_growth.csv", title="Newton per solve against N"),
            Entry("bench_newton_batch.csv", title="Batched Newton against one slice at a time"),
            Entry("bench_newton_sqp.csv", title="Newton (NumPy and compiled) against the paper's SQP"),
            Entry("newton_single_path.md"),
            Entry("newton_certification.md", data=("newton_certification.csv",)),
            Entry("certificate_weights.md", data=("certificate_weights.csv", "certificate_weights_run.csv")),
            Entry("newton_single_call.md", data=("newton_single_call.csv",)),
            Entry("bench_cost_model.md", data=("bench_cost_model.csv",)),
            Entry("bench_cli_run.md", data=("bench_cli_run.csv",)),
            Entry("bench_newton_cascade.md", data=("bench_newton_cascade.csv",)),
            Entry("conic_defaults.md", data=("conic_defaults.csv",)),
            Entry("extremes.md", data=("extremes.csv",)),
            Entry("reference_certification.md", data=("reference_certification.csv",)),
            Entry("conic_scene_runs.md", data=("conic_scene_runs.csv", "conic_scene_runs_failed_slices.csv",
                                               "conic_scene_runs_verify.csv", "conic_scene_runs_minima.csv")),
            Entry("bench_second_start.md", data=("bench_second_start.csv",)),
        ),
    ),
    Page(
        "work_precision",
        "Work-precision",
        "Error against cost: one collision step against a tight reference, whole homogeneous runs "
        "against the exact solutions, and the JKO methods against a finite-volume peer.",
        (
            Entry("work_precision_step.md", figures=("work_precision_step.png",), data=("work_precision_step.csv",)),
            Entry(
                "work_precision_run.md",
                figures=("work_precision_run.png", "work_precision_run_bias.png"),
                data=("work_precision_run.csv",),
            ),
            Entry(
                "work_precision_peer.md",
                figures=("work_precision_peer.png", "work_precision_peer_time_order.png"),
                data=("work_precision_peer.csv", "work_precision_peer_time_order.csv"),
            ),
            Entry("strang_self_convergence.md", data=("strang_self_convergence.csv",)),
        ),
    ),
    Page(
        "scale",
        "Scale and threads",
        "The batched Newton solver and the inhomogeneous time step against the grid size, the BLAS "
        "thread setting and the machine's load.",
        (
            Entry("bench_scale.md", data=("bench_scale_newton.csv", "bench_scale_step.csv")),
            Entry("bench_scale_gamma4.md", data=("bench_scale_gamma4_newton.csv",)),
            Entry("bench_scale_loaded.md", data=("bench_scale_loaded_newton.csv", "bench_scale_loaded_step.csv")),
            Entry("bench_scale_ab.csv", title="Scale A/B runs of two commits, side by side"),
            Entry("bench_chained_structured.md", data=("bench_chained_structured.csv",)),
            Entry("bench_threads.md", data=("bench_threads.csv",)),
            Entry("bench_slice_threads.md", data=("bench_slice_threads.csv",)),
            Entry(
                "cost_growth.md",
                figures=("cost_growth.png",),
                data=("cost_growth_step.csv", "cost_growth_time_step.csv"),
            ),
            Entry("cost_growth_exponents.csv", title="Cost growth: fitted exponents"),
            Entry("cost_growth_batch.csv", title="Cost growth: batched against one-at-a-time Newton"),
            Entry("bench_crawl.md", data=("bench_crawl.csv",)),
        ),
    ),
    Page(
        "reproduce_tables",
        "The paper's tables, reproduced",
        "The blow-up tables of the paper (tab:bu, tab:bu_tb2, tab:g2bu) rerun by `jko-cvx reproduce`, "
        "each entry beside the paper's number, the controls of its blow-up criteria (across the "
        "tab:g2bu threshold, and across gamma = 2 where the homogeneous theory forbids blow-up), and the "
        "Fisher-weight scan behind tab:bu.",
        (
            Entry(R + "tab_bu.md", figures=(R + "tab_bu.png",), data=(R + "tab_bu.csv",)),
            Entry(R + "tab_bu_tb2.md", figures=(R + "tab_bu_tb2.png",), data=(R + "tab_bu_tb2.csv",)),
            Entry(
                R + "tab_g2bu.md",
                figures=(R + "tab_g2bu.png", R + "tab_g2bu_snapshots.png"),
                data=(R + "tab_g2bu.csv", R + "tab_g2bu_previous_code.csv"),
            ),
            Entry(R + "tab_g2bu_control.md", data=(R + "tab_g2bu_control.csv",)),
            Entry(
                R + "criterion_control.md",
                figures=(R + "criterion_control.png",),
                data=(R + "criterion_control.csv",),
            ),
            Entry(R + "tab_bu_beta_scan.md", data=(R + "tab_bu_beta_scan.csv",)),
            Entry(R + "tab_bu_beta_scan_summary.csv", title="tab:bu against beta: summary"),
            Entry(R + "tab_bu_traces.md", data=(R + "tab_bu_traces.csv",)),
        ),
    ),
    Page(
        "reproduce_conclusions",
        "The paper's conclusions against our files",
        "What the blow-up tables' agreement is worth (a trivial answer scored the same way), and "
        "every conclusion of the paper's numerical sections against the evidence files.",
        (
            Entry(R + "discrimination.md", data=(R + "discrimination.csv",)),
            Entry(R + "conclusions.md", data=(R + "conclusions.csv",)),
        ),
    ),
    Page(
        "reproduce_sections",
        "The paper's figures and sections, reproduced",
        "The other experiments of the paper rerun by `jko-cvx reproduce`: the explicit solutions, the "
        "homogeneous and inhomogeneous runs behind its figures, the mesh maps and the Fisher weight.",
        (
            Entry(R + "explicit.md", figures=(R + "explicit.png",), data=(R + "explicit.csv",)),
            Entry(R + "explicit_figures.md", figures=(R + "explicit_figures.png",), data=(R + "explicit_figures.csv",)),
            Entry(
                R + "explicit2_sketch.md",
                figures=(R + "fig_explicit2_right.png",),
                data=(R + "explicit2_sketch.csv", R + "explicit2_sketch_curves.csv"),
            ),
            Entry(
                R + "gk1_records.md",
                figures=(R + "gk1_records.png", R + "gk1_adpt_tau.png"),
                data=(R + "gk1_records.csv",),
            ),
            Entry(R + "gk1_final.md", figures=(R + "gk1_final.png",), data=(R + "gk1_final.csv",)),
            Entry(
                R + "g2bu_records.md",
                figures=(R + "g2bu_records.png", R + "g2bu_loglog.png"),
                data=(R + "g2bu_records.csv",),
            ),
            Entry(R + "gk2_bu.md", figures=(R + "fig_gk2_bu.png",), data=(R + "gk2_bu.csv",)),
            Entry(
                R + "gk3_panels.md",
                figures=(
                    R + "fig_gk3_ih_2_C2_2.png",
                    R + "fig_gk3_ih_2_C2.png",
                    R + "fig_gk3_ih_2_C5_2.png",
                    R + "fig_gk3_ih_2_C5.png",
                ),
                data=(R + "gk3_panels.csv", R + "gk3_panels_records.csv"),
            ),
            Entry(R + "ibu.md", figures=(R + "ibu.png",), data=(R + "ibu.csv",)),
            Entry(R + "ibu_panels.md", figures=(R + "ibu_panels.png",), data=(R + "ibu_panels.csv",)),
            Entry(
                R + "inhom_gamma1p5.md",
                figures=(
                    R + "inhom_gamma1p5.png",
                    R + "inhom_gamma1p5_properties.png",
                    R + "inhom_gamma1p5_resolution.png",
                ),
                data=(
                    R + "inhom_gamma1p5.csv",
                    R + "inhom_gamma1p5_resolution.csv",
                    R + "inhom_gamma1p5_resolution_previous_code.csv",
                    R + "inhom_gamma1p5_properties.csv",
                ),
            ),
            Entry(
                R + "inhom_gamma1p5_events.md",
                figures=(R + "inhom_gamma1p5_events.png",),
                data=(R + "inhom_gamma1p5_events.csv",),
            ),
            Entry(
                R + "inhom_gamma3.md",
                figures=(R + "inhom_gamma3.png", R + "inhom_gamma3_properties.png", R + "inhom_gamma3_snapshots.png"),
                data=(R + "inhom_gamma3.csv",),
            ),
            Entry(
                R + "mesh_maps.md",
                figures=(R + "fig_mr_demon.png", R + "fig_mr_demon_mu2.png"),
                data=(R + "mesh_maps.csv",),
            ),
            Entry(R + "fisher_width.md", data=(R + "fisher_width.csv",)),
            Entry(R + "paper_variants.md", data=(R + "paper_variants.csv",)),
            Entry(R + "paper_variants_concentration.md", data=(R + "paper_variants_concentration.csv",)),
            Entry(R + "property_budget.md", data=(R + "property_budget.csv", R + "property_budget_summary.csv")),
        ),
    ),
    Page(
        "grid_convergence",
        "Grid convergence",
        "Two of the paper's inhomogeneous experiments rerun on successively refined grids, and the "
        "records of the runs that first failed at 481 x 481.",
        (
            Entry(R + "grid_convergence.md", figures=(R + "grid_convergence.png",), data=(R + "grid_convergence.csv",)),
            Entry(R + "grid_convergence_gamma1p5.csv", title="gamma = 3/2: convergence per quantity"),
            Entry(R + "grid_convergence_g2bu.csv", title="tab:g2bu over N_v"),
            Entry("grid_convergence_failure.json", title="The 481 x 481 run that stops at the density's collapse"),
            Entry("grid_convergence_failure_no_floor.json", title="The same run without the floor every step"),
            Entry("grid_convergence_failure_before_fix.json", title="The same run before the fix"),
            Entry(R + "g3_dt_probe.md", figures=(R + "g3_dt_probe.png",), data=(R + "g3_dt_probe.csv",)),
        ),
    ),
    Page(
        "blowup_fit",
        "Blow-up estimator validation",
        "The blow-up-time estimator of {mod}`jko_cvx.blowup` against the exact times of homogeneous "
        "gamma = 1 runs, its classification against the Osgood criterion, and the first-order step's lag "
        "its bar holds off gamma = 1.",
        (
            Entry("blowup_fit_validation.md", data=("blowup_fit_validation.csv",)),
            Entry("blowup_fit_validation_osgood.csv", title="Osgood criterion: finite-time or not, per gamma and dt"),
            Entry(
                "blowup_fit_convergence.md",
                figures=("blowup_fit_convergence.png",),
                data=("blowup_fit_convergence.csv",),
            ),
            Entry("first_order_lag.md", data=("first_order_lag.csv",)),
        ),
    ),
    Page(
        "verify",
        "Verify benchmark",
        "What `jko-cvx verify` costs beside the run it checks, the conic reference against N, and its "
        "DC splits (eigen, truncated) side by side.",
        (
            Entry("bench_verify.md", data=("bench_verify.csv",)),
            Entry("bench_verify_conic.csv", title="One conic solve at gamma = 3 against N"),
            Entry("bench_conic_split.md", data=("bench_conic_split.csv", "bench_conic_split_verify.csv")),
            Entry("conic_truncated_split.md", data=("conic_truncated_split.csv",)),
        ),
    ),
    Page(
        "misuse",
        "Misuse probes",
        "Every class of bad input the probes try, through the Python API and through scene files and "
        "the CLI, with the error each now raises.",
        (
            Entry("misuse_api.md", data=("misuse_api.csv",)),
            Entry("misuse_scene_cli.md", data=("misuse_scene_cli.csv",)),
        ),
    ),
    Page(
        "checks",
        "Checks of the tests and of the result files",
        "How many one-line mutations of the package the tests catch, how long regenerating the "
        "numerical section takes, what changed in the reproductions across a round of changes, and "
        "the numbers studies/README.md and the guides quote, computed from the result files.",
        (
            Entry("mutation.md", data=("mutation.csv", "mutation_round2_first_run.csv")),
            Entry(
                "regenerate_timing.md",
                data=("regenerate_timing.csv", "regenerate_timing_2026-12-02T0620.csv"),
            ),
            Entry(
                "regenerate_timing_section.md",
                data=(
                    "regenerate_timing_section.csv",
                    "regenerate_timing_section_2026-12-02T0549.csv",
                    "regenerate_timing_section_2026-12-02T0753.csv",
                ),
            ),
            Entry(R + "section.md", data=(R + "section.csv",)),
            Entry("ab_entry.csv", title="One reproduction entry timed on two commits, alternating"),
            Entry("reproduce_unchanged.md"),
            Entry(R + "summary.md"),
        ),
    ),
)
"""Every results page and the files it renders, in the order of the results index."""


UNSHOWN: dict[str, str] = {
    R + "environment.json": "read for the provenance of the files beside it",
    "environment.json": "read for the provenance of the files beside it",
    "regenerate_timing_2026-12-02T0620.md": "an earlier run of regenerate_timing.md (its CSV is listed)",
    "regenerate_timing_section_2026-12-02T0549.md": "an earlier run of the section timing (its CSV is listed)",
    "regenerate_timing_section_2026-12-02T0753.md": "an earlier run of the section timing (its CSV is listed)",
}
"""Files of ``studies/results`` and ``studies/results/reproduce`` no page renders, and why."""


def sources(pages: tuple[Page, ...] = PAGES) -> list[str]:
    """Every result file the pages render, relative to the results directory."""
    return list(dict.fromkeys(f for p in pages for f in p.files()))


# ---- provenance -----------------------------------------------------------------------------------

_DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
_COMMIT = re.compile(r"\b(?:commit|code|git|tree):?\s+(?:git\s+|main at\s+)?[0-9a-f]{7,40}\b", re.I)
_THREADS = re.compile(r"thread", re.I)
_THREAD_SETTING = re.compile(r"\b[A-Z_]*NUM_THREADS\b|\bBLAS\s+threads?\b|thread environment|slice threads", re.I)
_RECORDED = re.compile("|".join([r"\*Environment:", _DATE.pattern, _COMMIT.pattern, _THREAD_SETTING.pattern]), re.I)
_SENTENCE_END = re.compile(r"(?<=\.)\s+(?=[A-Z`*(])")
PROVENANCE_COLUMNS = ("date", "finished", "commit", "threads", "provenance")
"""CSV columns that record when, with which code or which thread setting a row was computed."""


def _sentence(text: str, searched: str | None = None, **known: bool) -> str:
    """``text`` as a sentence, then what ``searched`` (default ``text``) does not name.

    Named or not: a date, a code commit, a thread setting; ``known`` (keys ``date``, ``commit``,
    ``threads``) marks those recorded otherwise (a CSV column of that name).
    """
    searched = text if searched is None else searched
    missing = [
        what
        for key, what, pattern in (
            ("date", "date", _DATE),
            ("commit", "code commit", _COMMIT),
            ("threads", "thread setting", _THREADS),
        )
        if not known.get(key) and not pattern.search(searched)
    ]
    text = text.rstrip()
    text += "" if text.endswith((".", ".*")) else "."
    return text + (f" It records no {' and no '.join(missing)}." if missing else "")


def _report_provenance(lines: list[str]) -> tuple[tuple[int, int], str] | None:
    """Where a report records its provenance, and what it says.

    The first prose paragraph (not a heading or table) naming a date, a commit, a thread
    setting or the environment: its line span ``[start, stop)`` and the sentences of it that
    name one; ``None`` if no paragraph does.
    """
    prose = [bool(s.strip()) and not s.startswith(("#", "|")) for s in lines]
    start = 0
    while start < len(lines):
        if not prose[start]:
            start += 1
            continue
        stop = start + 1
        while stop < len(lines) and prose[stop]:
            stop += 1
        paragraph = " ".join(s.strip() for s in lines[start:stop])  # a phrase may wrap across lines
        if _RECORDED.search(paragraph):
            return (start, stop), " ".join(t for t in _SENTENCE_END.split(paragraph) if _RECORDED.search(t))
        start = stop
    return None


def _environment_record(path: Path) -> dict[str, Any] | None:
    """The ``environment.json`` entry :func:`jko_cvx.environment.record_csv` wrote for ``path``, if any."""
    record = path.parent / "environment.json"
    if not record.is_file():
        return None
    return json.loads(record.read_text()).get(path.name)


def _distinct(values: list[str], most: int = 4) -> str:
    seen = list(dict.fromkeys(values))
    shown = ", ".join(f"`{v}`" for v in seen[:most])
    return shown + (f" and {len(seen) - most} more" if len(seen) > most else "")


def provenance(path: Path) -> str:
    """The provenance ``path`` records, as one Markdown sentence; :data:`NOT_RECORDED` when none.

    Read from (the first that applies): the ``environment.json`` entry beside the file; for a
    report, the sentences of its first paragraph that name a date, a commit, a thread setting or
    the environment (:func:`jko_cvx.environment.write_markdown` puts the environment line under
    the title); a CSV's :data:`PROVENANCE_COLUMNS`; a JSON record's ``code`` entry.  What the
    record does not name of the date, the commit and the thread setting is said after it.
    """
    from jko_cvx.environment import environment_line

    entry = _environment_record(path)
    if entry is not None:
        return f"written {entry['written']}; {environment_line(entry['environment'])}"
    if path.suffix == ".md":
        lines = path.read_text().splitlines()
        found = _report_provenance(lines)
        return NOT_RECORDED if found is None else _sentence(found[1])
    if path.suffix == ".csv":
        import pandas as pd

        frame = pd.read_csv(path, dtype=str, keep_default_na=False)
        cols = [c for c in frame.columns if c.strip().lower() in PROVENANCE_COLUMNS]
        if not cols:
            return NOT_RECORDED
        names = {c.strip().lower() for c in cols}
        return _sentence(
            "; ".join(f"column `{c}`: {_distinct(list(frame[c]))}" for c in cols),
            " ".join(" ".join(frame[c]) for c in cols),
            date=bool(names & {"date", "finished"}),
            commit="commit" in names,
            threads="threads" in names,
        )
    if path.suffix == ".json":
        code = json.loads(path.read_text()).get("code")
        if not isinstance(code, dict) or not code.get("git_commit"):
            return NOT_RECORDED
        return _sentence(f"code git {code['git_commit']} (jko_cvx modified: {code.get('jko_cvx_modified')})")
    return NOT_RECORDED


def _provenance_block(results: Path, rel: str) -> list[str]:
    return [f"> **Provenance** of `studies/results/{rel}`: {provenance(results / rel)}", ""]


# ---- rendering ------------------------------------------------------------------------------------

_CODE_SPAN = re.compile(r"(`+)(.+?)\1")


def _escape_html(line: str) -> str:
    """``<`` outside code spans escaped, so that text like ``<object ...>`` is not read as raw HTML."""
    out, last = [], 0
    for m in _CODE_SPAN.finditer(line):
        out += [line[last : m.start()].replace("<", r"\<"), m.group(0)]
        last = m.end()
    return "".join([*out, line[last:].replace("<", r"\<")])


_SEPARATOR = re.compile(r"^\|(?:\s*:?-+:?\s*\|)+\s*$")


def _cells(row: str) -> int:
    return row.strip().strip("|").count("|") + 1


def _content_pipe(row: str, i: int) -> bool:
    """Whether the ``|`` at ``row[i]`` is cell text: a delimiter has a space (or the row's end) on both sides."""
    before = i == 0 or row[i - 1] == " "
    after = i + 1 == len(row) or row[i + 1] == " "
    return not (before and after)


def _repair_tables(lines: list[str]) -> list[str]:
    """Escape the ``|`` a report left unescaped in a cell (``median |x - y|``), which splits the row.

    Only rows with more cells than their table's separator line are touched.
    """
    out, width = list(lines), None
    for k, line in enumerate(lines):
        if not line.startswith("|"):
            width = None
            continue
        if width is None and k + 1 < len(lines) and _SEPARATOR.match(lines[k + 1]):
            width = _cells(lines[k + 1])
        if width is not None and not _SEPARATOR.match(line) and _cells(line) > width:
            row = line.rstrip()
            out[k] = "".join(r"\|" if c == "|" and _content_pipe(row, i) else c for i, c in enumerate(row))
    return out


def _report(path: Path) -> tuple[str, list[str], tuple[tuple[int, int], str] | None]:
    """(title, body lines, :func:`_report_provenance` of the body) of a Markdown report.

    The report's headings move under the section it gets on the page (``#`` becomes the section,
    ``##`` its ``###``...), each at most one level below the previous one (MyST warns on jumps).
    """
    lines = path.read_text().splitlines()
    title = path.name
    if lines and lines[0].startswith("# "):
        title, lines = lines[0][2:].strip(), lines[1:]
    body, level = [], 2
    for line in lines:
        m = re.match(r"^(#{1,6})\s+(.*)$", line)
        if m:
            level = min(len(m.group(1)) + 1, level + 1, 6)
            body.append(f"{'#' * level} {m.group(2)}")
        else:
            body.append(_escape_html(line))
    body = _repair_tables(body)
    return title, body, _report_provenance(body)


def _cell(value: Any) -> Any:
    return value.replace("|", r"\|").replace("<", r"\<") if isinstance(value, str) else value


def csv_table(path: Path) -> str:
    """The CSV file rendered as a Markdown table (every row, every column)."""
    import pandas as pd

    frame = pd.read_csv(path)
    frame.columns = [_cell(str(c)) for c in frame.columns]
    return frame.apply(lambda col: col.map(_cell)).to_markdown(index=False)


def _figure(rel: str, results: Path) -> list[str]:
    return [
        f"```{{figure}} {FILES}/{rel}",
        f":alt: {Path(rel).name}",
        "",
        f"`studies/results/{rel}`; {provenance(results / rel)}",
        "```",
        "",
    ]


def _data(rel: str, results: Path) -> str:
    import pandas as pd

    rows, cols = pd.read_csv(results / rel).shape
    return (
        f"- `studies/results/{rel}` ({rows} rows, {cols} columns; {{download}}`download <{FILES}/{rel}>`). "
        f"Provenance: {provenance(results / rel)}"
    )


def render_entry(entry: Entry, results: Path) -> list[str]:
    """The Markdown of one entry: heading, provenance, figures, data files, then the file itself."""
    path = results / entry.file
    if path.suffix == ".md":
        title, body, found = _report(path)
        if found is not None:
            (start, stop), said = found
            if said == " ".join(s.strip() for s in body[start:stop]):
                del body[start:stop]  # a paragraph of provenance only: shown once, in the provenance block
    else:
        title, body = entry.title or path.name, []
        if path.suffix == ".csv":
            body = [csv_table(path)]
        elif path.suffix == ".json":
            body = ["```json", path.read_text().rstrip(), "```"]
    out = [f"## {title}", "", *_provenance_block(results, entry.file)]
    for fig in entry.figures:
        out += _figure(fig, results)
    if entry.data:
        out += ["Data files behind this section:", "", *(_data(d, results) for d in entry.data), ""]
    return [*out, *body, ""]


def render_page(page: Page, results: Path) -> str:
    """The Markdown of one results page, every entry rendered from the files in ``results``."""
    out = [
        f"# {page.title}",
        "",
        page.intro,
        "",
        "Generated when the documentation is built, from the files named in each section "
        "(`docs/_ext/jko_results.py`); the provenance lines are what each file records.",
        "",
    ]
    for entry in page.entries:
        out += render_entry(entry, results)
    return "\n".join(out).rstrip() + "\n"


def _write_if_changed(target: Path, data: bytes) -> None:
    """Write ``data`` unless ``target`` holds it already (unchanged pages are not read again)."""
    if not target.is_file() or target.read_bytes() != data:
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)


def write_pages(results: Path, out: Path, pages: tuple[Page, ...] = PAGES) -> list[Path]:
    """Render ``pages`` from the files in ``results`` into ``out``; return the page files.

    Figures and data files are copied to ``out/files/``; files of ``out`` no page produced are
    removed.  Raises :class:`FileNotFoundError` naming every listed file missing from ``results``.
    """
    results, out = Path(results), Path(out)
    missing = [f for f in sources(pages) if not (results / f).is_file()]
    if missing:
        raise FileNotFoundError(f"results pages: files missing from {results}: {missing}")
    written: set[Path] = set()
    for page in pages:
        target = out / f"{page.name}.md"
        _write_if_changed(target, render_page(page, results).encode())
        written.add(target)
        for entry in page.entries:
            for rel in (*entry.figures, *entry.data):
                copy = out / FILES / rel
                _write_if_changed(copy, (results / rel).read_bytes())
                written.add(copy)
    for stale in [p for p in out.rglob("*") if p.is_file() and p not in written]:
        stale.unlink()
    return [out / f"{p.name}.md" for p in pages]


def results_dir() -> Path:
    """``studies/results`` of the checkout whose ``jko_cvx`` the build documents."""
    import jko_cvx

    return Path(jko_cvx.__file__).resolve().parents[1] / "studies" / "results"


def _on_builder_inited(app: Any) -> None:
    from sphinx.errors import ExtensionError

    results = Path(app.config.jko_results_dir or results_dir())
    try:
        write_pages(results, Path(app.srcdir) / GENERATED)
    except (OSError, ValueError) as exc:
        raise ExtensionError(f"jko_results: {exc}") from exc


def setup(app: Any) -> dict[str, Any]:
    app.add_config_value("jko_results_dir", None, "env")
    app.connect("builder-inited", _on_builder_inited)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
