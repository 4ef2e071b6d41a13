"""``sitl campaign SPEC --out DIR``: fly a campaign's missing flights on the local engine
(a process pool, :mod:`sitl.campaign.engine`) or on Ray (``--engine ray``,
:mod:`sitl.campaign.ray_engine`), record each in ``DIR/results.sqlite`` and write
``DIR/report.html``.

The spec's mistakes are one ``error:`` line each (exit status 2) before anything flies. A
spec whose ``autopilots`` name ``px4`` needs the PX4 SITL build (``--px4-dir`` or
``PX4_SITL_DIR``); each such flight runs PX4, the simulator and the companion at the
validated speed (about two cores), so the default number of workers halves.
The same command again flies only the flights not in the table yet; ``--replay ID`` flies
one flight alone, with its log and figures, into ``DIR/replay/ID``.
"""

from __future__ import annotations

import os
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from companion.cli.usage import fail, load_or_exit, output_dir_or_exit
from companion.config import read_toml, read_toml_document
from sitl.campaign.flights import Flight, expand, replay_command, replay_toml, scenario_document
from sitl.campaign.fly import WORK_DIR_VARIABLE
from sitl.campaign.spec import CampaignSpec, load_spec
from sitl.campaign.store import failed, refused
from sitl.cli_options import Px4DirOpt

if TYPE_CHECKING:
    from sitl.campaign.engine import FlightTask

__all__ = ["RESULTS_FILE", "campaign"]

RESULTS_FILE = "results.sqlite"
"""The results table's file in ``--out``."""


class _Progress:
    """One line on stderr: flights done of all, how many did not complete, errors, ETA;
    redrawn in place on a terminal, a line per flight otherwise."""

    def __init__(self, total: int, done: int) -> None:
        self.total, self.done, self.start_done = total, done, done
        self.failed = self.refused = self.errors = 0
        self.t0 = time.monotonic()
        self.tty = sys.stderr.isatty()

    def add(self, row: dict[str, Any]) -> None:
        self.done += 1
        if row["status"] == "error":
            self.errors += 1
        elif refused(row):
            self.refused += 1
        elif failed(row):
            self.failed += 1
        flown = self.done - self.start_done
        rate = (time.monotonic() - self.t0) / flown
        eta = rate * (self.total - self.done)
        line = (
            f"campaign: {self.done}/{self.total} done, {self.failed} not completed, "
            f"{self.refused} refused, {self.errors} errors, ETA {eta / 60:.1f} min"
        )
        if self.tty:
            sys.stderr.write("\r" + line.ljust(78))
            if self.done == self.total:
                sys.stderr.write("\n")
        else:
            sys.stderr.write(line + "\n")
        sys.stderr.flush()


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _load(path: Path) -> tuple[CampaignSpec, list[Flight]]:
    spec = load_spec(path)
    return spec, expand(spec, path)


def campaign(
    spec: Annotated[Path, typer.Argument(help="Campaign spec TOML.", show_default=False)],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Results directory: results.sqlite, report.html, figures, replay/. The same "
            "command with the same --out flies only the missing flights.",
            show_default=False,
        ),
    ],
    workers: Annotated[
        int,
        typer.Option(
            help="Worker processes, or the CPUs of the local Ray runtime [default: the "
            "machine's cores; half of them when the spec flies px4].",
            show_default=False,
        ),
    ] = 0,
    engine: Annotated[
        str,
        typer.Option(
            help="local (a process pool on this machine) or ray (Ray tasks: needs the "
            "campaign extra, pip install -e '.[campaign]')."
        ),
    ] = "local",
    address: Annotated[
        str | None,
        typer.Option(
            help="--engine ray: a running Ray cluster (auto, ray://HOST:PORT or HOST:PORT) "
            "[default: a local Ray runtime of --workers CPUs, started for the campaign].",
            show_default=False,
        ),
    ] = None,
    limit: Annotated[int | None, typer.Option(help="Only the first N flights of the spec.")] = None,
    flight_timeout: Annotated[
        float,
        typer.Option(
            help="Wall seconds after which a flight's worker is stopped (flown once more, "
            "then recorded as an error); a pickup takes 15-40 s."
        ),
    ] = 900.0,
    replay: Annotated[
        str | None,
        typer.Option(help="Fly the flight of this id alone into OUT/replay/ID (log, figures)."),
    ] = None,
    px4_dir: Px4DirOpt = None,
) -> None:
    """Fly a campaign (a spec's flights over a scenario's keys) on this machine's cores,
    one SQLite row per flight, and write report.html."""
    spec_path = spec
    loaded, flights = load_or_exit(spec_path, _load)
    if workers < 0:
        fail(f"--workers must be 1 or more (0: the machine's cores), got {workers}")
    if engine not in ("local", "ray"):
        fail(f"--engine must be local or ray, got {engine!r}")
    if address is not None and engine != "ray":
        fail("--address names a Ray cluster: it needs --engine ray")
    if not flight_timeout > 0.0:
        fail(f"--flight-timeout must be a positive number of seconds, got {flight_timeout:g}")
    if limit is not None:
        if limit < 1:
            fail(f"--limit must be 1 or more, got {limit}")
        flights = flights[:limit]
    if replay is not None:
        _replay(flights, replay, out, spec_path, px4_dir)
        return
    if loaded.flies_px4:
        _use_px4(px4_dir)
    if out.exists() and not out.is_dir():
        fail(f"--out {out}: is a file, not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        fail(f"--out {out}: cannot create ({exc.strerror or exc})")
    cores = os.cpu_count() or 1
    cpus = workers or (max(1, cores // 2) if loaded.flies_px4 else cores)
    _run(loaded, flights, out, spec_path, _Engine(engine, address, cpus), flight_timeout)


def _use_px4(px4_dir: Path | None) -> None:
    """Check the PX4 SITL build the spec's px4 flights need and name it to the workers
    (``PX4_SITL_DIR`` in this process's environment, which they inherit and
    :meth:`~sitl.px4_sitl.launcher.Px4Build.from_env` reads)."""
    from sitl.px4_sitl.launcher import PX4_SITL_DIR_ENV, Px4Build, Px4BuildError

    if px4_dir is None:
        fail("the spec flies px4 (autopilots): pass --px4-dir DIR or set PX4_SITL_DIR")
    try:
        build = Px4Build.at(px4_dir)
    except Px4BuildError as exc:
        fail(str(exc))
    os.environ[PX4_SITL_DIR_ENV] = str(build.root)


class _Engine:
    """Where the flights fly: ``local`` on ``workers`` processes, or ``ray`` (at
    ``address``, or a local runtime of ``workers`` CPUs)."""

    def __init__(self, name: str, address: str | None, workers: int) -> None:
        self.name, self.address, self.workers = name, address, workers

    def describe(self, missing: int) -> str:
        if self.name == "ray":
            where = self.address or f"a local runtime of {self.workers} CPUs"
            return f"on Ray ({where})"
        n = min(self.workers, max(missing, 1))
        return f"on {n} worker{'s' if n > 1 else ''}"

    def run(
        self,
        tasks: list[FlightTask],
        record: Callable[[Flight, dict[str, Any]], None],
        flight_timeout_s: float,
    ) -> None:
        if self.name == "ray":
            from sitl.campaign.ray_engine import RayUnavailableError, run_ray

            try:
                run_ray(
                    tasks,
                    record,
                    address=self.address,
                    cpus=self.workers,
                    flight_timeout_s=flight_timeout_s,
                )
            except RayUnavailableError as exc:
                fail(str(exc))
            return
        from sitl.campaign.engine import run_local

        run_local(tasks, self.workers, record, flight_timeout_s=flight_timeout_s)


def _run(
    spec: CampaignSpec,
    flights: list[Flight],
    out: Path,
    spec_path: Path,
    engine: _Engine,
    flight_timeout_s: float,
) -> None:
    from sitl.campaign.report import write_report
    from sitl.campaign.store import CampaignMismatchError, ResultsStore, identity_columns

    store = ResultsStore(out / RESULTS_FILE)
    try:
        store.open(spec.name, spec.axes)
    except CampaignMismatchError as exc:
        fail(str(exc))
    base_docs: dict[str, dict[str, Any]] = {}
    with store:
        done = store.done()
        missing = [f for f in flights if f.flight_id not in done]
        typer.echo(
            f"campaign {spec.name}: {len(flights)} flights, {len(flights) - len(missing)} in "
            f"{out / RESULTS_FILE}, {len(missing)} to fly {engine.describe(len(missing))}"
        )
        tasks = []
        base_texts: dict[str, str] = {}
        for f in flights:
            if f.base not in base_docs:
                document = load_or_exit(Path(f.base), read_toml_document)
                base_texts[f.base], base_docs[f.base] = document.text, document.data
        for f in missing:
            tasks.append((f, scenario_document(f, base_docs[f.base])))
        progress = _Progress(len(flights), len(flights) - len(missing))

        def record(flight: Flight, row: dict[str, Any]) -> None:
            row = {**identity_columns(flight), **row, "finished_unix_s": time.time()}
            if failed(row) or spec.outside_bounds(row):
                row["replay"] = replay_command(flight, out, spec_path)
                replay_dir = out / "replay"
                replay_dir.mkdir(exist_ok=True)
                (replay_dir / f"{flight.flight_id}.toml").write_text(
                    replay_toml(flight, base_texts[flight.base])
                )
            store.add(row)
            progress.add(row)

        # A SIGTERM (a job scheduler's stop) ends the campaign as Ctrl-C does.
        previous = signal.signal(signal.SIGTERM, _interrupt)
        work = tempfile.mkdtemp(prefix=f"sitl-campaign-{spec.name}-")
        os.environ[WORK_DIR_VARIABLE] = work  # the workers' flights log there (fly.py)
        try:
            if tasks:
                engine.run(tasks, record, flight_timeout_s)
        except KeyboardInterrupt:
            have = len(store.done())
            typer.echo(
                f"\ncampaign {spec.name}: stopped; {have} flights are in "
                f"{out / RESULTS_FILE}; the same command flies the other "
                f"{len(flights) - have}",
                err=True,
            )
            raise typer.Exit(130) from None
        finally:
            signal.signal(signal.SIGTERM, previous)
            shutil.rmtree(work, ignore_errors=True)  # a killed worker's flight left its logs
        ids = {f.flight_id for f in flights}
        rows = [r for r in store.rows() if r["flight_id"] in ids]
    report = write_report(rows, list(spec.axes), out, spec.name, spec.description, spec)
    not_completed = sum(1 for r in rows if failed(r))
    refusals = sum(1 for r in rows if refused(r))
    outside = sum(1 for r in rows if spec.outside_bounds(r))
    bounds = f", {outside} outside the spec's bounds" if spec.bounds else ""
    typer.echo(
        f"campaign {spec.name}: {len(rows)} flights in {out / RESULTS_FILE}, {not_completed} "
        f"did not complete, {refusals} refused (beyond authority){bounds}; report {report}"
    )


def _replay(
    flights: list[Flight], flight_id: str, out: Path, spec_path: Path, px4_dir: Path | None
) -> None:
    """Fly one flight alone; only a px4 flight needs the PX4 build."""
    from sitl.campaign.fly import fly_flight

    chosen = [f for f in flights if f.flight_id == flight_id]
    if not chosen:
        fail(f"--replay {flight_id}: no flight of {spec_path} has this id")
    flight = chosen[0]
    if flight.autopilot == "px4":
        _use_px4(px4_dir)
    where = output_dir_or_exit(out / "replay" / flight.flight_id, ("summary.json",), "--out")
    typer.echo(
        f"replaying flight {flight.flight_id}: {flight.controller}, seed {flight.seed}, "
        f"fault {flight.fault.label()}, {dict(flight.settings)}"
    )
    row = fly_flight(
        flight, scenario_document(flight, load_or_exit(Path(flight.base), read_toml)), keep=where
    )
    if row["status"] == "error":
        typer.echo(row["error"], err=True)
        raise typer.Exit(1)
    figures = [
        f"{label} {row[key] * scale:{form}} {unit}"
        for key, label, scale, form, unit in (
            ("mass_error_pct", "mass error", 1.0, "+.1f", "%"),
            ("com_error_pct", "CoM error", 1.0, "+.1f", "%"),
            ("carry_rms_m", "carry RMS", 100.0, ".1f", "cm"),
        )
        if row.get(key) is not None
    ]
    failure = f" ({row['failure']})" if row.get("failure") else ""
    typer.echo(
        f"{row['outcome']}{failure}{'; ' if figures else ''}{', '.join(figures)}; log and "
        f"figures in {where}"
    )
    raise typer.Exit(0 if row["completed"] else 1)
