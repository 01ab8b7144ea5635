"""LICENSE and CITATION.cff agree with pyproject.toml: the licence named there is the one in
LICENSE, the citation's software version and licence are the package's, and it cites the paper
in ../shared/reference."""

import re
import tomllib
from pathlib import Path

import yaml

from tests.shared_data import shared_root

ROOT = Path(__file__).resolve().parents[1]


def _project() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_license_file_is_the_licence_pyproject_names():
    assert _project()["license"] == "Apache-2.0"
    text = (ROOT / "LICENSE").read_text()
    assert text.split()[:4] == ["Apache", "License", "Version", "2.0,"]
    assert "TERMS AND CONDITIONS FOR USE, REPRODUCTION, AND DISTRIBUTION" in text
    assert "END OF TERMS AND CONDITIONS" in text


def test_citation_matches_the_package_and_cites_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    project = _project()
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert str(cff["version"]) == project["version"]
    assert cff["license"] == project["license"]
    paper = cff["preferred-citation"]
    assert paper["type"] == "conference-paper" and paper["year"] == 2026
    tex = shared_root() / "reference" / "paper.tex"
    if tex.exists():  # the title and authors are the paper's own
        source = tex.read_text()
        title = re.search(r"\\title\{(.*?)\}\n", source, re.S).group(1).replace("\\\\", " ")
        assert " ".join(title.split()) == paper["title"]
        for a in paper["authors"]:
            assert f"{a['given-names']} {a['family-names']}" in source
