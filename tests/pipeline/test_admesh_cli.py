"""`carlaocc admesh show/sheet`: headless renders of the library to PNG."""

from __future__ import annotations

import struct

import pytest
from typer.testing import CliRunner

from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app

cli = CliRunner()


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    root = tmp_path_factory.mktemp("lib") / "data"
    r = cli.invoke(app, ["run", "--stages", "ingest", "--root", str(root), "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    return Store(str(root))


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", data[16:24])
    return w, h


def _pixels(path):
    """RGB pixels of a PNG written by catalog.images (one IDAT chunk, filter 0)."""
    import zlib

    import numpy as np

    data = path.read_bytes()
    w, h = _png_size(path)
    n = struct.unpack(">I", data[33:37])[0]
    raw = np.frombuffer(zlib.decompress(data[41:41 + n]), np.uint8).reshape(h, 1 + 3 * w)
    return raw[:, 1:].reshape(h, w, 3)


def test_show_one_asset(library, tmp_path):
    (aid,), = query(library, "SELECT asset_id FROM assets WHERE category = 'Car' ORDER BY asset_id LIMIT 1")[1]
    out = tmp_path / "car.png"
    r = cli.invoke(app, ["admesh", "show", aid, "--out", str(out), "--root", library.url])
    assert r.exit_code == 0, r.output
    assert _png_size(out) == (512, 512)
    px = _pixels(out)
    # white background at the corner, the car in the middle (Car's palette colour is blue)
    assert (px[0, 0] == 255).all()
    centre = px[192:320, 192:320].reshape(-1, 3).astype(int)
    assert ((centre[:, 2] > centre[:, 0] + 40)).mean() > 0.2


def test_contact_sheet_of_a_query(library, tmp_path):
    out = tmp_path / "cars.png"
    r = cli.invoke(app, ["admesh", "sheet", "--where", "category_id = 14", "--limit", "7", "--columns", "4",
                         "--size", "96", "--out", str(out), "--root", library.url])
    assert r.exit_code == 0 and "7 assets" in r.output
    w, h = _png_size(out)
    assert w > 4 * 96 and h > 2 * 96  # four columns (and the key), two rows of thumbnails


def test_bad_requests_exit_2(library, tmp_path):
    r = cli.invoke(app, ["admesh", "show", "nope", "--out", str(tmp_path / "x.png"), "--root", library.url])
    assert r.exit_code == 2 and "no asset 'nope'" in r.output
    r = cli.invoke(app, ["admesh", "sheet", "--where", "categry = 1", "--root", library.url])
    assert r.exit_code == 2 and "categry" in r.output and "Traceback" not in r.output
    r = cli.invoke(app, ["admesh", "sheet", "--where", "1 = 1; DROP VIEW assets", "--root", library.url])
    assert r.exit_code == 2
    assert not (tmp_path / "x.png").exists()
