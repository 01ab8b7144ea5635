"""The manual as a site (mkdocs.yml, tools/docs_hooks.py): README.md is a short front page whose
links all resolve; the generated references name every CLI command and every dataset config key
with its default; the site builds with warnings as errors (broken internal links and anchors
included) and its front page and a tutorial carry their text and pictures. The build test needs
the docs toolchain (the `docs` extra, also in `test`) and is skipped without it."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import docs_hooks
from browser import chromium


def test_readme_is_a_short_front_page_whose_links_resolve():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) < 200
    # CI follows the two set-up commands
    assert "make dataset FRAMES=2" in text and "\nmake test " in text
    assert "../shared" not in text
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    assert len(targets) > 10
    for t in targets:
        if not t.startswith(("http://", "https://")):
            assert (ROOT / t.split("#")[0]).exists(), f"README links {t}, which is not in the tree"


def test_front_page_links_are_relative_to_docs():
    page = docs_hooks.front_page("![a](docs/x.png) [b](docs/t/y.md#z) [c](LICENSE) [d](https://e.org)")
    assert page == "![a](x.png) [b](t/y.md#z) c (`LICENSE` in the repository) [d](https://e.org)"


def test_cli_reference_names_every_command_and_option():
    import typer
    from carlaocc.pipeline.cli import app

    page = docs_hooks.cli_reference()
    # every command of the app, walked here independently of the generator
    def walk(cmd, path):
        yield path, cmd
        for name, sub in getattr(cmd, "commands", {}).items():
            if not sub.hidden:
                yield from walk(sub, [*path, name])

    commands = list(walk(typer.main.get_command(app), ["carlaocc"]))
    assert len(commands) > 30
    for path, cmd in commands:
        head = f"## `{' '.join(path)}`"
        assert head in page, f"{head} missing"
        section = page.split(head + "\n", 1)[1].split("\n## `", 1)[0]
        for p in cmd.params:
            for opt in getattr(p, "opts", [])[:1] if p.param_type_name == "option" and not p.hidden else []:
                assert f"`{opt}`" in section, f"{' '.join(path)}: {opt} missing"
    assert "| `--voxel-size`, `--res` | str |" in page
    # help text is words: "<root>/plan.yaml" must not become an HTML tag
    assert "&lt;root&gt;/plan.yaml" in page and "<root>" not in page


def _leaves(d: dict, prefix: str = ""):
    for k, v in d.items():
        if isinstance(v, dict) and v:
            yield from _leaves(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


def test_config_reference_has_every_key_with_its_default():
    from carlaocc.schemas.configs import DatasetConfig

    page = docs_hooks.config_reference()
    # | `key` | type | default | meaning |  (a pipe inside a cell is escaped)
    cells = [re.split(r"(?<!\\)\|", ln)[1:-1] for ln in page.splitlines() if ln.startswith("| `")]
    rows = {c[0].strip().strip("`"): c[2].strip() for c in cells}
    leaves = dict(_leaves(DatasetConfig().model_dump()))
    assert len(leaves) > 50
    for key, value in leaves.items():
        assert key in rows, f"config reference lacks {key}"
        if isinstance(value, (int, float, str, bool)) and not isinstance(value, bool) or value is None:
            assert rows[key] == repr(value).replace("|", "\\|"), (key, rows[key], value)


NO_MKDOCS = importlib.util.find_spec("mkdocs") is None
# the Terrain colour of docs/front.png's 3D view: large flat areas keep it when the browser scales
TERRAIN = np.array([140, 231, 140])


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site, built with warnings as errors (broken internal links and anchors included)."""
    site = tmp_path_factory.mktemp("docs") / "site"
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], check=False,
                       cwd=ROOT, capture_output=True, text=True, timeout=300, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stderr[-3000:]
    return site


@pytest.mark.skipif(NO_MKDOCS, reason="the docs toolchain (carlaocc[docs]) is not installed")
def test_site_builds_strict(site):
    index = (site / "index.html").read_text()
    assert "carlaocc builds instance-centric panoptic occupancy datasets" in index
    assert 'src="front.png"' in index and (site / "front.png").is_file()
    assert 'href="tutorials/first-dataset.html"' in index
    first = (site / "tutorials" / "first-dataset.html").read_text()
    assert "make dataset FRAMES=2" in first and 'src="../front.png"' in first
    # the tutorials' not-runnable marks stay HTML comments: in the page's source, not on screen
    assert "<!-- not-runnable:" in first and "&lt;!-- not-runnable" not in first
    sensors = (site / "concepts" / "sensors.html").read_text()
    assert 'src="../rgb_sheet.png"' in sensors and 'src="../rgb_textured.png"' in sensors
    cli = (site / "reference" / "cli.html").read_text()
    assert "carlaocc run" in cli and "--voxel-size" in cli
    api = (site / "reference" / "api.html").read_text()
    assert "GridSpec" in api
    # the docstrings' Sphinx roles and literal-block markers are not shown as text
    assert not re.search(r":(class|func|meth|mod|attr|data):<code>", api) and "::</p>" not in api


@pytest.mark.skipif(NO_MKDOCS, reason="needs the docs toolchain")
@pytest.mark.parametrize("page", ["index.html", "tutorials/first-dataset.html"])
def test_page_shows_its_picture_in_a_browser(site, page, tmp_path):
    # a screenshot in headless Chromium: the page's picture loaded and drawn (its flat terrain
    # colour covers thousands of pixels; a missing image would draw none)
    shot = tmp_path / "shot.png"
    r = subprocess.run([chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                        "--window-size=1280,3000", f"--screenshot={shot}", (site / page).as_uri()],
                       check=False, capture_output=True, text=True, timeout=120)
    assert shot.is_file(), r.stderr[-2000:]
    pixels = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert (np.abs(pixels - TERRAIN).max(axis=-1) <= 3).sum() > 2000, f"{page}: its picture is not drawn"
