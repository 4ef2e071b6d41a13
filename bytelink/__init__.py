"""Byte links between parts of one process: the medium under the companion's MAVLink link
and servo bus when a flight runs on simulated time (:mod:`bytelink.memory`).

A package of its own because both ``companion.link`` and ``arm_driver`` open these links
and ``sitl`` serves them: it depends on none of them, and all three may depend on it. It is
in the flight install (``pip install .``), as the clients that open it are.
"""
