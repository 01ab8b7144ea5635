"""The tutorials run: every fenced code block of docs/tutorials/*.md is executed against a small
built root (a copy of :func:`default_01`, the embedded default at 0.1 m, two frames a sequence,
one camera, stages up to sensors) unless the line before its fence marks it
``<!-- not-runnable: <reason> -->`` (an HTML comment: the site does not show it).

A ``python`` block runs as a script; any other block runs line by line, each line a ``carlaocc``
command (shell words, ``#`` comments dropped), all in a directory where ``data`` is
the root, and each must exit 0. They run in this process (``carlaocc`` through the Typer app, a
script with ``exec``): a subprocess would pay carlaocc's imports again for every line. A block with anything else in it (``make``, a transcript, a
placeholder) must be marked, with its reason. The count of run and skipped blocks is printed
(``pytest -s``) and checked against the pages."""

from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TUTORIALS = ROOT / "docs" / "tutorials"
FENCE = re.compile(r"^```(\w*)\s*$")
MARK = re.compile(r"^<!-- not-runnable: (.+?) -->$")


def blocks(text: str) -> list[tuple[int, str, str, str | None]]:
    """The fenced blocks of a markdown page: (line of the fence, language, body, the not-runnable
    reason or None). Raises ValueError on an unclosed fence or an empty reason."""
    lines = text.splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        # the body runs to the closing fence
        end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), None)
        if end is None:
            raise ValueError(f"line {i + 1}: unclosed code fence")
        prev = lines[i - 1].strip() if i else ""
        mark = MARK.match(prev)
        if prev.startswith("<!-- not-runnable") and not mark:
            raise ValueError(f"line {i}: a not-runnable mark needs a reason: <!-- not-runnable: <reason> -->")
        out.append((i + 1, m.group(1), "\n".join(lines[i + 1:end]), mark.group(1).strip() if mark else None))
        i = end + 1
    return out


def commands(body: str) -> list[list[str]]:
    """A shell block's ``carlaocc`` commands: one a line, shell words with ``#`` comments dropped."""
    out = []
    for line in body.splitlines():
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if words[0] == "carlaocc":
            out.append(words)
        else:
            raise ValueError(f"{line!r}: the runner runs carlaocc commands only; mark the block "
                             "<!-- not-runnable: <reason> -->")
    return out


PAGES = sorted(TUTORIALS.glob("*.md"))
ALL = [(p, *b) for p in PAGES for b in blocks(p.read_text())]
RUNNABLE = [b for b in ALL if b[4] is None]


def test_blocks_parser():
    page = "a\n```python\nprint(1)\n```\n<!-- not-runnable: needs S3 -->\n```bash\nmake x\n```\n"
    assert blocks(page) == [(2, "python", "print(1)", None), (6, "bash", "make x", "needs S3")]
    with pytest.raises(ValueError, match="reason"):
        blocks("<!-- not-runnable -->\n```\nx\n```\n")
    with pytest.raises(ValueError, match="unclosed"):
        blocks("```\nx\n")
    assert commands("carlaocc info --root data   # what it holds\n\n# a comment\n") == [
        ["carlaocc", "info", "--root", "data"]]
    with pytest.raises(ValueError, match="not-runnable"):
        commands("make dataset")


def test_every_tutorial_block_runs_or_says_why_not():
    # the pages hold blocks, some runnable; every other one names its reason
    skipped = [b for b in ALL if b[4] is not None]
    print(f"\ntutorial code blocks: {len(RUNNABLE)} run, {len(skipped)} marked not-runnable")
    assert len(PAGES) >= 6 and RUNNABLE and len(RUNNABLE) + len(skipped) == len(ALL)
    for page, line, lang, body, _ in RUNNABLE:
        if lang != "python":
            commands(body)  # raises on anything but carlaocc commands


@pytest.fixture(scope="module")
def workdir(default_01, tmp_path_factory) -> Path:
    """A directory whose ``data`` is a copy of the shared root (a tutorial may write to it)."""
    work = tmp_path_factory.mktemp("tutorials")
    shutil.copytree(default_01.url, work / "data")
    return work


@pytest.mark.parametrize("page,line,lang,body", [pytest.param(p, ln, lg, b, id=f"{p.stem}:{ln}")
                                                  for p, ln, lg, b, _ in RUNNABLE])
def test_tutorial_block_runs(page, line, lang, body, workdir, monkeypatch, capsys):
    from carlaocc.pipeline.cli import app
    from typer.testing import CliRunner

    monkeypatch.chdir(workdir)
    if lang == "python":
        exec(compile(body, f"{page.name}:{line}", "exec"), {"__name__": "__main__"})  # noqa: S102  (the tutorial's own code)
        assert capsys.readouterr().out.strip(), f"{page.name}:{line}: the script printed nothing"
        return
    for cmd in commands(body):
        r = CliRunner().invoke(app, cmd[1:])
        assert r.exit_code == 0, f"{page.name}:{line}: {shlex.join(cmd)} exited {r.exit_code}\n{r.output[-3000:]}"
        assert r.output.strip(), f"{page.name}:{line}: {shlex.join(cmd)} printed nothing"
