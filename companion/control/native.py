"""The compiled parts of the control cycle (the C extension ``companion.control._step``) and the
switch between them and the Python reference.

:func:`native_module` answers one question for
:class:`~companion.estimation.filters.StateFilter` and
:class:`~companion.control.flight.FlightControl`: run compiled or in Python. Compiled is the
default where the extension is built (``pip install .`` always builds it); ``False`` or the
environment variable ``COMPANION_STEP=python`` selects the Python reference. A missing
extension gives the Python path after a one-line warning (once per process).
"""

from __future__ import annotations

import logging
import os
from types import ModuleType

__all__ = ["native_module", "python_reason"]

_log = logging.getLogger(__name__)

try:
    from companion.control import _step as _module

    _step: ModuleType | None = _module
    _MISSING = ""
except ImportError as error:  # not built: the Python reference runs
    _step = None
    _MISSING = str(error)

_warned = False


def python_reason() -> str | None:
    """Why the control step runs in Python by default here (the environment variable, or
    the extension not built), or None when it runs compiled."""
    if os.environ.get("COMPANION_STEP") == "python":
        return "COMPANION_STEP=python selects the Python reference"
    if _step is None:
        return f"companion.control._step is not built ({_MISSING}; `pip install .` builds it)"
    return None


def native_module(compiled: bool | None = None) -> ModuleType | None:
    """The extension if the compiled path is wanted and built, else None.

    ``compiled``: True (RuntimeError if the extension is not built), False (None), or
    None: wanted unless ``COMPANION_STEP`` is ``python``; if it is not built, a one-line
    warning (once per process) and None.
    """
    global _warned
    wanted = os.environ.get("COMPANION_STEP") != "python" if compiled is None else compiled
    if not wanted:
        return None
    if _step is None:
        if compiled:
            raise RuntimeError(
                f"compiled=True but companion.control._step is not built ({_MISSING})"
            )
        if not _warned:
            _warned = True
            _log.warning(
                "companion.control._step is not built (%s): the control step runs in Python "
                "(`pip install .` builds it)",
                _MISSING,
            )
    return _step
