"""The compiled parts of the control cycle (the compiled twin of
:mod:`companion.control.control_step`) and the switch between them and the Python reference.

:func:`native_module` answers one question for
:class:`~companion.estimation.filters.StateFilter` and
:class:`~companion.control.flight.FlightControl`: run compiled or in Python. Compiled is the
default where the twin is built from the source as it is (``pip install .`` always builds
it); ``False`` or the environment variable ``COMPANION_STEP=python`` selects the Python
reference (the numpy classes, not the twin's source). A missing or stale twin gives the
Python path after a one-line warning (once per process).
"""

from __future__ import annotations

import importlib
import logging
import os
from types import ModuleType

from companion.compiled import twin_name, twin_reason

__all__ = ["native_module", "python_reason"]

_log = logging.getLogger(__name__)

_SOURCE = "companion.control.control_step"
_NAME = twin_name(_SOURCE)
_MISSING = twin_reason(_SOURCE) or ""
_step: ModuleType | None = None if _MISSING else importlib.import_module(_NAME)

_warned = False


def _missing() -> str:
    """Why the twin cannot run."""
    return _MISSING or f"{_NAME} is not built"


def python_reason() -> str | None:
    """Why the control step runs in Python by default here (the environment variable, or
    the twin not built or stale), or None when it runs compiled."""
    if os.environ.get("COMPANION_STEP") == "python":
        return "COMPANION_STEP=python selects the Python reference"
    if _step is None:
        return _missing()
    return None


def native_module(compiled: bool | None = None) -> ModuleType | None:
    """The compiled twin if the compiled path is wanted and the twin can run, else None.

    ``compiled``: True (RuntimeError if the twin is not built or stale), False (None), or
    None: wanted unless ``COMPANION_STEP`` is ``python``; if the twin cannot run, a one-line
    warning (once per process) and None.
    """
    global _warned
    wanted = os.environ.get("COMPANION_STEP") != "python" if compiled is None else compiled
    if not wanted:
        return None
    if _step is None:
        if compiled:
            raise RuntimeError(f"compiled=True but {_missing()}")
        if not _warned:
            _warned = True
            _log.warning("%s: the control step runs in Python", _missing())
    return _step
