"""A package's public names imported on first use (PEP 562 module ``__getattr__``).

Each concept package of ``companion`` lists its public names in its ``__init__`` and where
each lives; the modules import one another's concrete modules, never a package, so no
import cycle runs through an ``__init__``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module

__all__ = ["lazy_attributes"]


def lazy_attributes(package: str, homes: Mapping[str, str]) -> Callable[[str], object]:
    """The ``__getattr__`` of ``package``: ``homes`` maps each public name to its module."""

    def __getattr__(name: str) -> object:
        if name in homes:
            return getattr(import_module(homes[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
