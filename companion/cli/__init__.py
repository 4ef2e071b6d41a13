"""The ``companion`` command line: ``mission``, ``arm``, ``plot`` (:mod:`~companion.cli.main`).

- :mod:`~companion.cli.mission`: ``companion mission pickup``;
- :mod:`~companion.cli.arm`: ``companion arm`` (scan, calibrate, ...);
- :mod:`~companion.cli.plot`: ``companion plot``;
- :mod:`~companion.cli.entry`, :mod:`~companion.cli.usage`: ``--version``, one-line usage
  errors, output directories (shared with ``sitl``).
"""

from companion.cli.main import main

__all__ = ["main"]
