"""CITATION.cff names the paper and the package, at the package's version."""

import tomllib
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")

ROOT = Path(__file__).resolve().parents[2]


def test_citation_names_the_paper_and_the_package_version():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert str(cff["version"]) == project["version"]
    paper = cff["preferred-citation"]
    assert paper["title"] == "To blow-up or not to blow-up for a granular kinetic equation"
    assert [a["family-names"] for a in paper["authors"]] == ["Carrillo", "Shu", "Wang", "Xu"]
