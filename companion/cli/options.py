"""A command's options declared once, as the fields of a dataclass.

:func:`options_command` makes a function of one options dataclass into a typer command
whose options are the dataclass's fields: each field is annotated with its
``typer.Option`` (``Annotated[float, typer.Option(help=...)]``), its default is the
option's default, and the command receives the options as one instance. The options are
declared in one place, checked by the dataclass's own methods, and passed on as one value,
instead of a command function with two dozen parameters. Shared options are ``Annotated``
aliases, used by the dataclasses and by the plain commands alike.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable

__all__ = ["options_command"]

Options = typing.TypeVar("Options")


def options_command(
    options: type[Options],
) -> Callable[[Callable[[Options], None]], Callable[..., None]]:
    """Decorator: ``command(opts: options)`` as a function of ``options``' fields, by
    keyword, in their order (what typer reads for the command's options and its help)."""
    if not dataclasses.is_dataclass(options):
        raise TypeError(f"{options.__name__} is not a dataclass")
    made = [
        f.name for f in dataclasses.fields(options) if f.default_factory is not dataclasses.MISSING
    ]
    if made:
        raise TypeError(
            f"{options.__name__}.{made[0]}: an option's default is a value, not a factory"
        )
    hints = typing.get_type_hints(options, include_extras=True)
    parameters = [
        inspect.Parameter(
            field.name,
            inspect.Parameter.KEYWORD_ONLY,
            annotation=hints[field.name],
            default=inspect.Parameter.empty
            if field.default is dataclasses.MISSING
            else field.default,
        )
        for field in dataclasses.fields(options)
    ]

    def decorate(command: Callable[[Options], None]) -> Callable[..., None]:
        @functools.wraps(command)
        def from_fields(**values: object) -> None:
            command(options(**values))

        from_fields.__signature__ = inspect.Signature(parameters)  # type: ignore[attr-defined]
        from_fields.__annotations__ = {}
        return from_fields

    return decorate
