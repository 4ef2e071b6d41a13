"""The generated references in docs/ are what the code says now: ``docs/cli.md`` (every
command and option of ``companion`` and ``sitl``) and ``docs/config.md`` (every key of the
configuration models). Both are regenerated in memory and compared with the checked-in
files; a change to a command or a config key must come with the regenerated page."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "docs" / "gen_reference.py"


def generator() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gen_reference", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    ("page", "render"), [("cli.md", "render_cli"), ("config.md", "render_config")]
)
def test_the_checked_in_reference_is_current(page, render):
    path = ROOT / "docs" / page
    expected = getattr(generator(), render)()
    current = path.read_text(encoding="utf-8") if path.exists() else ""
    assert current == expected, (
        f"docs/{page} is stale (the commands or the config models changed): "
        f"regenerate it with `python docs/gen_reference.py` and commit it"
    )


def test_every_command_and_option_is_in_the_cli_reference():
    import typer

    from companion.cli.main import app as companion_app
    from sitl.cli import app as sitl_app

    text = generator().render_cli()
    for name, app in (("companion", companion_app), ("sitl", sitl_app)):
        root = typer.main.get_command(app)
        for command in root.commands.values():  # type: ignore[attr-defined]
            assert f"`{name} {command.name}" in text, command.name
            for param in command.params:
                for option in param.opts:
                    if option.startswith("--"):
                        assert f"`{option}" in text, (command.name, option)
    assert "`--version`" in text


def test_every_config_key_is_in_the_config_reference():
    from pydantic import BaseModel

    from sitl.scenario import Scenario

    text = generator().render_config()

    def keys(model: type[BaseModel]):
        for name, field in model.model_fields.items():
            yield field.alias or name
            for inner in (field.annotation, *getattr(field.annotation, "__args__", ())):
                for candidate in (inner, *getattr(inner, "__args__", ())):
                    if isinstance(candidate, type) and issubclass(candidate, BaseModel):
                        yield from keys(candidate)

    for key in keys(Scenario):
        assert f"`{key}`" in text or f".{key}]" in text or f"[{key}]" in text, key
