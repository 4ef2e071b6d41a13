"""Calibrating the arm: the servos' torque constants and the joints' offsets, written into the
config.

- :mod:`~companion.calibration.servo`: a servo's torque constant against gravity;
- :mod:`~companion.calibration.arm`: the arm's calibration run over the bus;
- :mod:`~companion.calibration.config_edit`: calibrated values written into a config TOML in
  place, comments and layout kept.
"""
