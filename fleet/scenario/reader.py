"""Scenario files: which floor, which fleet, which plugins, which jobs, for how long.

A scenario is a TOML file (see ``scenarios/default.toml``) of the structure
`fleet.scenario.spec.ScenarioFile` describes; every key is optional except that a map must be
known. `parse_scenario` converts the file's tables to that structure (msgspec checks types,
ranges and unknown keys), checks what spans keys or needs the disk, and builds the frozen
`Scenario` everything downstream reads. Bad values raise `ScenarioError` naming the file, the
field and the value. Command-line options override the file through `Scenario.override`.
"""

from __future__ import annotations

import copy
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import msgspec

from fleet.errors import ScenarioError
from fleet.printing import PrintSchedule, PrintTask
from fleet.scenario.spec import (
    LATENCY_RULE,
    BreakdownsTable,
    JobsTable,
    NonNegativeInt,
    Positive,
    PositiveInt,
    QualityTable,
    RobotsTable,
    ScenarioFile,
    ScriptedJobTable,
    convert,
)

if TYPE_CHECKING:
    from fleet.printing.quality import QualityModel

__all__ = [
    "RobotsConfig",
    "PluginChoice",
    "ScriptedJob",
    "JobsConfig",
    "BusConfig",
    "BatteryConfig",
    "QualityConfig",
    "BreakdownsConfig",
    "Scenario",
    "Latency",
    "parse_latency",
    "load_scenario",
    "parse_scenario",
    "parse_with_settings",
    "default_scenario",
    "REPO_ROOT",
]

#: The source checkout (maps/ and scenarios/ live here in a development install).
REPO_ROOT = Path(__file__).resolve().parents[2]

#: Compute latency (`Scenario.latency`): None for none, "measured", or fixed seconds.
Latency = float | Literal["measured"] | None


@dataclass(frozen=True)
class RobotsConfig:
    """One group of identical robots: how many, where they start, their limits and period.

    A scenario's fleet is one or more groups (``[robots]`` or ``[[robots]]`` in the file), so
    a fleet can mix robots with different speeds, accelerations and control periods.
    """

    count: int = 4
    start: tuple[str, ...] = ()  # station names, cycled; empty -> the floor's depots
    v_max: float = 1.0
    a_max: float = 0.5
    radius: float = 0.4
    period_s: float = 0.25
    return_home: bool = True  # idle robots drive back to their start position
    #: Turning in place (None: the robot is holonomic and never turns). A robot that sets off
    #: from rest in a new direction first turns on the spot at ``v_max / turn_radius_m`` rad/s
    #: (its wheels, ``turn_radius_m`` from its centre, keep to the speed limit), then settles
    #: for ``turn_settle_s`` seconds.
    turn_radius_m: float | None = None
    turn_settle_s: float = 0.0


@dataclass(frozen=True)
class PluginChoice:
    """A plugin by entry-point name plus the keyword options for its constructor."""

    name: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ScriptedJob:
    """A job released at `at_s` to `station`.

    What the robot prints on the way is either a `part` (a name from the scenario's
    ``[parts]``, analysed from its G-code) or explicit `tasks` (times relative to the print's
    start, which is when the job is assigned). `via` lists stations to pass through, in order,
    before the destination; with `shuttle` the robot drives round them again and again while
    the print lasts, then goes to the destination.
    """

    at_s: float
    station: str
    due_s: float | None = None
    tasks: tuple[PrintTask, ...] = ()
    part: str | None = None
    via: tuple[str, ...] = ()
    shuttle: bool = False


@dataclass(frozen=True)
class JobsConfig:
    """Where jobs come from: Poisson arrivals or a scripted list of "go to station X"."""

    mode: str = "poisson"  # "poisson" or "scripted"
    rate_per_h: float = 60.0
    stations: tuple[str, ...] = ()  # destinations; empty -> every station that is not a depot
    due_in_s: float | None = None  # due time relative to release, for Poisson jobs
    #: Poisson jobs are released until this time (s), then none (None: to the end of the run).
    release_until_s: float | None = None
    scripted: tuple[ScriptedJob, ...] = ()
    parts: tuple[str, ...] = ()  # Poisson jobs print one of these parts, drawn uniformly
    #: A job handed back more often than this (robots blocked, agents failed) is given up.
    max_handbacks: int = 3


@dataclass(frozen=True)
class BusConfig:
    """How the engine waits for robot agents (``[bus]``)."""

    #: Longest wait (s) for an agent's answer in one control round.
    timeout_s: float = 10.0
    #: An agent silent this long (s; no answer, no heartbeat) while a round waits is lost.
    lost_after_s: float = 3.0
    #: Longest message (bytes) the bus takes in or sends (`fleet.bus.schema.MAX_MESSAGE_BYTES`).
    max_message_bytes: int = 2 * 1024 * 1024
    #: "strict": a round waits for the commands, which drive the step after the observation;
    #: "pipelined": they answer the next tick's (predicted) observation and take effect then,
    #: the engine stepping the world meanwhile (`fleet.engine.pipeline`).
    lockstep: str = "strict"
    #: Robots' steps each agent host computes at once, in threads (`fleet.bus.responder`).
    threads: int = 1


@dataclass(frozen=True)
class BatteryConfig:
    """Every robot's battery (``[battery]``; see `fleet.engine.energy`).

    The battery draws `drive_wh_per_m` per metre driven, `print_w` while printing and `idle_w`
    at all times; a charger fills it at `charge_w`. It starts at `initial_share` of
    `capacity_wh`.
    """

    capacity_wh: float = 500.0
    drive_wh_per_m: float = 0.05
    print_w: float = 60.0
    idle_w: float = 0.0
    initial_share: float = 1.0
    charge_w: float = 300.0


@dataclass(frozen=True)
class QualityConfig:
    """How printed parts are judged (see `fleet.printing.quality`).

    `calibration` is a QSP calibration CSV (None: the paper's Table 1); `tolerance_mm` the
    allowed dimensional error per task kind (kinds not listed: `default_tolerance_mm`).
    `scope` "task" judges every print task on its own motion; "print" judges the whole print
    as one task (its mean speed, the strictest tolerance of its tasks, the worst bump): the
    conditions under which the paper measured Tables 1 and 2.
    """

    calibration: Path | None = None
    default_tolerance_mm: float = 0.05
    tolerance_mm: dict[str, float] = field(default_factory=dict)
    speed_metric: str = "mean"
    scope: str = "task"

    def model(self) -> QualityModel:
        """The quality model this configuration describes.

        Contour, infill and support are judged against their tolerances; nozzle travel and the
        skirt, brim or wipe tower ("other") are not part of the finished part, so they are
        judged only when given a tolerance of their own.
        """
        from fleet.printing import quality

        base = (
            quality.default_model()
            if self.calibration is None
            else quality.QualityModel.from_csv(self.calibration)
        )
        tolerances = {kind: self.default_tolerance_mm for kind in ("contour", "infill", "support")}
        tolerances.update(other=math.inf, travel=math.inf)
        tolerances.update(self.tolerance_mm)
        return replace(base, tolerances=tolerances, speed_metric=self.speed_metric)


@dataclass(frozen=True)
class BreakdownsConfig:
    """Random breakdowns (``[breakdowns]``): each robot runs for a time drawn with mean `mtbf_s`
    (from the start, or from its last repair), breaks down, and is repaired where it stopped
    after a time drawn with mean `mttr_s`.

    `failures` is "exponential" or "fixed"; `repairs` "exponential", "lognormal" (coefficient
    of variation `repair_cv`) or "fixed". `groups` holds one ``(mtbf_s, mttr_s)`` per robot
    group, None where the group takes the table's value (empty: every group does). An
    `mtbf_s` of 0 means no breakdowns.
    """

    mtbf_s: float
    mttr_s: float
    failures: str = "exponential"
    repairs: str = "exponential"
    repair_cv: float = 0.5
    groups: tuple[tuple[float | None, float | None], ...] = ()

    def for_group(self, index: int) -> tuple[float, float]:
        """``(mtbf_s, mttr_s)`` of robot group `index` (an mtbf_s of 0: it never breaks down)."""
        mtbf, mttr = self.groups[index] if self.groups else (None, None)
        return (self.mtbf_s if mtbf is None else mtbf, self.mttr_s if mttr is None else mttr)


@dataclass(frozen=True)
class Scenario:
    """A whole run description, validated."""

    name: str
    source: str
    map: Path
    duration_s: float = 600.0
    seed: int = 1
    robots: tuple[RobotsConfig, ...] = (RobotsConfig(),)
    controller: PluginChoice = field(default_factory=lambda: PluginChoice("follower"))
    dispatcher: PluginChoice = field(default_factory=lambda: PluginChoice("greedy"))
    jobs: JobsConfig = field(default_factory=JobsConfig)
    bus_address: str | None = None  # None -> a private inproc:// address
    bus: BusConfig = field(default_factory=BusConfig)
    #: A robot that gets no closer to its goal for this long (s) while robots stand close is
    #: deadlocked (None: no detection).
    deadlock_after_s: float | None = 30.0
    #: Robots with a job wait their turn short of a station another robot with a job is
    #: nearer (`fleet.engine.queueing`); False: they crowd round it.
    station_queue: bool = True
    arrival_tolerance_m: float = 0.05
    sensing_radius_m: float = 0.0  # > 0: observations list the robots this close (nearest 8)
    #: Per-axis speed cap (m/s) of each print task kind; kinds not listed are not capped.
    print_caps: dict[str, float] = field(default_factory=dict)
    #: Whether the print caps are speed limits (checked as violations) or only advice that
    #: controllers see in their observations and may ignore (studies of naive strategies).
    enforce_print_caps: bool = True
    #: Parts jobs may print: name -> G-code file.
    parts: dict[str, Path] = field(default_factory=dict)
    #: Shortest print task (s) after merging the G-code's features (`fleet.printing.gcode`).
    min_task_s: float = 10.0
    #: Overrides of the G-code feature -> task kind table.
    classify: dict[str, str] = field(default_factory=dict)
    quality: QualityConfig = field(default_factory=QualityConfig)
    #: The TOML tables the scenario was read from (empty for one built field by field) and the
    #: file their relative paths are relative to: `fleet.api.change` writes dotted settings
    #: over them and validates them again. Not compared: equal scenarios run alike.
    tables: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)
    origin: Path | None = field(default=None, compare=False, repr=False)
    #: When set, every rough area of the map is also a speed zone with this limit (m/s): the
    #: paper's "varying" strategy, slow over bumps and rough floor.
    rough_v_max: float | None = None
    #: Compute latency (``[scenario] latency``): how long after its tick a command takes
    #: effect. None ("none"): at the tick, as the paper's model assumes; ``"measured"``: after
    #: the controller's own measured step time (`SolveReport.step_s`; 0 without a report), so
    #: the run depends on the wall clock; a number: that many seconds for every controller
    #: command (reproducible). See docs/fleet.md "Compute latency".
    latency: Latency = None
    #: Random breakdowns of robots (``[breakdowns]``; None: none). Drawn from streams of their
    #: own, so switching them on changes no job arrival (`fleet.engine.breakdowns`).
    breakdowns: BreakdownsConfig | None = None
    #: Start-up transient (s) the KPIs leave out (``[scenario] warmup_s``): throughput, lead
    #: times, waits and state shares are measured over [warmup_s, the run's end).
    warmup_s: float = 0.0
    #: Robots' batteries (``[battery]``); None: they never run out (no chargers are used).
    battery: BatteryConfig | None = None
    #: The charging policy (``[charging]``), used only with `battery`.
    charging: PluginChoice = field(default_factory=lambda: PluginChoice("threshold"))

    def print_schedule(self, job: ScriptedJob) -> PrintSchedule | None:
        """The print schedule of a scripted job under this scenario's caps (None: no print)."""
        if not job.tasks:
            return None
        return PrintSchedule(job.tasks, self.print_caps)

    def override(
        self,
        *,
        map: str | Path | None = None,
        robots: int | None = None,
        controller: str | None = None,
        dispatcher: str | None = None,
        duration: float | None = None,
        seed: int | None = None,
        latency: str | float | None = None,
        controller_options: Mapping[str, Any] | None = None,
        threads: int | None = None,
    ) -> Scenario:
        """A copy with command-line overrides applied and validated.

        `latency` takes what ``--latency`` takes: ``"none"``, ``"measured"`` or seconds >= 0
        (a number or its text); None leaves the scenario's setting. `threads` sets ``[bus]
        threads`` (``--threads``).

        A `controller` that is the scenario's own keeps its options; another one gets only
        `controller_options` (those given with it, ``--set controller.options.*``): the file's
        options were written for another plugin.
        """
        src = "command line"
        out = self
        if map is not None:
            path = Path(map)
            if not path.is_file():
                raise ScenarioError(src, "--map", str(map), "no such map file")
            out = replace(out, map=path.resolve())
        if robots is not None:
            count = convert(robots, PositiveInt, src, "--robots")
            if len(out.robots) != 1:
                raise ScenarioError(
                    src,
                    "--robots",
                    robots,
                    f"{out.source} defines {len(out.robots)} robot groups; set each group's "
                    "count in the file",
                )
            out = replace(out, robots=(replace(out.robots[0], count=count),))
        if controller is not None and controller != out.controller.name:
            out = replace(out, controller=PluginChoice(controller, dict(controller_options or {})))
        if dispatcher is not None:
            out = replace(out, dispatcher=PluginChoice(dispatcher))
        if duration is not None:
            out = replace(out, duration_s=convert(duration, Positive, src, "--duration"))
        if seed is not None:
            out = replace(out, seed=convert(seed, NonNegativeInt, src, "--seed"))
        if latency is not None:
            out = replace(out, latency=parse_latency(src, "--latency", latency, parse_text=True))
            check_lockstep(out, "--latency")
        if threads is not None:
            out = replace(
                out, bus=replace(out.bus, threads=convert(threads, PositiveInt, src, "--threads"))
            )
        return out


def default_scenario() -> Scenario:
    """The scenario `fleet run` uses without a file: ``scenarios/default.toml``."""
    return load_scenario(REPO_ROOT / "scenarios" / "default.toml")


def load_scenario(
    path: str | Path,
    settings: Mapping[str, Any] | None = None,
    *,
    settings_source: str = "--set",
) -> Scenario:
    """Read and validate a scenario file; relative paths in it are relative to the file.

    Parameters
    ----------
    path:
        The scenario TOML.
    settings:
        Values written over the file's before it is checked, by dotted key (``robots.count``,
        ``controller.options.horizon``), typed as TOML values are (``fleet run --set``). File
        names among them (``scenario.map``, ``parts.<name>``, ``quality.calibration``) are
        relative to the current directory, not to the file.
    settings_source:
        How errors name where the settings came from.

    Raises
    ------
    ScenarioError
        Naming the file, or `settings_source` when a setting is what is wrong, with the field
        and the value.
    """
    path = Path(path)
    src = str(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ScenarioError(src, "(file)", src, "no such scenario file") from None
    except IsADirectoryError:
        raise ScenarioError(
            src, "(file)", src, "cannot read the scenario file: it is a directory"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(src, "(file)", src, f"cannot read the scenario file: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(src, "(syntax)", str(exc), "the file must be valid TOML") from None
    return parse_with_settings(raw, path, settings, settings_source=settings_source)


def parse_with_settings(
    raw: dict[str, Any],
    path: str | Path,
    settings: Mapping[str, Any] | None,
    *,
    source: str | None = None,
    settings_source: str = "--set",
) -> Scenario:
    """`parse_scenario` of `raw` (left as it is) with `settings` written over it by dotted key,
    as `load_scenario` takes them; an error a setting causes names `settings_source`, the key
    and the value. `fleet.api.change` applies settings to a scenario's tables this way."""
    if not settings:
        return parse_scenario(raw, path, source=source)
    raw = copy.deepcopy(raw)
    for key, value in settings.items():
        _put_setting(raw, key, value, settings_source)
    try:
        return parse_scenario(raw, path, source=source)
    except ScenarioError as exc:
        if not any(_within(exc.field, key) for key in settings):
            raise
        raise ScenarioError(settings_source, exc.field, exc.value, exc.rule) from None


#: Settings whose values are file names, read relative to the current directory.
_PATH_SETTINGS = re.compile(r"^(scenario\.map|quality\.calibration|parts\.[^.]+)$")


def _put_setting(raw: dict[str, Any], key: str, value: Any, source: str) -> None:
    """Write `value` at the dotted `key` of the scenario's tables, making tables on the way."""
    parts = key.split(".")
    if not all(parts):
        raise ScenarioError(source, key, value, "a key is a dotted path like robots.count")
    if isinstance(value, str) and _PATH_SETTINGS.match(key):
        value = str(Path(value).resolve())
    table = raw
    for depth, part in enumerate(parts[:-1]):
        inner = table.setdefault(part, {})
        if not isinstance(inner, dict):
            where = ".".join(parts[: depth + 1])
            raise ScenarioError(
                source,
                key,
                value,
                f"{where} is not a table in the scenario ({type(inner).__name__}), so it has no "
                f"key {parts[depth + 1]!r}",
            )
        table = inner
    table[parts[-1]] = value


def _within(field: str, key: str) -> bool:
    """Whether the error's `field` is the setting `key`, inside it, or a table holding it."""
    return (
        field == key
        or field.startswith((key + ".", key + "["))
        or key.startswith((field + ".", field + "["))
    )


def parse_scenario(raw: dict[str, Any], path: str | Path, *, source: str | None = None) -> Scenario:
    """Validate a scenario's TOML tables `raw` as if read from the file `path`.

    Relative paths in `raw` (map, parts, calibration) are relative to `path`'s folder, and
    errors name `source` (default: `path`). `fleet.study.sweep` uses this to validate a
    scenario with a study cell's values written over the file's.
    """
    path = Path(path)
    src = source if source is not None else str(path)
    file: ScenarioFile = convert(raw, ScenarioFile, src)
    sc = file.scenario
    map_path = (path.parent / sc.map).resolve()
    if not map_path.is_file():
        raise ScenarioError(src, "scenario.map", sc.map, f"no such map file ({map_path})")
    groups = [file.robots] if isinstance(file.robots, RobotsTable) else file.robots
    parts = _parts(src, file.parts, path.parent)
    jobs = _jobs(src, file.jobs, parts)
    quality = _quality(src, file.quality, path.parent)
    caps = file.printing.caps
    if caps == "quality":
        caps = {k: c for k, c in quality.model().caps().items() if math.isfinite(c)}
    bus = file.bus
    if bus.lost_after_s > bus.timeout_s:
        raise ScenarioError(
            src,
            "bus.lost_after_s",
            bus.lost_after_s,
            f"must not exceed bus.timeout_s ({bus.timeout_s:g})",
        )
    scenario = Scenario(
        name=path.stem if sc.name is None else sc.name,
        source=src,
        tables=copy.deepcopy(raw),
        origin=path,
        map=map_path,
        duration_s=sc.duration_s,
        seed=sc.seed,
        robots=tuple(
            RobotsConfig(
                count=g.count,
                start=tuple(g.start),
                v_max=g.v_max,
                a_max=g.a_max,
                radius=g.radius,
                period_s=g.period_s,
                return_home=g.return_home,
                turn_radius_m=g.turn_radius_m,
                turn_settle_s=g.turn_settle_s,
            )
            for g in groups
        ),
        controller=PluginChoice(file.controller.name, file.controller.options),
        dispatcher=PluginChoice(file.dispatcher.name, file.dispatcher.options),
        jobs=jobs,
        bus_address=bus.address,
        bus=BusConfig(
            bus.timeout_s, bus.lost_after_s, bus.max_message_bytes, bus.lockstep, bus.threads
        ),
        deadlock_after_s=sc.deadlock_after_s or None,
        station_queue=sc.station_queue,
        arrival_tolerance_m=sc.arrival_tolerance_m,
        sensing_radius_m=sc.sensing_radius_m,
        print_caps=caps,
        enforce_print_caps=file.printing.enforce,
        parts=parts,
        min_task_s=file.printing.min_task_s,
        classify=file.printing.classify,
        quality=quality,
        rough_v_max=file.floor.rough_v_max,
        latency=None if sc.latency == "none" else sc.latency,
        warmup_s=sc.warmup_s,
        battery=None
        if file.battery is None
        else BatteryConfig(**msgspec.structs.asdict(file.battery)),
        charging=PluginChoice(file.charging.name, file.charging.options),
        breakdowns=_breakdowns(src, file.breakdowns, len(groups), raw.get("breakdowns")),
    )
    check_warmup(scenario)
    check_lockstep(scenario)
    return scenario


def check_fleet(scenario: Scenario, clearance: float | None = None) -> None:
    """The rules across fields that a fleet must keep, for a scenario read from a file, changed
    on the command line or built in code alike (`fleet.engine.World` asks).

    - Robots that see each other (more than one, `sensing_radius_m` > 0) cover at most their
      own diameter per axis in one control period at full speed (``v_max * period_s <=
      2 * radius``): they observe each other only at their ticks, and two robots that each move
      further than that unseen can cross where the other will be before either sees it
      (`scripts/fuzz_floors.py` found contacts at 1 s periods with v_max 1 and radius 0.4, for
      both built-in controllers, and none at 0.5 s).
    - Robots that see each other see far enough to stop for each other: `sensing_radius_m`
      is at least `sensing_needed` (for two robots of one group ``2 * radius + sqrt(2) *
      (v_max**2 / a_max + 4 * v_max * period_s)``). The floor fuzz had two MPC robots at 1 s
      periods drive through each other from outside a 3.3 m sensing radius, never seen.
    - With the floor's `clearance` given and above 0: no robot is wider than it. The free space
      is the map's open area shrunk by the clearance, so a larger robot would overlap walls and
      obstacles while its centre stays in the free space. (A clearance of 0 models robots as
      points against walls, as the paper's case studies do; they still keep their radii apart
      from each other.)
    """
    groups = scenario.robots
    fleet = sum(g.count for g in groups) > 1 and scenario.sensing_radius_m > 0
    for i, g in enumerate(groups):
        where = "robots" if len(groups) == 1 else f"robots[{i}]"
        if fleet and g.v_max * g.period_s > 2.0 * g.radius + 1e-9:
            raise ScenarioError(
                scenario.source,
                f"{where}.period_s",
                g.period_s,
                f"robots that see each other must not move more than their diameter per axis "
                f"in one period: v_max * period_s = {g.v_max * g.period_s:g} m > 2 * radius = "
                f"{2.0 * g.radius:g} m; use period_s <= {2.0 * g.radius / g.v_max:g}",
            )
        for j, h in enumerate(groups[: i + 1]):
            needed = sensing_needed(g, h)
            if fleet and scenario.sensing_radius_m < needed - 1e-9:
                pair = where if i == j else f"robots[{j}] and {where}"
                raise ScenarioError(
                    scenario.source,
                    "scenario.sensing_radius_m",
                    scenario.sensing_radius_m,
                    f"robots that see each other must see far enough to stop for each other: "
                    f"at least {math.ceil(needed * 100) / 100:g} m for {pair} (radius + radius "
                    f"+ sqrt(2) * (v_max**2 / (2 * a_max) + 2 * v_max * period_s) of each: "
                    f"v_max bounds each axis, so on a diagonal a robot goes sqrt(2) * v_max)",
                )
        if clearance and g.radius > clearance + 1e-9:
            raise ScenarioError(
                scenario.source,
                f"{where}.radius",
                g.radius,
                f"wider than the map's floor.clearance ({clearance:g} m), the room the map keeps "
                "round walls and obstacles: raise the clearance in the map or use a smaller radius",
            )


def sensing_needed(one: RobotsConfig, other: RobotsConfig) -> float:
    """The least sensing radius (m) at which a robot of group `one` and one of group `other`
    (the same group or not) see each other early enough to stop for each other:
    ``r1 + r2 + sqrt(2) * (reach(one) + reach(other))``, with each robot's
    ``reach = v_max**2 / (2 * a_max) + 2 * v_max * period_s``: its braking distance from full
    speed, half a period the discrete step travels on at the present speed, a period unseen
    (robots observe each other only at their ticks), a period to react and half a period more
    (a higher-priority robot keeps its course one tick until the lower one is close). `v_max`
    and `a_max` bound each axis, so on a diagonal a robot goes sqrt(2) times as fast and brakes
    over sqrt(2) times the distance. For two robots of one group: ``2 * radius + sqrt(2) *
    (v_max**2 / a_max + 4 * v_max * period_s)``."""

    def reach(g: RobotsConfig) -> float:
        return g.v_max**2 / (2.0 * g.a_max) + 2.0 * g.v_max * g.period_s

    return one.radius + other.radius + math.sqrt(2.0) * (reach(one) + reach(other))


def check_warmup(scenario: Scenario) -> None:
    """`Scenario.warmup_s` is a number >= 0 and shorter than the run (`duration_s`, however it
    was set: file, ``--duration`` or code); `ScenarioError` naming the file and field otherwise."""
    w = scenario.warmup_s
    if isinstance(w, bool) or not isinstance(w, int | float) or not (0 <= w < math.inf):
        raise ScenarioError(scenario.source, "scenario.warmup_s", w, "must be a number >= 0")
    if w >= scenario.duration_s:
        raise ScenarioError(
            scenario.source,
            "scenario.warmup_s",
            w,
            f"must be less than the run's duration_s ({scenario.duration_s:g} s): the KPIs are "
            "measured after the warm-up",
        )


def check_lockstep(scenario: Scenario, fld: str = "scenario.latency") -> None:
    """A pipelined lockstep (``[bus] lockstep = "pipelined"``) has no compute latency: its
    commands already take effect one tick late; `ScenarioError` naming the file (`fld`:
    where the latency was set) otherwise."""
    bus = scenario.bus
    if bus.lockstep not in ("strict", "pipelined"):
        raise ScenarioError(
            scenario.source, "bus.lockstep", bus.lockstep, 'must be "strict" or "pipelined"'
        )
    if bus.lockstep == "pipelined" and scenario.latency is not None:
        raise ScenarioError(
            scenario.source,
            fld,
            scenario.latency,
            'must be "none" with bus.lockstep = "pipelined" (its commands already take effect'
            " one tick after the state they answer)",
        )


def parse_latency(src: str, fld: str, value: Any, *, parse_text: bool = False) -> Latency:
    """Read a latency setting: "none", "measured" or seconds >= 0 (with `parse_text`, also
    seconds written as text, as on the command line); `ScenarioError` naming `src` and `fld`
    otherwise."""
    if isinstance(value, str):
        word = value.strip()
        if word == "none":
            return None
        if word == "measured":
            return "measured"
        if parse_text:
            try:
                number = float(word)
            except ValueError:
                number = math.nan
            if math.isfinite(number) and number >= 0:
                return number
        raise ScenarioError(src, fld, value, LATENCY_RULE)
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value < 0
    ):
        raise ScenarioError(src, fld, value, LATENCY_RULE)
    return float(value)


def _parts(src: str, files: dict[str, str], folder: Path) -> dict[str, Path]:
    """The ``[parts]`` G-code files, which must exist."""
    parts = {}
    for part, file in files.items():
        gcode = (folder / file).resolve()
        if not gcode.is_file():
            raise ScenarioError(src, f"parts.{part}", file, f"no such G-code file ({gcode})")
        parts[part] = gcode
    return parts


def _jobs(src: str, jobs: JobsTable, parts: dict[str, Path]) -> JobsConfig:
    """``[jobs]``, whose scripted jobs and parts must make sense together."""
    scripted = tuple(_scripted_job(src, i, job) for i, job in enumerate(jobs.scripted))
    if jobs.mode == "scripted" and not scripted:
        raise ScenarioError(src, "jobs.scripted", [], "mode 'scripted' needs at least one job")
    for i, part in enumerate(jobs.parts):
        if part not in parts:
            raise ScenarioError(src, f"jobs.parts[{i}]", part, _unknown_part(parts))
    for i, job in enumerate(scripted):
        if job.part is not None and job.part not in parts:
            raise ScenarioError(src, f"jobs.scripted[{i}].part", job.part, _unknown_part(parts))
    return JobsConfig(
        mode=jobs.mode,
        rate_per_h=jobs.rate_per_h,
        stations=tuple(jobs.stations),
        due_in_s=jobs.due_in_s,
        release_until_s=jobs.release_until_s,
        scripted=scripted,
        parts=tuple(jobs.parts),
        max_handbacks=jobs.max_handbacks,
    )


def _scripted_job(src: str, i: int, job: ScriptedJobTable) -> ScriptedJob:
    where = f"jobs.scripted[{i}]"
    if job.part is not None and job.tasks:
        raise ScenarioError(src, f"{where}.part", job.part, "give either part or print, not both")
    if job.shuttle and not job.via:
        raise ScenarioError(src, f"{where}.shuttle", job.shuttle, "shuttle needs via stations")
    tasks: list[PrintTask] = []
    for k, task in enumerate(job.tasks):
        if task.end_s <= task.start_s:
            raise ScenarioError(
                src,
                f"{where}.print[{k}].end_s",
                task.end_s,
                f"must be after start_s ({task.start_s:g})",
            )
        if tasks and task.start_s < tasks[-1].end_s:
            raise ScenarioError(
                src,
                f"{where}.print[{k}].start_s",
                task.start_s,
                f"tasks must be in order and not overlap (the previous one ends at "
                f"{tasks[-1].end_s:g} s)",
            )
        tasks.append(PrintTask(task.kind, task.start_s, task.end_s))
    return ScriptedJob(
        at_s=job.at_s,
        station=job.station,
        due_s=job.due_s,
        tasks=tuple(tasks),
        part=job.part,
        via=tuple(job.via),
        shuttle=job.shuttle,
    )


def _breakdowns(
    src: str, table: BreakdownsTable | None, groups: int, raw: Any
) -> BreakdownsConfig | None:
    """``[breakdowns]`` (`raw` as written), whose `groups` has one entry per robot group."""
    if table is None:
        return None
    if table.groups and len(table.groups) != groups:
        raise ScenarioError(
            src,
            "breakdowns.groups",
            raw["groups"],
            f"needs one entry per robot group ({groups}), in the order of the [[robots]] groups",
        )
    return BreakdownsConfig(
        mtbf_s=table.mtbf_s,
        mttr_s=table.mttr_s,
        failures=table.failures,
        repairs=table.repairs,
        repair_cv=table.repair_cv,
        groups=tuple((g.mtbf_s, g.mttr_s) for g in table.groups),
    )


def _unknown_part(parts: dict[str, Path]) -> str:
    known = ", ".join(sorted(parts)) or "none: add a [parts] table"
    return f"no such part in [parts] (known: {known})"


def _quality(src: str, quality: QualityTable, folder: Path) -> QualityConfig:
    """``[quality]``, whose calibration file must exist."""
    calibration = None
    if quality.calibration is not None:
        calibration = (folder / quality.calibration).resolve()
        if not calibration.is_file():
            raise ScenarioError(
                src, "quality.calibration", quality.calibration, f"no such CSV file ({calibration})"
            )
    tolerance = quality.tolerance_mm
    return QualityConfig(
        calibration=calibration,
        default_tolerance_mm=0.05 if isinstance(tolerance, dict) else tolerance,
        tolerance_mm=tolerance if isinstance(tolerance, dict) else {},
        speed_metric=quality.speed_metric,
        scope=quality.scope,
    )
