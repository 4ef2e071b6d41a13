"""A spec expanded into flights: each one's resolved parameters, identity and scenario.

A :class:`Flight` is everything that decides a flight on simulated time (DESIGN.md section
7): the base scenario's bytes (by hash), the scenario keys set, the place point, the noise
seed, the controller, the fault and the autopilot. Its :attr:`~Flight.flight_id` is a hash
of those, so the same spec always names the same flights and a rerun flies only those
missing from the results; :attr:`~Flight.pair_id` leaves the controller out (paired
flights: one draw and autopilot, every controller).

The scenario of a flight is the base scenario's document with the flight's keys set,
validated as a scenario file is (:func:`sitl.scenario.parse_scenario`); the same keys set
into the base file's text (comments kept) give the TOML that ``sitl demo --config`` replays.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import shlex
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomlkit

from companion.config import ConfigError, read_toml_document
from sitl.campaign.design import sample_ranges
from sitl.campaign.spec import LINK_FAULTS, CampaignSpec, Fault, KeyPath, parse_key
from sitl.scenario import Scenario, parse_scenario

__all__ = [
    "CRUISE_ALTITUDE_M",
    "Flight",
    "expand",
    "replay_command",
    "replay_toml",
    "scenario_document",
    "scenario_of",
]

CRUISE_ALTITUDE_M = 1.5
"""The pickup's cruise altitude [m]: ``sitl demo``'s, so that its command replays a flight."""

Setting = tuple[str, Any]


@dataclass(frozen=True)
class Flight:
    """One flight of a campaign, resolved."""

    campaign: str
    base: str
    """The base scenario file (absolute path)."""
    base_sha256: str
    """Hash of the base scenario file's bytes."""
    draw: int
    """Index of the draw (design point and grid cell) in the spec's expansion."""
    repetition: int
    seed: int
    """Seed of the simulated sensors' noise (the same for every controller of a draw)."""
    controller: str
    fault: Fault
    autopilot: str
    """``imitation`` (on simulated time, in one process) or ``px4`` (the real PX4 SITL
    build in the loop, at its validated speed)."""
    settings: tuple[Setting, ...]
    """Scenario keys set for this flight ([set] and the axes), as the spec spells them."""
    axes: tuple[str, ...]
    """The keys of the spec's axes (place point entries included)."""
    place_at_m: tuple[float, float, float]

    def identity(self, with_controller: bool = True) -> dict[str, Any]:
        """The resolved parameters that decide the flight (what its id hashes)."""
        ident: dict[str, Any] = {
            "scenario_sha256": self.base_sha256,
            "settings": sorted([k, v] for k, v in self.settings),
            "place_at_m": list(self.place_at_m),
            "seed": self.seed,
            "fault": self.fault.model_dump(exclude_none=True),
        }
        if self.autopilot != "imitation":  # the imitation's ids as before autopilots came
            ident["autopilot"] = self.autopilot
        if with_controller:
            ident["controller"] = self.controller
        return ident

    @property
    def flight_id(self) -> str:
        """16 hex digits of the SHA-256 of :meth:`identity`."""
        return _digest(self.identity())

    @property
    def pair_id(self) -> str:
        """The id of the draw's flights under every controller on one autopilot (controller
        left out)."""
        return _digest(self.identity(with_controller=False))

    def axis_values(self) -> dict[str, Any]:
        """The value of each axis of the spec in this flight."""
        values = dict(self.settings)
        return {key: values[key] for key in self.axes}


def _digest(identity: dict[str, Any]) -> str:
    text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _fault_settings(fault: Fault) -> list[tuple[tuple[str | int, ...], Any]]:
    """The ``[world]`` keys of a truth fault (the link faults are run options)."""
    if fault.kind == "grasp_fails":
        return [(("world", "grasp_fails"), True)]
    if fault.kind == "payload_slip":
        return [(("world", "payload_slip"), {"after_grasp_s": fault.after_grasp_s})]
    return []


def _put(doc: Any, parts: tuple[str | int, ...], value: Any) -> None:
    """Set ``value`` at ``parts`` in a TOML document (plain dict or tomlkit), creating the
    tables on the way."""
    node = doc
    for part, after in itertools.pairwise(parts):
        if isinstance(part, int):
            node = node[part]
            continue
        if part not in node:
            if isinstance(after, int):  # an entry of a vector the base does not have
                raise KeyError(part)
            node[part] = {}
        node = node[part]
    node[parts[-1]] = list(value) if isinstance(value, tuple) else value


def _apply(doc: Any, flight: Flight) -> None:
    for key, value in flight.settings:
        parts = parse_key(key, key, flight.base).parts
        if parts[0] != "place_at_m":
            try:
                _put(doc, parts, value)
            except (IndexError, KeyError, TypeError):
                raise ConfigError(
                    flight.base, key, "the base scenario has no value there to set"
                ) from None
    for parts, value in _fault_settings(flight.fault):
        _put(doc, parts, value)


def scenario_document(flight: Flight, base: dict[str, Any]) -> dict[str, Any]:
    """The flight's scenario document: ``base`` (the base file's, not changed) with the
    flight's keys set."""
    doc = copy.deepcopy(base)
    _apply(doc, flight)
    return doc


def scenario_of(flight: Flight, document: dict[str, Any]) -> Scenario:
    """The validated scenario of a flight's document (ConfigError as a scenario file's)."""
    return parse_scenario(document, flight.base)


def replay_toml(flight: Flight, base_text: str) -> str:
    """The base scenario file's text (``base_text``, as read when the flights were
    expanded) with the flight's keys set, its comments kept: a file for
    ``sitl demo --config``."""
    doc = tomlkit.parse(base_text)
    _apply(doc, flight)
    head = [
        f"# Flight {flight.flight_id} of the campaign {flight.campaign}: {flight.base}",
        "# with these keys set (the comments beside them are the base file's):",
        *(
            f"#   {key} = {value!r}"
            for key, value in flight.settings
            if key in _scenario_keys(flight)
        ),
        *([f"#   fault: {flight.fault.label()}"] if _fault_settings(flight.fault) else []),
        "",
    ]
    return "\n".join(head) + tomlkit.dumps(doc)


def _scenario_keys(flight: Flight) -> set[str]:
    return {k for k, _ in flight.settings if not k.startswith("place_at_m")}


def replay_command(flight: Flight, out_dir: Path, spec_path: Path) -> str:
    """The shell command that flies ``flight`` alone: ``sitl demo --clock virtual`` (with
    PX4: ``--autopilot px4 --speed validated``, the build from ``PX4_SITL_DIR``) on its
    scenario (``OUT/replay/ID.toml``, :func:`replay_toml`), seed, controller and place
    point; a flight with a link fault, which ``sitl demo`` cannot inject, is replayed by
    ``sitl campaign SPEC --out OUT --replay ID``."""
    out = out_dir.resolve()
    if flight.fault.kind in LINK_FAULTS:
        return shlex.join(
            ["sitl", "campaign", str(spec_path.resolve()), "--out", str(out), "--replay",
             flight.flight_id]
        )  # fmt: skip
    place = ",".join(repr(float(v)) for v in flight.place_at_m)
    autopilot = (
        ["--clock", "virtual"]
        if flight.autopilot == "imitation"
        else ["--autopilot", "px4", "--speed", "validated"]
    )
    return shlex.join(
        [
            "sitl", "demo", *autopilot,
            "--config", str(out / "replay" / f"{flight.flight_id}.toml"),
            "--controller", flight.controller,
            "--seed", str(flight.seed),
            "--place-at", place,
            "--out", str(out / "replay" / flight.flight_id),
        ]
    )  # fmt: skip


def _round(value: float) -> float:
    """A sampled value to 6 significant digits (readable in tables and commands)."""
    return float(f"{value:.6g}")


def _coerce(path: KeyPath, value: Any) -> Any:
    if isinstance(value, list):  # a vector: kept as a tuple, so that a flight is hashable
        return tuple(_coerce(path, v) for v in value)
    if path.float_leaf and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _draws(spec: CampaignSpec, path: str) -> Iterator[tuple[Setting, ...]]:
    ranged = [(k, a.range) for k, a in spec.axes.items() if a.range is not None]
    grid = [(k, a.values) for k, a in spec.axes.items() if a.values is not None]
    if not ranged and spec.design.samples > 1:
        raise ConfigError(
            path, "design.samples", f"{spec.design.samples} draws need an axis with a range"
        )
    points = sample_ranges(
        spec.design.kind,
        spec.design.samples if ranged else 1,
        [r for _, r in ranged if r is not None],
        spec.design.seed,
    )
    for point in points:
        sampled = [(k, _round(float(v))) for (k, _), v in zip(ranged, point, strict=True)]
        for cell in itertools.product(*(values for _, values in grid if values is not None)):
            yield (*sampled, *((k, v) for (k, _), v in zip(grid, cell, strict=True)))


def expand(spec: CampaignSpec, spec_path: str | Path) -> list[Flight]:
    """Every flight of a spec, in a fixed order (draw, repetition, fault, autopilot,
    controller), each one's scenario validated.

    Raises
    ------
    ConfigError
        One line naming the spec, the key and the reason: the base scenario unreadable or
        invalid, a value the scenario refuses, a key with nothing to set in the base.
    """
    path = str(spec_path)
    base_path = (Path(spec_path).parent / spec.scenario).resolve()
    try:
        document = read_toml_document(base_path)
    except ConfigError as exc:
        raise ConfigError(path, "scenario", str(exc)) from None
    base = document.data
    try:
        parse_scenario(base, str(base_path))
    except ConfigError as exc:
        raise ConfigError(path, "scenario", f"{base_path}: {exc.problems[0][1]} "
                          f"({exc.key})") from None  # fmt: skip
    sha = hashlib.sha256(document.raw).hexdigest()
    keys = {k: parse_key(k, k, path) for k in (*spec.set, *spec.axes)}
    fixed = [(k, _coerce(keys[k], v)) for k, v in spec.set.items()]
    flights: list[Flight] = []
    for draw, sampled in enumerate(_draws(spec, path)):
        settings = tuple(fixed) + tuple((k, _coerce(keys[k], v)) for k, v in sampled)
        place = list(spec.place_at_m)
        for key, value in settings:
            if keys[key].is_place:
                place[int(keys[key].parts[1])] = float(value)
        for repetition, fault, autopilot, controller in itertools.product(
            range(spec.repetitions), spec.faults, spec.autopilots, spec.controllers
        ):
            flights.append(
                Flight(
                    campaign=spec.name,
                    base=str(base_path),
                    base_sha256=sha,
                    draw=draw,
                    repetition=repetition,
                    seed=draw * spec.repetitions + repetition,
                    controller=controller,
                    fault=fault,
                    autopilot=autopilot,
                    settings=settings,
                    axes=tuple(spec.axes),
                    place_at_m=(place[0], place[1], place[2]),
                )
            )
    checked: set[str] = set()
    for flight in flights:
        if flight.pair_id in checked:
            continue
        checked.add(flight.pair_id)
        _check_flight(flight, base, path)
    return flights


def _check_flight(flight: Flight, base: dict[str, Any], path: str) -> None:
    try:
        scenario = scenario_of(flight, scenario_document(flight, base))
    except ConfigError as exc:
        key, reason = exc.problems[0]
        values = ", ".join(f"{k} = {v!r}" for k, v in flight.settings)
        raise ConfigError(
            path, key or "scenario", f"{reason}; in draw {flight.draw} ({values})"
        ) from None
    if scenario.world is None or scenario.world.payload_position_m is None:
        raise ConfigError(
            path, "scenario", f"{flight.base} has no object to pick up ([world] payload_position_m)"
        )
