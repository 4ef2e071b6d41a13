"""DroneCAN backend: actuators commanded with ``uavcan.equipment.actuator`` messages.

- :mod:`~arm_driver.dronecan.bus`: :class:`~arm_driver.dronecan.bus.DroneCanBus`, the
  ``dronecan://`` backend of :class:`~arm_driver.bus.ArmBus`;
- :mod:`~arm_driver.dronecan.can_driver`: the dronecan CAN driver over python-can that
  replaces dronecan's own (dronecan/pydronecan#79), the one place that works around it.

Imported only when a ``dronecan://`` bus is opened (``arm_driver.bus`` registry).
"""
