"""Flight-envelope campaigns: many pickups on simulated time over a scenario's keys.

A spec (:mod:`sitl.campaign.spec`) names a base scenario, the keys to vary (grids, or
ranges sampled by a seeded design, :mod:`sitl.campaign.design`), repetitions, controllers
and faults; it expands into flights with stable ids (:mod:`sitl.campaign.flights`); the
local engine (:mod:`sitl.campaign.engine`) flies them on worker processes
(:mod:`sitl.campaign.fly`); each finished flight is one committed row of a SQLite table
(:mod:`sitl.campaign.store`); the report is computed from that table
(:mod:`sitl.campaign.report`). ``sitl campaign`` is :mod:`sitl.campaign.cli`.
"""
