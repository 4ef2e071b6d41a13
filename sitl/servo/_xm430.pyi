"""Type stub of the C extension ``_xm430`` (source ``_xm430.c``): the XM430 servo model's
per-step physics; see :class:`sitl.servo.xm430.XM430Servo` for the layouts."""

from array import array

def set_state(
    table: bytearray, loop: array, constants: array, angle_rad: float, rate_rad_s: float
) -> bool: ...
def step(table: bytearray, loop: array, constants: array, dt_s: float) -> bool: ...
