"""companion.cli.options: a command's options declared once as a dataclass."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

import pytest
import typer
from typer.testing import CliRunner

from companion.cli.options import options_command


@dataclass(frozen=True)
class _Options:
    name: Annotated[str, typer.Option(help="A required name.")]
    rate_hz: Annotated[float, typer.Option(help="A rate [Hz].")] = 250.0
    loud: Annotated[bool, typer.Option("--loud/--quiet", help="Say more.")] = False


def _app(seen: list[_Options]) -> typer.Typer:
    app = typer.Typer(add_completion=False)

    @app.command()
    @options_command(_Options)
    def go(options: _Options) -> None:
        """Go somewhere."""
        seen.append(options)

    @app.command()
    def other() -> None:
        """A second command, so that go is a subcommand."""

    return app


def test_the_command_gets_one_instance_of_its_options() -> None:
    """GIVEN a command of an options dataclass WHEN invoked with some options THEN it gets
    one instance with those values and the fields' defaults for the rest."""
    seen: list[_Options] = []
    result = CliRunner().invoke(_app(seen), ["go", "--name", "arm", "--loud"])
    assert result.exit_code == 0, result.output
    assert seen == [_Options(name="arm", rate_hz=250.0, loud=True)]


def test_the_fields_are_the_options_with_their_help_and_defaults() -> None:
    """GIVEN the same command WHEN asked for its help THEN every field is an option, in the
    fields' order, with its help, its default and the command's docstring."""
    result = CliRunner().invoke(_app([]), ["go", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    text = result.output
    assert "Go somewhere." in text
    order = [text.index(option) for option in ("--name", "--rate-hz", "--loud")]
    assert order == sorted(order)
    assert "A rate [Hz]." in text and "250.0" in text and "--quiet" in text


def test_a_missing_required_option_is_a_usage_error() -> None:
    """GIVEN the same command WHEN its required field is not given THEN exit status 2 names
    it, and the command never runs."""
    seen: list[_Options] = []
    result = CliRunner().invoke(_app(seen), ["go"])
    assert result.exit_code == 2
    assert "--name" in result.output
    assert seen == []


def test_only_a_dataclass_with_plain_defaults_declares_options() -> None:
    with pytest.raises(TypeError, match="not a dataclass"):
        options_command(dict)

    @dataclass(frozen=True)
    class Made:
        ids: list[int] = field(default_factory=list)

    with pytest.raises(TypeError, match=r"Made\.ids: an option's default is a value"):
        options_command(Made)
