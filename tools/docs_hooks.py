"""The generated pages of the documentation site, as an mkdocs hook (``mkdocs.yml`` ``hooks:``).

Two reference pages are generated at every ``mkdocs build`` and never committed, so they cannot
drift from the code:

* ``reference/cli.md``    — every ``carlaocc`` command, from the Typer application: its help
  text, its arguments and options with their types and defaults;
* ``reference/config.md`` — every key of the dataset config (``carlaocc config`` prints one),
  from the pydantic models under :class:`carlaocc.schemas.configs.DatasetConfig`: dotted key,
  type, default and description.

``cli_reference()`` and ``config_reference()`` are pure functions of the code (markdown text out),
tested in ``tests/test_docs_site.py``.
"""

from __future__ import annotations

import enum
import re
import types
import typing

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

CLI_PAGE = "reference/cli.md"
CONFIG_PAGE = "reference/config.md"


def _text(text: object) -> str:
    """Help text as markdown: ``<root>`` and the like are words, not HTML tags."""
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _cell(text: object) -> str:
    """One markdown table cell: no newline, no bare pipe, no HTML."""
    return _text(" ".join(str(text).split())).replace("|", "\\|")


def _subcommands(cmd) -> list[tuple[str, object]]:
    """A group's visible commands in the order ``--help`` lists them; [] for a command."""
    if not hasattr(cmd, "list_commands"):
        return []
    ctx = cmd.make_context(cmd.name or "carlaocc", ["--help"], resilient_parsing=True)
    return [(n, c) for n in cmd.list_commands(ctx) if (c := cmd.get_command(ctx, n)) is not None and not c.hidden]


def _commands(cmd, path: list[str]) -> typing.Iterator[tuple[list[str], object]]:
    """Depth first: (words after ``carlaocc``, command)."""
    yield path, cmd
    for name, sub in _subcommands(cmd):
        yield from _commands(sub, [*path, name])


def _param_type(p) -> str:
    """What a parameter takes: Typer keeps the annotation (its vendored click no ``type``)."""
    td = getattr(p, "type_descriptor", None)
    if td is not None:
        return _type_name(td.annotation)
    t = getattr(p, "type", None)
    return getattr(t, "name", str(t))


def _param_row(p) -> str:
    # the option's spellings (an argument: its name), then what it takes and its default
    option = p.param_type_name == "option"
    if option:
        names = ", ".join(f"`{o}`" for o in (*p.opts, *p.secondary_opts))
    else:
        names = f"`{(p.name or '').upper()}`"
    kind = "flag" if option and getattr(p, "is_flag", False) else _param_type(p)
    default = "required" if p.required else ("" if p.default in (None, False, (), []) else f"`{p.default}`")
    if callable(p.default):
        default = ""
    return f"| {names} | {_cell(kind)} | {_cell(default)} | {_cell(getattr(p, 'help', '') or '')} |"


def cli_reference() -> str:
    """Markdown of every ``carlaocc`` command (from the Typer app, as ``carlaocc --help`` sees it)."""
    import typer
    from carlaocc.pipeline.cli import app

    root = typer.main.get_command(app)
    out = ["# CLI reference", "",
           ("Generated from the Typer application at every site build (`tools/docs_hooks.py`); "
            "`carlaocc <command> --help` prints the same text. Exit codes: 0 ok, 1 a task or "
            "work failed, 2 a usage or input error (one line, nothing in the root touched)."), ""]
    for path, cmd in _commands(root, []):
        title = " ".join(["carlaocc", *path])
        out += [f"## `{title}`", ""]
        if cmd.help:
            out += [_text(cmd.help.strip().replace("\b\n", "")), ""]
        params = [p for p in cmd.params if not getattr(p, "hidden", False) and p.name != "help"]
        if params:
            out += ["| argument / option | takes | default | meaning |", "|---|---|---|---|"]
            out += [_param_row(p) for p in params] + [""]
        subs = _subcommands(cmd)
        if subs:
            out += ["Commands: " + ", ".join(f"`{title} {n}`" for n, _ in subs), ""]
    return "\n".join(out) + "\n"


def _type_name(t: object) -> str:
    """A field's annotation as a short readable string (``float | None``, ``'a' | 'b'``)."""
    origin = typing.get_origin(t)
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in typing.get_args(t))
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in typing.get_args(t))
    if t is type(None):
        return "None"
    if isinstance(t, type) and issubclass(t, enum.Enum):
        return " | ".join(repr(m.value) for m in t)
    if isinstance(t, type):
        return t.__name__
    return str(t).replace("typing.", "").replace("carlaocc.schemas.", "")


def _model_of(t: object) -> type[BaseModel] | None:
    """The pydantic model a field holds (itself or ``Model | None``), else None."""
    if isinstance(t, type) and issubclass(t, BaseModel):
        return t
    args = [a for a in typing.get_args(t) if a is not type(None)]
    if len(args) == 1 and isinstance(args[0], type) and issubclass(args[0], BaseModel):
        return args[0]
    return None


def _config_rows(model: type[BaseModel], prefix: str, seen: set) -> typing.Iterator[str]:
    # one row per scalar key; a nested model is walked once, under the first key that holds it
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        sub = _model_of(field.annotation)
        if sub is not None and sub not in seen:
            default = "None" if field.default is None else "(the keys below)"
            yield f"| `{key}` | {_cell(_type_name(field.annotation))} | {default} | {_cell(field.description or '')} |"
            yield from _config_rows(sub, key + ".", seen | {sub})
            continue
        if field.default is not PydanticUndefined:
            default = field.default
        elif field.default_factory is not None:
            default = "(computed)"
        else:
            default = "required"
        if isinstance(default, BaseModel):
            default = "(the defaults below)"
        yield (f"| `{key}` | {_cell(_type_name(field.annotation))} | {_cell(repr(default) if default not in ('required', '(computed)') else default)} "
               f"| {_cell(field.description or '')} |")


def config_reference() -> str:
    """Markdown of every dataset config key (from the pydantic models), in declaration order."""
    from carlaocc.schemas.configs import DatasetConfig, SourceIngestConfig, TownSpec

    out = ["# Configuration keys", "",
           ("Generated from the pydantic models at every site build (`tools/docs_hooks.py`). "
            "A dataset config is YAML or JSON (`carlaocc config` prints the effective one, "
            "`carlaocc run --config cfg.yaml` uses it); a key left out keeps its default, an "
            "unknown key is refused with exit 2."), ""]
    for title, model, prefix in (("Dataset config", DatasetConfig, ""),
                                 ("A town (`scenes.towns[i]`)", TownSpec, "scenes.towns[i]."),
                                 ("An ingest source (`carlaocc ingest`)", SourceIngestConfig, "")):
        out += [f"## {title}", "", (model.__doc__ or "").strip().split("\n\n")[0], "",
                "| key | type | default | meaning |", "|---|---|---|---|"]
        out += list(_config_rows(model, prefix, {model})) + [""]
    return "\n".join(out) + "\n"


def front_page(readme: str) -> str:
    """README.md as the site's ``index.md``: a link into ``docs/`` made relative to ``docs/``; a
    link to another file of the repository (LICENSE, CITATION.cff: not part of the site) becomes
    its text with the file's name as code."""

    def link(m: re.Match) -> str:
        label, target = m.group(1), m.group(2)
        if target.startswith(("http://", "https://", "#")):
            return m.group(0)
        if target.startswith("docs/"):
            return f"[{label}]({target[len('docs/'):]})"
        return f"{label} (`{target}` in the repository)"

    # [label](target), not an image's ![alt](src) (the front page's picture is under docs/)
    text = re.sub(r"(?<!!)\[([^\]]+)\]\(([^)\s]+)\)", link, readme)
    return re.sub(r"(!\[[^\]]*\])\(docs/", r"\1(", text)


def on_files(files, config):
    """mkdocs hook: add the front page (README.md) and the generated reference pages to the site."""
    from pathlib import Path

    from mkdocs.structure.files import File

    readme = (Path(config["config_file_path"]).parent / "README.md").read_text()
    files.append(File.generated(config, "index.md", content=front_page(readme)))
    for page, text in ((CLI_PAGE, cli_reference()), (CONFIG_PAGE, config_reference())):
        files.append(File.generated(config, page, content=text))
    return files


# the docstrings are written for Sphinx: their cross-reference roles (:class:`Store`) and literal
# block markers ("as follows::") come out of mkdocstrings' Markdown as text; shown as code and ":"
_ROLE = re.compile(r":(?:class|func|meth|mod|attr|data|exc|obj|py:\w+):(<code>)")
_LITERAL_MARK = re.compile(r"::(</p>)")


def on_page_content(html, page, config, files):
    """Sphinx roles and literal-block markers in the generated API page, as a reader expects them."""
    if not page.file.src_uri.startswith("reference/"):
        return html
    return _LITERAL_MARK.sub(r":\1", _ROLE.sub(r"\1", html))
