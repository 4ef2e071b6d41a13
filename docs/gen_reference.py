"""Write the generated references: ``docs/cli.md`` and ``docs/config.md``.

    python docs/gen_reference.py            # rewrite both files
    python docs/gen_reference.py --check    # exit 1 if either is stale

``docs/cli.md`` walks the command trees of ``companion`` and ``sitl`` as click sees them
(``typer.main.get_command``): every command, its arguments and options with their types,
defaults and help. ``docs/config.md`` walks the configuration models
(``companion.config.CompanionConfig``, and ``sitl.scenario.Scenario`` for the simulator's
sections): every key with its type, whether it is required or its default, the range the
loader enforces, and the key's own docstring in the model. Nothing is written by hand, so
the pages change only when the code does; ``tests/test_reference_docs.py`` fails when the
checked-in pages differ from what this script writes.
"""

from __future__ import annotations

import argparse
import ast
import inspect
import itertools
import sys
import textwrap
import types
import typing
from collections.abc import Iterator
from enum import Enum
from pathlib import Path
from typing import Any

import annotated_types
import typer
from pydantic import AfterValidator, BaseModel
from pydantic.fields import FieldInfo
from typer._click import Command, Context, Parameter

DOCS = Path(__file__).resolve().parent
CLI_PAGE = DOCS / "cli.md"
CONFIG_PAGE = DOCS / "config.md"
REGENERATE = "python docs/gen_reference.py"

# --- command lines --------------------------------------------------------------------


def _cell(text: str) -> str:
    """``text`` on one line, safe inside a Markdown table cell."""
    return " ".join(text.split()).replace("|", "\\|")


def _help_text(text: str | None) -> str:
    """A command's help as paragraphs of Markdown (typer keeps the docstring's layout)."""
    if not text:
        return ""
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(" ".join(p.split()) for p in paragraphs if p.strip())


def _param_usage(param: Parameter, ctx: Context) -> str:
    """The parameter as ``--help`` lists it: its names and the kind of value it takes."""
    record = param.get_help_record(ctx)
    text = record[0] if record else (param.name or "")
    if param.param_type_name == "argument":
        name, _, kind = text.partition(" ")
        text = f"{name.upper()} {kind}".strip()
    return f"`{_cell(text)}`"


def _param_default(param: Parameter) -> str:
    if param.required:
        return "required"
    default = param.default
    if default is None or (getattr(param, "is_flag", False) and default is False):
        return ""
    if isinstance(default, Enum):
        default = default.value
    if isinstance(default, bool):
        return "on" if default else "off"
    if isinstance(default, list | tuple):
        return ", ".join(f"`{item}`" for item in default) if default else ""
    return f"`{_portable(default)}`"


def _portable(default: object) -> object:
    """An absolute path inside the packages (a config shipped as package data) relative to
    the directory that holds them, so that the page reads the same in every checkout and
    install."""
    if not isinstance(default, str | Path) or not Path(default).is_absolute():
        return default
    import companion
    import sitl

    path = Path(default)
    for package in (companion, sitl):
        base = Path(package.__file__).parent.parent  # type: ignore[arg-type]
        if path.is_relative_to(base):
            return path.relative_to(base).as_posix()
    return default


def _param_help(param: Parameter) -> str:
    text = _cell(getattr(param, "help", None) or "")
    envvar = getattr(param, "envvar", None)
    if envvar:
        names = [envvar] if isinstance(envvar, str) else list(envvar)
        text += f" (environment: {', '.join(f'`{name}`' for name in names)})"
    return text.strip()


def _commands(command: Command, ctx: Context) -> Iterator[tuple[Command, Context]]:
    """``command`` and every command below it, depth first in the order ``--help`` lists
    them."""
    yield command, ctx
    list_commands = getattr(command, "list_commands", None)
    if list_commands is None:
        return
    for name in list_commands(ctx):
        sub = command.get_command(ctx, name)  # type: ignore[attr-defined]
        if sub is None or sub.hidden:
            continue
        yield from _commands(sub, Context(sub, info_name=name, parent=ctx))


def _command_section(command: Command, ctx: Context) -> list[str]:
    path = ctx.command_path
    level = "#" * min(2 + path.count(" "), 4)
    lines = [f"{level} `{path}`", ""]
    pieces = " ".join(command.collect_usage_pieces(ctx))
    lines += ["```", f"{path} {pieces}".rstrip(), "```", ""]
    help_text = _help_text(command.help)
    if help_text:
        lines += [help_text, ""]
    params = [p for p in command.get_params(ctx) if not getattr(p, "hidden", False)]
    params = [p for p in params if p.name != "help"]
    if params:
        lines += ["| argument or option | default | help |", "|---|---|---|"]
        for param in params:
            cells = (_param_usage(param, ctx), _param_default(param), _param_help(param))
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def render_cli() -> str:
    """The text of ``docs/cli.md``."""
    from companion.cli.main import app as companion_app
    from sitl.cli import app as sitl_app

    lines = [
        "# Command-line reference",
        "",
        f"Generated from the commands themselves by `{REGENERATE}`; do not edit. Every",
        "command also takes `--help`, which prints the same text. A usage error (an",
        "unknown option, a missing argument) is one `error:` line and exit status 2.",
        "",
        "Every file a command reads is looked at before it is read (`companion.user_files`): a",
        "missing path, a directory, a FIFO, a device, a socket or a loop of symbolic links is",
        "one `error:` line naming the file and what it is, exit 2, and is never opened. A TOML",
        "file (configuration, scenario, campaign spec) over 1 MiB is refused by its size, unread;",
        "one nested too deeply to parse, or without a key, is one line too. Flight logs are",
        "read row by row, never whole.",
        "",
    ]
    for name, app in (("companion", companion_app), ("sitl", sitl_app)):
        root = typer.main.get_command(app)
        tree = list(_commands(root, Context(root, info_name=name)))
        lines.append(f"Commands of `{name}`: " + ", ".join(f"`{c.command_path}`" for _, c in tree))
        lines.append("")
        for command, ctx in tree:
            lines += _command_section(command, ctx)
    return "\n".join(lines).rstrip() + "\n"


# --- configuration --------------------------------------------------------------------


def _attribute_docstrings(model: type[BaseModel]) -> dict[str, str]:
    """Each field's docstring (the string literal below its annotation) in ``model`` and
    its bases, as Python's attribute docstring convention has them."""
    found: dict[str, str] = {}
    for cls in reversed(model.__mro__):
        if not (isinstance(cls, type) and issubclass(cls, BaseModel)) or cls is BaseModel:
            continue
        try:
            source = textwrap.dedent(inspect.getsource(cls))
        except (OSError, TypeError):
            continue
        body = ast.parse(source).body[0]
        assert isinstance(body, ast.ClassDef)
        statements = body.body
        for statement, following in itertools.pairwise(statements):
            if not (
                isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)
            ):
                continue
            if isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant):
                if isinstance(following.value.value, str):
                    found[statement.target.id] = inspect.cleandoc(following.value.value)
    return found


def _split(annotation: Any) -> tuple[Any, list[Any]]:
    """A type without its ``Annotated`` layers, and their metadata (pydantic's FieldInfo
    flattened into its own metadata)."""
    metadata: list[Any] = []
    while typing.get_origin(annotation) is typing.Annotated:
        annotation, *extra = typing.get_args(annotation)
        for item in extra:
            if isinstance(item, FieldInfo):
                metadata.extend(item.metadata)
            else:
                metadata.append(item)
    return annotation, metadata


def _optional(annotation: Any) -> tuple[Any, bool]:
    """``annotation`` without ``| None``, and whether it had it."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(annotation)) == 2:
            return args[0], True
    return annotation, False


def _number(value: float) -> str:
    return f"{value:g}"


def _constraints(metadata: list[Any]) -> list[str]:
    """What the loader enforces on one value, from the declarations' metadata."""
    found = []
    for item in metadata:
        if isinstance(item, annotated_types.Gt):
            found.append(f"> {_number(item.gt)}")  # type: ignore[arg-type]
        elif isinstance(item, annotated_types.Ge):
            found.append(f">= {_number(item.ge)}")  # type: ignore[arg-type]
        elif isinstance(item, annotated_types.Lt):
            found.append(f"< {_number(item.lt)}")  # type: ignore[arg-type]
        elif isinstance(item, annotated_types.Le):
            found.append(f"<= {_number(item.le)}")  # type: ignore[arg-type]
        elif isinstance(item, AfterValidator):
            found.extend(_validator_text(item.func))
    return found


def _validator_text(func: Any) -> list[str]:
    """A range validator's bounds and reason, from the variables it closes over
    (``companion.config._within``); other validators by their docstring's first line."""
    names = inspect.getclosurevars(func).nonlocals
    if {"low", "high", "why"} <= names.keys():
        unit = f" {names['unit']}" if names.get("unit") else ""
        low, high = _number(names["low"]), _number(names["high"])
        return [f"within [{low}, {high}]{unit} ({names['why']})"]
    doc = inspect.getdoc(func)
    return [doc.splitlines()[0]] if doc else []


_SCALARS = {float: "number", int: "integer", bool: "boolean", str: "string"}


def _type_text(annotation: Any, metadata: list[Any]) -> tuple[str, list[str]]:
    """How a value of ``annotation`` is written in TOML, and its constraints."""
    annotation, inner = _split(annotation)
    metadata = [*metadata, *inner]
    if annotation in _SCALARS:
        return _SCALARS[annotation], _constraints(metadata)
    origin = typing.get_origin(annotation)
    if origin is typing.Literal:
        return "one of " + ", ".join(f'`"{v}"`' for v in typing.get_args(annotation)), []
    if origin is tuple:
        item, _ = typing.get_args(annotation)
        item_text, item_constraints = _type_text(item, [])
        lengths = {
            type(m).__name__: m for m in metadata if isinstance(m, annotated_types.BaseMetadata)
        }
        low = getattr(lengths.get("MinLen"), "min_length", None)
        high = getattr(lengths.get("MaxLen"), "max_length", None)
        if low is not None and low == high:
            count = f"{low} "
        elif low is not None and high is not None:
            count = f"{low}-{high} "
        elif low is not None:
            count = f"{low} or more "
        else:
            count = ""
        plural = item_text if item_text.startswith("table") else f"{item_text}s"
        return f"array of {count}{plural}", [f"each {c}" for c in item_constraints]
    if origin is dict:
        _, value = typing.get_args(annotation)
        value_text, value_constraints = _type_text(value, [])
        return f"table of name = {value_text}", [f"each {c}" for c in value_constraints]
    return _cell(str(annotation)), _constraints(metadata)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    return str(value)


def _default_text(field: FieldInfo) -> str:
    if field.is_required():
        return "required"
    if field.default_factory is not None:
        made = field.default_factory()  # type: ignore[call-arg]
        if isinstance(made, BaseModel):
            return "its keys' defaults"
        return f"`{_toml_value(made)}`"
    if field.default is None:
        return "absent"
    return f"`{_toml_value(field.default)}`"


def _model_of(annotation: Any) -> tuple[type[BaseModel] | None, bool, bool]:
    """The section model a field holds, whether it is optional, whether it is an array
    of tables."""
    annotation, _ = _split(annotation)
    annotation, optional = _optional(annotation)
    annotation, _ = _split(annotation)
    if typing.get_origin(annotation) is tuple:
        item, _ = _split(typing.get_args(annotation)[0])
        if isinstance(item, type) and issubclass(item, BaseModel):
            return item, optional, True
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation, optional, False
    return None, optional, False


def _section_lines(
    model: type[BaseModel],
    path: str,
    optional: bool,
    array: bool,
    keys: list[str] | None,
    field_doc: str = "",
) -> list[str]:
    """One section's table and, after it, its subsections; ``keys`` limits the fields
    (the simulator's part of a scenario); ``field_doc`` is the docstring of the key that
    holds the section."""
    docs = _attribute_docstrings(model)
    heading = f"[[{path}]]" if array else f"[{path}]" if path else "top level"
    lines = [f"### `{heading}`" if path else f"### {heading}", ""]
    for text in (field_doc, _help_text(model.__doc__)):
        if text and path:
            lines += [text, ""]
    where = f"`{model.__module__}.{model.__qualname__}`"
    notes = [where]
    if optional:
        notes.append("optional section")
    if array:
        notes.append("an array of tables, one per entry")
    lines += ["(" + "; ".join(notes) + ")", ""]
    rows, subsections = [], []
    for name, field in model.model_fields.items():
        if keys is not None and name not in keys:
            continue
        key = field.alias or name
        sub, sub_optional, sub_array = _model_of(field.annotation)
        if sub is not None:
            sub_path = f"{path}.{key}" if path else key
            subsections.append((sub, sub_path, sub_optional, sub_array, _help_text(docs.get(name))))
            continue
        annotation, _ = _optional(field.annotation)
        text, constraints = _type_text(annotation, list(field.metadata))
        description = _cell(docs.get(name, ""))
        rows.append(
            f"| `{key}` | {_cell(text)} | {_default_text(field)} | "
            f"{_cell('; '.join(constraints))} | {description} |"
        )
    if rows:
        lines += [
            "| key | type | default | allowed | meaning |",
            "|---|---|---|---|---|",
            *rows,
            "",
        ]
    else:
        lines += ["Only subsections.", ""]
    for sub, sub_path, sub_optional, sub_array, sub_doc in subsections:
        lines += _section_lines(sub, sub_path, sub_optional, sub_array, None, sub_doc)
    return lines


def render_config() -> str:
    """The text of ``docs/config.md``."""
    from companion.config import SIMULATOR_SECTIONS, CompanionConfig
    from sitl.scenario import Scenario

    companion_keys = list(CompanionConfig.model_fields)
    simulator_keys = [k for k in Scenario.model_fields if k not in CompanionConfig.model_fields]
    assert set(simulator_keys) == set(SIMULATOR_SECTIONS), (simulator_keys, SIMULATOR_SECTIONS)
    lines = [
        "# Configuration reference",
        "",
        f"Generated from the configuration models by `{REGENERATE}`; do not edit.",
        "A configuration is one TOML file (`configs/*.toml`). Keys carry their unit in their",
        "name (`_m`, `_kg`, `_rad`, `_hz`, `_n_m`, ...); units inside the code are SI. Every",
        "key below is checked on load: unknown keys, missing required keys, wrong types and",
        "values outside the range shown are refused, each as one `file: key: reason` line",
        "(`companion check FILE`, `sitl check FILE`). Beyond the ranges per key the loaders",
        "check relations between keys (a centre of mass within its link, lc = m3/m2 within",
        "[0, l2], m4 >= m3^2/m2, ordered bounds, the arm bus's joints).",
        "",
        "## The companion's sections",
        "",
        "What the companion believes and how it flies: `companion.config.load_config` reads",
        "these and skips the simulator's sections, so its types cannot hold the truth.",
        "",
    ]
    lines += _section_lines(CompanionConfig, "", False, False, companion_keys)
    lines += [
        "## The simulator's sections",
        "",
        "The truth and the offline runs, read by `sitl.scenario.load_scenario` (the whole",
        "file: the companion's sections above plus these). The companion never reads them.",
        "",
    ]
    docs = _attribute_docstrings(Scenario)
    for key in simulator_keys:
        field = Scenario.model_fields[key]
        sub, optional, array = _model_of(field.annotation)
        assert sub is not None, key
        doc = _help_text(docs.get(key))
        lines += _section_lines(sub, field.alias or key, optional, array, None, doc)
    return "\n".join(lines).rstrip() + "\n"


# --- the script -----------------------------------------------------------------------

PAGES = {CLI_PAGE: render_cli, CONFIG_PAGE: render_config}


def stale_pages() -> list[Path]:
    """The checked-in pages that differ from what this script writes now."""
    stale = []
    for page, render in PAGES.items():
        current = page.read_text(encoding="utf-8") if page.exists() else None
        if current != render():
            stale.append(page)
    return stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a page is stale")
    args = parser.parse_args(argv)
    if args.check:
        stale = stale_pages()
        for page in stale:
            print(f"{page.relative_to(DOCS.parent)} is stale: run {REGENERATE}", file=sys.stderr)
        return 1 if stale else 0
    for page, render in PAGES.items():
        page.write_text(render(), encoding="utf-8")
        print(f"wrote {page.relative_to(DOCS.parent)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
