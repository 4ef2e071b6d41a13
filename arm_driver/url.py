"""Bus URLs: which backend, which device, which options, in one string.

::

    dynamixel:///dev/ttyUSB0?baud=1000000
    dronecan://can0?interface=socketcan&node_id=10

The scheme names the backend, the rest of the location (host and path joined) is the
device, and the query holds options. Options are strings here; each backend converts and
validates its own and rejects the ones it does not know. An option given twice is an
error, not "the last one wins".
"""

from __future__ import annotations

import urllib.parse
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = ["BusUrl", "convert_options", "flag", "milliseconds", "parse_bus_url"]


@dataclass(frozen=True)
class BusUrl:
    """A parsed bus URL.

    Attributes
    ----------
    backend
        Backend name (the URL scheme, lower case), e.g. ``"dynamixel"``.
    device
        Device: a path (``/dev/ttyUSB0``) or an interface name (``can0``).
    options
        Query options, name -> value (strings, unconverted).
    """

    backend: str
    device: str
    options: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", MappingProxyType(dict(self.options)))


def parse_bus_url(url: str) -> BusUrl:
    """Split a bus URL into backend, device and options.

    Raises
    ------
    ValueError
        No scheme, no device, a fragment, an option without ``=`` or given twice.
    """
    parts = urllib.parse.urlsplit(url)
    if not parts.scheme:
        raise ValueError(
            f"bus URL {url!r} has no backend (expected e.g. 'dynamixel:///dev/ttyUSB0')"
        )
    if parts.fragment:
        raise ValueError(f"bus URL {url!r}: fragments ('#...') are not used")
    device = urllib.parse.unquote(parts.netloc + parts.path)
    if not device:
        raise ValueError(f"bus URL {url!r} names no device")
    try:
        pairs = urllib.parse.parse_qsl(parts.query, keep_blank_values=True, strict_parsing=True)
    except ValueError:
        if parts.query:
            raise ValueError(f"bus URL {url!r}: malformed options {parts.query!r}") from None
        pairs = []
    options: dict[str, str] = {}
    for name, value in pairs:
        if name in options:
            raise ValueError(f"bus URL {url!r}: option {name!r} given twice")
        options[name] = value
    return BusUrl(parts.scheme.lower(), device, options)


OptionSpec = Mapping[str, tuple[str, Callable[[str], Any]]]
"""URL option name -> (constructor keyword, parser of the option's text)."""


def convert_options(backend: str, options: Mapping[str, str], spec: OptionSpec) -> dict[str, Any]:
    """A backend's constructor keywords from its URL options; ``ValueError`` names an
    unknown option (with the known ones) or a value its parser refuses."""
    unknown = sorted(set(options) - set(spec))
    if unknown:
        raise ValueError(f"unknown {backend} option(s) {unknown}; known: {sorted(spec)}")
    kwargs = {}
    for name, text in options.items():
        keyword, parse = spec[name]
        try:
            kwargs[keyword] = parse(text)
        except ValueError:
            raise ValueError(f"{backend} option {name}={text!r} is not valid") from None
    return kwargs


def flag(text: str) -> bool:
    """A boolean URL option: 1/true/yes/on or 0/false/no/off."""
    if text.lower() in ("1", "true", "yes", "on"):
        return True
    if text.lower() in ("0", "false", "no", "off"):
        return False
    raise ValueError(text)


def milliseconds(text: str) -> float:
    """A duration option given in milliseconds, as seconds."""
    return float(text) / 1e3
