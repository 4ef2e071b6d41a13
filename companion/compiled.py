"""Compiled twins: a module written once in Python, and the same file compiled.

``setup.py`` compiles each module it lists in ``TWINS`` (say ``sitl.vehicle_step``)
with Cython into ``_<name>`` beside it (``sitl._vehicle_step``), which carries the
SHA-256 of the source it was built from. :func:`twin` gives the compiled module while it
was built from the source as it is now, and otherwise the Python module itself: a twin
that is not built (a checkout without ``pip install .``) or stale (the source edited
since the build) is never used, and says so once per process in a one-line warning.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import logging
from pathlib import Path
from types import ModuleType

__all__ = ["twin", "twin_name", "twin_reason"]

_log = logging.getLogger(__name__)
_warned: set[str] = set()


def twin_name(module: str) -> str:
    """The compiled twin's module name of ``module`` (``a.b.c`` -> ``a.b._c``)."""
    package, _, name = module.rpartition(".")
    return f"{package}._{name}"


@functools.cache
def _source_sha256(path: str) -> str:
    """SHA-256 of a twin's source (read once per process: sources do not change under a
    running flight)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def twin_reason(module: ModuleType | str) -> str | None:
    """Why ``module``'s compiled twin cannot run (not built, or built from another
    source), or None when it can. ``module`` is the Python module or its name: a name's
    source is found and hashed, not imported (a caller with another fallback than the
    source, as the control step's numpy reference, need not load it)."""
    if isinstance(module, str):
        spec = importlib.util.find_spec(module)
        assert spec is not None and spec.origin is not None, module
        module_name, source = module, spec.origin
    else:
        assert module.__file__ is not None
        module_name, source = module.__name__, module.__file__
    name = twin_name(module_name)
    try:
        compiled = importlib.import_module(name)
    except ImportError as error:
        return f"{name} is not built ({error}; `pip install .` builds it)"
    if getattr(compiled, "SOURCE_SHA256", None) != _source_sha256(source):
        return (
            f"{name} was built from another {Path(source).name} "
            "(rebuild: `python setup.py build_ext --inplace`)"
        )
    return None


def twin(module: ModuleType, compiled: bool = True) -> ModuleType:
    """``module``'s compiled twin if ``compiled`` and it is built from ``module``'s
    source as it is now; else ``module`` (with a one-line warning, once per process, when
    the twin was wanted)."""
    if not compiled:
        return module
    reason = twin_reason(module)
    if reason is None:
        return importlib.import_module(twin_name(module.__name__))
    if module.__name__ not in _warned:
        _warned.add(module.__name__)
        _log.warning("%s: running its Python source", reason)
    return module
