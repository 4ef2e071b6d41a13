"""A campaign spec: a TOML file naming a base scenario, the axes to vary and how to sample
them, validated on load like the scenario files (:mod:`companion.config`).

Format (every key but ``name`` and ``scenario`` optional)::

    name = "envelope"                        # the campaign's name (a results table holds one)
    description = "what it asks"
    scenario = "../sitl_pickup.toml"         # the base scenario, relative to this file
    controllers = ["passivity", "nonadaptive"]  # each draw flown by each: paired flights
                                             # (also "px4_position": PX4's own position
                                             # control with its hover thrust estimator)
    autopilots = ["imitation"]               # and by each autopilot: imitation (simulated
                                             # time) or px4 (the real build, PX4_SITL_DIR)
    repetitions = 2                          # flights per draw and controller, each its own
                                             # sensor-noise seed (the same for the pair)
    place_at_m = [-1.0, 0.5, 0.05]           # where the object goes (sitl demo --place-at)

    [design]                                 # how the ``range`` axes are sampled
    kind = "latin_hypercube"                 # or "random"
    samples = 150
    seed = 1

    [set]                                    # scenario keys set for every flight
    "plant.battery.capacity_ah" = 4.0

    [axes]                                   # scenario keys varied, by dotted name
    "payload.mass_kg" = { range = [0.10, 0.45] }       # sampled by the design
    "world.start_yaw_rad" = { values = [0.0, 1.57] }   # a grid: every draw with each value
    "world.payload_position_m[0]" = { range = [0.8, 1.5] }  # one entry of a vector
    "plant.wind_m_s[0]" = { range = [-3.0, 3.0] }      # a steady wind from the west or east
    "place_at_m[1]" = { range = [0.0, 0.5] }           # the place point, entry by entry

    [[faults]]                               # each draw flown with each fault (default: none)
    kind = "none"
    [[faults]]
    kind = "payload_slip"                    # grasp_fails; link_cut (at_s, duration_s);
    after_grasp_s = 2.5                      # servo_silent (servo_id, at_s); link_loss
                                             # (at_s, duration_s, drop_fraction);
                                             # link_latency (at_s, duration_s, delay_s);
                                             # pilot_takeover (at_s, mode = "POSCTL")
    [[faults]]
    kind = "link_cut"                        # a fault at a phase instead of a time:
    at_phase = "grasp"                       # takeoff, to_object ... to_home, landing
    offset_s = 0.5                           # (docs/faults.md), this long into it
    duration_s = 2.0                         # with px4: link_cut, link_latency,
                                             # pilot_takeover and the servo faults (sitl
                                             # run's options), at a time or a phase;
                                             # link_loss, bus_corruption: imitation

    [bounds.passivity]                       # per controller: a completed flight whose
    mass_error_pct = 3.0                     # |figure| exceeds one of these is outside the
    com_error_pct = 5.0                      # bounds (reported with its replay command)
    placement_error_m = 0.05

A key of ``[set]`` and ``[axes]`` is a scenario key as the scenario file spells it
(``plant.thrust_mismatch``), with ``[i]`` for an entry of a vector or of an array of tables
(``arm_bus.joints[0].torque_constant_n_m_per_a``), or ``place_at_m[i]``. An unknown key is
one :class:`~companion.config.ConfigError` line naming the closest valid one; the values are
checked when the flights are expanded (:func:`sitl.campaign.flights.expand`), each flight's
scenario validated as a scenario file is.
"""

from __future__ import annotations

import difflib
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

from companion.config import ConfigError, read_toml, validate
from sitl.scenario import Scenario
from sitl.vehicle.mission_phases import FAULT_PHASES

__all__ = [
    "BOUND_FIGURES",
    "FAULT_KINDS",
    "LINK_FAULTS",
    "PLACE_KEY",
    "Axis",
    "CampaignSpec",
    "Design",
    "Fault",
    "KeyPath",
    "load_spec",
    "parse_key",
]

FAULT_KINDS = (
    "none", "payload_slip", "grasp_fails", "link_cut", "link_loss", "link_latency",
    "pilot_takeover", "servo_silent", "servo_error", "servo_reboot", "bus_corruption",
)  # fmt: skip
"""Faults a flight can be given: in the truth (``payload_slip``, ``grasp_fails``: the
scenario's ``[world]``) or in the links (``link_cut``, ``link_loss``, ``link_latency``,
``pilot_takeover``, ``servo_silent``, ``servo_error``, ``servo_reboot``,
``bus_corruption``: the run options)."""
LINK_FAULTS = (
    "link_cut", "link_loss", "link_latency", "pilot_takeover", "servo_silent", "servo_error",
    "servo_reboot", "bus_corruption",
)  # fmt: skip
"""The faults that start at a time or a phase, injected by the simulator's links."""
BoundFigure = Literal[
    "mass_error_pct",
    "com_error_pct",
    "placement_error_m",
    "carry_rms_m",
    "carry_max_error_m",
    "max_tilt_deg",
]
BOUND_FIGURES: tuple[str, ...] = typing.get_args(BoundFigure)
"""The figures of a flight's row ``[bounds]`` may limit (their magnitude)."""
PLACE_KEY = "place_at_m"
"""The key of the place point (not a scenario key: the mission's ``--place-at``)."""

Scalar = float | int | bool | str
SetValue = Scalar | list[Scalar]
Number = Annotated[float, Field(allow_inf_nan=False)]


class _Table(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Axis(_Table):
    """One varied key: grid ``values`` or a ``range`` [low, high] sampled by the design."""

    values: Annotated[tuple[Scalar, ...], Field(min_length=1)] | None = None
    range: tuple[Number, Number] | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> Axis:
        if (self.values is None) == (self.range is None):
            raise ValueError("give either values = [...] (a grid) or range = [low, high]")
        if self.range is not None and not self.range[0] < self.range[1]:
            raise ValueError(f"range low must be below high, got {list(self.range)}")
        return self


class Design(_Table):
    """The seeded design that samples the ``range`` axes (draws in the unit cube, scaled)."""

    kind: Literal["latin_hypercube", "random"] = "latin_hypercube"
    samples: Annotated[int, Field(strict=True, ge=1, le=100_000)] = 1
    seed: Annotated[int, Field(strict=True, ge=0)] = 0


_FAULT_VALUES = (
    "servo_id", "error", "mode", "after_grasp_s", "at_s", "at_phase", "offset_s",
    "duration_s", "drop_fraction", "delay_s", "corrupt_fraction", "boot_s",
)  # fmt: skip
"""A fault's values, in the order its label gives them."""


class Fault(_Table):
    """A fault injected into each flight of a draw (``none``: a healthy flight)."""

    kind: Literal[
        "none", "payload_slip", "grasp_fails", "link_cut", "link_loss", "link_latency",
        "pilot_takeover", "servo_silent", "servo_error", "servo_reboot", "bus_corruption",
    ]  # fmt: skip
    after_grasp_s: Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)] | None = None
    """payload_slip: the object slips out this long after the grasp [s]."""
    at_s: Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)] | None = None
    """link_cut, link_loss, link_latency, pilot_takeover, servo_silent, servo_error: when the
    fault starts
    [s, simulated time]; or ``at_phase``."""
    at_phase: str | None = None
    """The fault's mission phase instead (``docs/faults.md``),
    ``offset_s`` after it began (as the companion told it on the onboard link)."""
    offset_s: Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)] | None = None
    """With ``at_phase``: how long after the phase began [s, simulated time] (0 if not
    given)."""
    duration_s: Annotated[float, Field(strict=True, gt=0.0, allow_inf_nan=False)] | None = None
    """link_cut, link_loss, link_latency, bus_corruption: how long the onboard link stays
    silent, lossy or slow, or the servo bus's replies corrupted [s]."""
    drop_fraction: Annotated[float, Field(strict=True, gt=0.0, le=1.0)] | None = None
    """link_loss: the fraction of the onboard link's messages dropped, both ways."""
    delay_s: Annotated[float, Field(strict=True, gt=0.0, le=2.0)] | None = None
    """link_latency: how long every message of the onboard link is held back, both ways
    [s]."""
    corrupt_fraction: Annotated[float, Field(strict=True, gt=0.0, le=1.0)] | None = None
    """bus_corruption: the fraction of the servos' replies sent with a broken CRC."""
    mode: Literal["POSCTL", "ALTCTL", "AUTO_LOITER", "AUTO_RTL", "AUTO_LAND"] | None = None
    """pilot_takeover: the PX4 mode the pilot switches to from the ground station."""
    servo_id: Annotated[int, Field(strict=True, ge=0, le=252)] | None = None
    """servo_silent, servo_error, servo_reboot: the servo that stops answering, detects the
    error or reboots."""
    boot_s: Annotated[float, Field(strict=True, gt=0.0, le=10.0)] | None = None
    """servo_reboot: how long the rebooting servo answers nothing [s]."""
    error: Literal[
        "overload", "overheating", "input_voltage", "electrical_shock", "motor_encoder"
    ] | None = None  # fmt: skip
    """servo_error: the hardware error the servo detects (Hardware Error Status(70); torque
    off for overload, overheating and electrical shock, the XM430's Shutdown default)."""

    @model_validator(mode="after")
    def _its_fields(self) -> Fault:
        if self.at_phase is not None and self.at_phase not in FAULT_PHASES:
            raise ValueError(
                f"at_phase must be one of {', '.join(FAULT_PHASES)}, got {self.at_phase!r}"
            )
        timed = self.kind in LINK_FAULTS
        if timed and (self.at_s is None) == (self.at_phase is None):
            raise ValueError(f"{self.kind} needs either at_s or at_phase")
        if self.offset_s is not None and self.at_phase is None:
            raise ValueError("offset_s is the time into at_phase: give at_phase")
        start = ("at_s",) if self.at_s is not None else ("at_phase", "offset_s")
        needs = {
            "none": (),
            "grasp_fails": (),
            "payload_slip": ("after_grasp_s",),
            "link_cut": (*start, "duration_s"),
            "link_loss": (*start, "duration_s", "drop_fraction"),
            "link_latency": (*start, "duration_s", "delay_s"),
            "pilot_takeover": (*start, "mode"),
            "servo_silent": ("servo_id", *start),
            "servo_error": ("servo_id", "error", *start),
            "servo_reboot": ("servo_id", "boot_s", *start),
            "bus_corruption": (*start, "duration_s", "corrupt_fraction"),
        }[self.kind]
        given = {k for k in _FAULT_VALUES if getattr(self, k) is not None}
        missing = [k for k in needs if k not in given and k != "offset_s"]
        if missing:
            raise ValueError(f"{self.kind} needs {', '.join(missing)}")
        extra = sorted(given - set(needs))
        if extra:
            raise ValueError(f"{self.kind} takes no {', '.join(extra)}")
        return self

    def label(self) -> str:
        """``kind`` and its values, e.g. ``link_cut(at_s=20, duration_s=2)``."""
        values = [
            f"{k}={v}" if isinstance(v := getattr(self, k), str) else f"{k}={v:g}"
            for k in _FAULT_VALUES
            if getattr(self, k) is not None
        ]
        return f"{self.kind}({', '.join(values)})" if values else self.kind


class CampaignSpec(_Table):
    """A campaign: base scenario, axes, design, repetitions, controllers and faults."""

    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")]
    description: str = ""
    scenario: str
    """The base scenario file, relative to the spec's directory (or absolute)."""
    controllers: Annotated[
        tuple[Literal["passivity", "nonadaptive", "asmc", "px4_position"], ...],
        Field(min_length=1),
    ] = ("passivity",)
    autopilots: Annotated[tuple[Literal["imitation", "px4"], ...], Field(min_length=1)] = (
        "imitation",
    )
    """Who flies the vehicle: the PX4 imitation on simulated time, or the real PX4 SITL
    build in the loop (at its validated speed, about 2 of this machine's cores a flight)."""
    repetitions: Annotated[int, Field(strict=True, ge=1, le=10_000)] = 1
    place_at_m: tuple[Number, Number, Number] = (-1.0, 0.5, 0.05)
    design: Design = Design()
    set: dict[str, SetValue] = Field(default_factory=dict)
    axes: dict[str, Axis] = Field(default_factory=dict)
    faults: Annotated[tuple[Fault, ...], Field(min_length=1)] = (Fault(kind="none"),)
    bounds: dict[
        Literal["passivity", "nonadaptive", "asmc", "px4_position"],
        dict[BoundFigure, Annotated[float, Field(gt=0.0, allow_inf_nan=False)]],
    ] = Field(default_factory=dict)
    """Per controller, the largest magnitude of each figure a completed flight may have
    (:data:`BOUND_FIGURES`); :meth:`outside_bounds`."""

    @model_validator(mode="after")
    def _distinct(self) -> CampaignSpec:
        if len(set(self.controllers)) != len(self.controllers):
            raise ValueError(f"controllers listed twice: {list(self.controllers)}")
        if len(set(self.autopilots)) != len(self.autopilots):
            raise ValueError(f"autopilots listed twice: {list(self.autopilots)}")
        if "px4" in self.autopilots and any(
            f.kind in ("link_loss", "bus_corruption") for f in self.faults
        ):
            raise ValueError(
                "link_loss and bus_corruption fly on the imitation only (the campaign acts on "
                "its in-memory links); with px4 the campaign flies link_cut, pilot_takeover "
                "and the servo faults"
            )
        return self

    @property
    def flies_px4(self) -> bool:
        """Some of the flights need the PX4 SITL build."""
        return "px4" in self.autopilots

    def outside_bounds(self, row: dict[str, object]) -> list[str]:
        """What of a completed flight's ``row`` lies outside its controller's bounds, one
        text each (e.g. ``mass_error_pct -42.1 (bound 3)``); empty when within them or
        when the flight did not complete (that is a failure of its own)."""
        if not row.get("completed"):
            return []
        controller = row.get("controller")
        limits = next((b for c, b in self.bounds.items() if c == controller), {})
        broken = []
        for figure, limit in limits.items():
            value = row.get(figure)
            if isinstance(value, int | float) and not abs(value) <= limit:
                broken.append(f"{figure} {value:.4g} (bound {limit:g})")
        return broken


@dataclass(frozen=True)
class KeyPath:
    """A parsed key: its parts (names and indices) and whether its leaf holds floats."""

    key: str
    parts: tuple[str | int, ...]
    float_leaf: bool
    """The scenario's type of the leaf is a float: a whole number given becomes a float."""

    @property
    def is_place(self) -> bool:
        return self.parts[0] == PLACE_KEY


_PART = re.compile(r"([^.\[\]]+)((?:\[\d+\])*)")


def _split(key: str) -> list[str | int] | None:
    parts: list[str | int] = []
    for piece in key.split("."):
        match = _PART.fullmatch(piece)
        if match is None:
            return None
        parts.append(match.group(1))
        parts.extend(int(i) for i in re.findall(r"\[(\d+)\]", match.group(2)))
    return parts


def _unwrap(annotation: object) -> list[object]:
    """The types an annotation admits (through Annotated, Optional and unions)."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return _unwrap(typing.get_args(annotation)[0])
    if origin in (Union, types.UnionType):
        return [t for arg in typing.get_args(annotation) for t in _unwrap(arg)]
    return [annotation]


def _element(annotation: object) -> object | None:
    """The element type of a tuple or list annotation (None if it is not one)."""
    for t in _unwrap(annotation):
        if typing.get_origin(t) in (tuple, list):
            args = [a for a in typing.get_args(t) if a is not Ellipsis]
            return args[0] if args else None
    return None


def _model(annotation: object) -> type[BaseModel] | None:
    for t in _unwrap(annotation):
        if isinstance(t, type) and issubclass(t, BaseModel):
            return t
    return None


def _is_float(annotation: object) -> bool:
    kinds = _unwrap(annotation)
    return float in kinds and int not in kinds


def parse_key(key: str, where: str, path: str) -> KeyPath:
    """The :class:`KeyPath` of a ``[set]`` or ``[axes]`` key; :class:`ConfigError` (one
    line, at ``where``, with the closest valid name) if the scenario has no such key."""
    parts = _split(key)
    if not parts or not isinstance(parts[0], str):
        raise ConfigError(path, where, f"not a dotted key: {key!r}")
    if parts[0] == PLACE_KEY:
        if len(parts) == 2 and isinstance(parts[1], int) and parts[1] < 3:
            return KeyPath(key, tuple(parts), True)
        raise ConfigError(path, where, f"the place point's entries are {PLACE_KEY}[0] to [2]")
    model: type[BaseModel] | None = Scenario
    annotation: object = None
    done = ""
    for i, part in enumerate(parts):
        if isinstance(part, int):
            element = _element(annotation)
            if element is None:
                raise ConfigError(path, where, f"{done} is not a vector or an array: no [{part}]")
            annotation, model = element, _model(element)
            done += f"[{part}]"
            continue
        if model is None:
            raise ConfigError(path, where, f"{done} holds a value, not a table: no .{part}")
        fields = {(f.alias or n): f for n, f in model.model_fields.items()}
        if part not in fields:
            prefix = f"{done}." if done else ""
            close = difflib.get_close_matches(part, list(fields), n=1)
            if close:
                rest = key[len(prefix) + len(part) :]
                hint = f"; did you mean '{prefix}{close[0]}{rest}'?"
            else:
                hint = ""
            where_in = f" in [{done}]" if done else ""
            raise ConfigError(path, where, f"no scenario key '{part}'{where_in}{hint}")
        annotation = fields[part].annotation
        model = _model(annotation) if _element(annotation) is None else None
        done += f".{part}" if done else part
        if i == len(parts) - 1 and model is not None:
            raise ConfigError(path, where, f"{done} is a table; name one of its keys")
    element = _element(annotation)
    return KeyPath(key, tuple(parts), _is_float(element if element is not None else annotation))


def load_spec(path: str | Path) -> CampaignSpec:
    """Read and validate a campaign spec (its keys; the values are checked on expansion).

    Raises
    ------
    ConfigError
        If the file cannot be read, is not TOML, has an unknown or missing key, or names a
        scenario key that does not exist (one line, with the closest name).
    """
    path = str(path)
    spec = validate(CampaignSpec, read_toml(path), path)
    for section, keys in (("set", spec.set), ("axes", spec.axes)):
        for key in keys:
            parse_key(key, f'{section}."{key}"', path)
    both = sorted(set(spec.set) & set(spec.axes))
    if both:
        raise ConfigError(path, f'set."{both[0]}"', "is also an axis: set it or vary it")
    return spec
