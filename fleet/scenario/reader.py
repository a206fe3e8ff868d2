"""Scenario files: which floor, which fleet, which plugins, which jobs, for how long.

A scenario is a TOML file (see ``scenarios/default.toml``); every key is optional except that a
map must be known. Unknown keys and bad values raise `ScenarioError` naming the file, the field
and the value. Command-line options override the file through `Scenario.override`.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from fleet.errors import ScenarioError
from fleet.printing import TASK_KINDS, PrintSchedule, PrintTask

if TYPE_CHECKING:
    from fleet.printing.quality import QualityModel

__all__ = [
    "RobotsConfig",
    "PluginChoice",
    "ScriptedJob",
    "JobsConfig",
    "BusConfig",
    "QualityConfig",
    "Scenario",
    "Latency",
    "parse_latency",
    "load_scenario",
    "parse_scenario",
    "default_scenario",
    "REPO_ROOT",
]

#: The source checkout (maps/ and scenarios/ live here in a development install).
REPO_ROOT = Path(__file__).resolve().parents[2]

#: Compute latency (`Scenario.latency`): None for none, "measured", or fixed seconds.
Latency = float | Literal["measured"] | None

_LATENCY_RULE = (
    'must be "none" (commands apply at once), "measured" (each command waits its '
    "controller's measured step time) or a number of seconds >= 0 (a fixed latency)"
)


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
    #: When set, every rough area of the map is also a speed zone with this limit (m/s): the
    #: paper's "varying" strategy, slow over bumps and rough floor.
    rough_v_max: float | None = None
    #: Compute latency (``[scenario] latency``): how long after its tick a command takes
    #: effect. None ("none"): at the tick, as the paper's model assumes; ``"measured"``: after
    #: the controller's own measured step time (`SolveReport.step_s`; 0 without a report), so
    #: the run depends on the wall clock; a number: that many seconds for every controller
    #: command (reproducible). See docs/fleet.md "Compute latency".
    latency: Latency = None

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
    ) -> Scenario:
        """A copy with command-line overrides applied and validated.

        `latency` takes what ``--latency`` takes: ``"none"``, ``"measured"`` or seconds >= 0
        (a number or its text); None leaves the scenario's setting.
        """
        src = "command line"
        out = self
        if map is not None:
            path = Path(map)
            if not path.is_file():
                raise ScenarioError(src, "--map", str(map), "no such map file")
            out = replace(out, map=path.resolve())
        if robots is not None:
            count = _positive_int(src, "--robots", robots)
            if len(out.robots) != 1:
                raise ScenarioError(
                    src,
                    "--robots",
                    robots,
                    f"{out.source} defines {len(out.robots)} robot groups; set each group's "
                    "count in the file",
                )
            out = replace(out, robots=(replace(out.robots[0], count=count),))
        if controller is not None:
            out = replace(out, controller=PluginChoice(controller))
        if dispatcher is not None:
            out = replace(out, dispatcher=PluginChoice(dispatcher))
        if duration is not None:
            out = replace(out, duration_s=_positive(src, "--duration", duration))
        if seed is not None:
            out = replace(out, seed=_seed(src, "--seed", seed))
        if latency is not None:
            out = replace(out, latency=parse_latency(src, "--latency", latency, parse_text=True))
        return out


def default_scenario() -> Scenario:
    """The scenario `fleet run` uses without a file: ``scenarios/default.toml``."""
    return load_scenario(REPO_ROOT / "scenarios" / "default.toml")


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file; relative paths in it are relative to the file."""
    path = Path(path)
    src = str(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ScenarioError(src, "(file)", src, "no such scenario file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(src, "(syntax)", str(exc), "the file must be valid TOML") from None
    return parse_scenario(raw, path)


def parse_scenario(raw: dict[str, Any], path: str | Path, *, source: str | None = None) -> Scenario:
    """Validate a scenario's TOML tables `raw` as if read from the file `path`.

    Relative paths in `raw` (map, parts, calibration) are relative to `path`'s folder, and
    errors name `source` (default: `path`). `fleet.study.sweep` uses this to validate a
    scenario with a study cell's values written over the file's.
    """
    path = Path(path)
    src = source if source is not None else str(path)
    root = _Table(src, "", raw)
    sc = root.table("scenario")
    name = sc.take("name", str, path.stem)
    map_value = sc.take("map", str, required=True)
    map_path = (path.parent / map_value).resolve()
    if not map_path.is_file():
        raise ScenarioError(src, "scenario.map", map_value, f"no such map file ({map_path})")
    duration = _positive(src, "scenario.duration_s", sc.take("duration_s", (int, float), 600.0))
    seed = _seed(src, "scenario.seed", sc.take("seed", int, 1))
    tol = _positive(
        src, "scenario.arrival_tolerance_m", sc.take("arrival_tolerance_m", (int, float), 0.05)
    )
    sensing = _non_negative(
        src, "scenario.sensing_radius_m", sc.take("sensing_radius_m", (int, float), 0.0)
    )
    deadlock = _non_negative(
        src, "scenario.deadlock_after_s", sc.take("deadlock_after_s", (int, float), 30.0)
    )
    latency = parse_latency(src, "scenario.latency", sc.take_any("latency", "none"))
    sc.finish()

    groups = root.take("robots", (dict, list), {})
    if isinstance(groups, dict):
        robots = (_robots(_Table(src, "robots.", groups), src, "robots"),)
    elif not groups:
        raise ScenarioError(src, "robots", [], "needs at least one [[robots]] group")
    else:
        robots = tuple(
            _robots(_Table(src, f"robots[{i}].", g), src, f"robots[{i}]")
            for i, g in enumerate(groups)
        )

    controller = _plugin(root, "controller", "follower")
    dispatcher = _plugin(root, "dispatcher", "greedy")

    jb = root.table("jobs")
    mode = jb.take("mode", str, "poisson")
    if mode not in ("poisson", "scripted"):
        raise ScenarioError(src, "jobs.mode", mode, "must be 'poisson' or 'scripted'")
    rate = _positive(src, "jobs.rate_per_h", jb.take("rate_per_h", (int, float), 60.0))
    stations = tuple(jb.take_list("stations", str, ()))
    due_in = jb.take("due_in_s", (int, float), None)
    if due_in is not None:
        _positive(src, "jobs.due_in_s", due_in)
    scripted = []
    for i, item in enumerate(jb.take_list("scripted", dict, ())):
        t = _Table(src, f"jobs.scripted[{i}].", item)
        at = _non_negative(
            src, f"jobs.scripted[{i}].at_s", t.take("at_s", (int, float), required=True)
        )
        station = t.take("station", str, required=True)
        due = t.take("due_s", (int, float), None)
        tasks = _print_tasks(src, f"jobs.scripted[{i}].print", t.take_list("print", dict, ()))
        part = t.take("part", str, None)
        if part is not None and tasks:
            raise ScenarioError(
                src, f"jobs.scripted[{i}].part", part, "give either part or print, not both"
            )
        via = tuple(t.take_list("via", str, ()))
        shuttle = t.take("shuttle", bool, False)
        if shuttle and not via:
            raise ScenarioError(
                src, f"jobs.scripted[{i}].shuttle", shuttle, "shuttle needs via stations"
            )
        t.finish()
        scripted.append(
            ScriptedJob(
                float(at),
                station,
                None if due is None else float(due),
                tasks,
                part,
                via,
                shuttle,
            )
        )
    if mode == "scripted" and not scripted:
        raise ScenarioError(src, "jobs.scripted", [], "mode 'scripted' needs at least one job")
    job_parts = tuple(jb.take_list("parts", str, ()))
    handbacks = jb.take("max_handbacks", int, 3)
    if isinstance(handbacks, bool) or handbacks < 0:
        raise ScenarioError(src, "jobs.max_handbacks", handbacks, "must be an integer >= 0")
    jb.finish()
    jobs = JobsConfig(
        mode,
        float(rate),
        stations,
        None if due_in is None else float(due_in),
        tuple(scripted),
        job_parts,
        handbacks,
    )

    parts: dict[str, Path] = {}
    for part, file in root.take("parts", dict, {}).items():
        if not isinstance(file, str):
            raise ScenarioError(src, f"parts.{part}", file, "must be a G-code file name (string)")
        gcode = (path.parent / file).resolve()
        if not gcode.is_file():
            raise ScenarioError(src, f"parts.{part}", file, f"no such G-code file ({gcode})")
        parts[part] = gcode
    for i, part in enumerate(job_parts):
        if part not in parts:
            raise ScenarioError(src, f"jobs.parts[{i}]", part, _unknown_part(parts))
    for i, item in enumerate(scripted):
        if item.part is not None and item.part not in parts:
            raise ScenarioError(src, f"jobs.scripted[{i}].part", item.part, _unknown_part(parts))

    pr = root.table("print")
    caps_value = pr.take("caps", (dict, str), {})
    caps = {}
    if isinstance(caps_value, str) and caps_value != "quality":
        raise ScenarioError(
            src,
            "print.caps",
            caps_value,
            'must be a table of caps per kind, e.g. { contour = 0.3 }, or "quality" (the '
            "QSP's fastest speed within each kind's [quality] tolerance)",
        )
    for kind, cap in ({} if isinstance(caps_value, str) else caps_value).items():
        _check_kind(src, f"print.caps.{kind}", cap, kind)
        caps[kind] = _positive(src, f"print.caps.{kind}", cap)
    enforce = pr.take("enforce", bool, True)
    min_task = _non_negative(src, "print.min_task_s", pr.take("min_task_s", (int, float), 10.0))
    classify = {}
    for feature, kind in pr.take("classify", dict, {}).items():
        _check_kind(src, f"print.classify.{feature}", kind, kind)
        classify[feature] = kind
    pr.finish()

    quality = _quality(root.table("quality"), path)
    if caps_value == "quality":
        caps = {k: c for k, c in quality.model().caps().items() if math.isfinite(c)}
    fl = root.table("floor")
    rough = fl.take("rough_v_max", (int, float), None)
    if rough is not None:
        rough = _positive(src, "floor.rough_v_max", rough)
    fl.finish()

    bus = root.table("bus")
    address = bus.take("address", str, None)
    if address is not None and not address.startswith(("inproc://", "ipc://", "tcp://")):
        raise ScenarioError(
            src, "bus.address", address, "must start with inproc://, ipc:// or tcp://"
        )
    timeout = _positive(src, "bus.timeout_s", bus.take("timeout_s", (int, float), 10.0))
    lost_after = _positive(src, "bus.lost_after_s", bus.take("lost_after_s", (int, float), 3.0))
    if lost_after > timeout:
        raise ScenarioError(
            src, "bus.lost_after_s", lost_after, f"must not exceed bus.timeout_s ({timeout:g})"
        )
    bus.finish()
    root.finish()
    return Scenario(
        name=name,
        source=src,
        map=map_path,
        duration_s=float(duration),
        seed=seed,
        robots=robots,
        controller=controller,
        dispatcher=dispatcher,
        jobs=jobs,
        bus_address=address,
        bus=BusConfig(timeout, lost_after),
        deadlock_after_s=deadlock or None,
        arrival_tolerance_m=float(tol),
        sensing_radius_m=float(sensing),
        print_caps=caps,
        enforce_print_caps=enforce,
        parts=parts,
        min_task_s=float(min_task),
        classify=classify,
        quality=quality,
        rough_v_max=rough,
        latency=latency,
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
        raise ScenarioError(src, fld, value, _LATENCY_RULE)
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value < 0
    ):
        raise ScenarioError(src, fld, value, _LATENCY_RULE)
    return float(value)


def _check_kind(src: str, fld: str, value: Any, kind: str) -> None:
    """`kind` must be a task kind; `value` is what the file wrote at `fld`."""
    if kind not in TASK_KINDS:
        raise ScenarioError(src, fld, value, f"unknown task kind (known: {', '.join(TASK_KINDS)})")


def _unknown_part(parts: dict[str, Path]) -> str:
    known = ", ".join(sorted(parts)) or "none: add a [parts] table"
    return f"no such part in [parts] (known: {known})"


def _quality(q: _Table, path: Path) -> QualityConfig:
    src = q.source
    calibration = q.take("calibration", str, None)
    cal_path = None
    if calibration is not None:
        cal_path = (path.parent / calibration).resolve()
        if not cal_path.is_file():
            raise ScenarioError(
                src, "quality.calibration", calibration, f"no such CSV file ({cal_path})"
            )
    tol = q.take("tolerance_mm", (int, float, dict), 0.05)
    default_tol, per_kind = 0.05, {}
    if isinstance(tol, dict):
        for kind, value in tol.items():
            _check_kind(src, f"quality.tolerance_mm.{kind}", value, kind)
            per_kind[kind] = _positive(src, f"quality.tolerance_mm.{kind}", value)
    else:
        default_tol = _positive(src, "quality.tolerance_mm", tol)
    metric = q.take("speed_metric", str, "mean")
    if metric not in ("mean", "max"):
        raise ScenarioError(src, "quality.speed_metric", metric, "must be 'mean' or 'max'")
    scope = q.take("scope", str, "task")
    if scope not in ("task", "print"):
        raise ScenarioError(src, "quality.scope", scope, "must be 'task' or 'print'")
    q.finish()
    return QualityConfig(cal_path, default_tol, per_kind, metric, scope)


def _print_tasks(src: str, where: str, items: list[dict]) -> tuple[PrintTask, ...]:
    """Read ``print = [{kind, start_s, end_s}, ...]``: in order, not overlapping."""
    tasks: list[PrintTask] = []
    for i, item in enumerate(items):
        t = _Table(src, f"{where}[{i}].", item)
        kind = t.take("kind", str, required=True)
        _check_kind(src, f"{where}[{i}].kind", kind, kind)
        start = _non_negative(
            src, f"{where}[{i}].start_s", t.take("start_s", (int, float), required=True)
        )
        end = _positive(src, f"{where}[{i}].end_s", t.take("end_s", (int, float), required=True))
        t.finish()
        if end <= start:
            raise ScenarioError(
                src, f"{where}[{i}].end_s", end, f"must be after start_s ({start:g})"
            )
        if tasks and start < tasks[-1].end_s:
            raise ScenarioError(
                src,
                f"{where}[{i}].start_s",
                start,
                f"tasks must be in order and not overlap (the previous one ends at "
                f"{tasks[-1].end_s:g} s)",
            )
        tasks.append(PrintTask(kind, start, end))
    return tuple(tasks)


def _robots(rb: _Table, src: str, where: str) -> RobotsConfig:
    group = RobotsConfig(
        count=_positive_int(src, f"{where}.count", rb.take("count", int, 4)),
        start=tuple(rb.take_list("start", str, ())),
        v_max=_positive(src, f"{where}.v_max", rb.take("v_max", (int, float), 1.0)),
        a_max=_positive(src, f"{where}.a_max", rb.take("a_max", (int, float), 0.5)),
        radius=_positive(src, f"{where}.radius", rb.take("radius", (int, float), 0.4)),
        period_s=_positive(src, f"{where}.period_s", rb.take("period_s", (int, float), 0.25)),
        return_home=rb.take("return_home", bool, True),
        turn_radius_m=_optional_positive(
            src, f"{where}.turn_radius_m", rb.take("turn_radius_m", (int, float), None)
        ),
        turn_settle_s=_non_negative(
            src, f"{where}.turn_settle_s", rb.take("turn_settle_s", (int, float), 0.0)
        ),
    )
    rb.finish()
    return group


def _plugin(root: _Table, key: str, default: str) -> PluginChoice:
    t = root.table(key)
    name = t.take("name", str, default)
    options = t.take("options", dict, {})
    t.finish()
    return PluginChoice(name, dict(options))


class _Table:
    """Reads one TOML table strictly: typed fields, and no key left unread."""

    def __init__(self, source: str, prefix: str, data: Any) -> None:
        if not isinstance(data, dict):
            raise ScenarioError(
                source, prefix.rstrip(".") or "(top level)", data, "must be a table"
            )
        self.source, self.prefix, self.data, self.seen = source, prefix, data, set()

    def table(self, key: str) -> _Table:
        self.seen.add(key)
        return _Table(self.source, f"{self.prefix}{key}.", self.data.get(key, {}))

    def take(self, key: str, kind: Any, default: Any = None, *, required: bool = False) -> Any:
        self.seen.add(key)
        if key not in self.data:
            if required:
                raise ScenarioError(self.source, self.prefix + key, None, "is required")
            return default
        value = self.data[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        # bool is an int in Python; never accept true/false for a number.
        if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
            names = " or ".join(k.__name__ for k in kinds)
            raise ScenarioError(self.source, self.prefix + key, value, f"must be of type {names}")
        return value

    def take_any(self, key: str, default: Any) -> Any:
        """The value at `key` whatever its type (the caller checks it), or `default`."""
        self.seen.add(key)
        return self.data.get(key, default)

    def take_list(self, key: str, kind: Any, default: Any) -> Any:
        value = self.take(key, list, default)
        for i, item in enumerate(value):
            if not isinstance(item, kind):
                raise ScenarioError(
                    self.source,
                    f"{self.prefix}{key}[{i}]",
                    item,
                    f"must be of type {kind.__name__}",
                )
        return value

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.seen)
        if unknown:
            allowed = ", ".join(sorted(self.seen))
            raise ScenarioError(
                self.source,
                self.prefix + unknown[0],
                self.data[unknown[0]],
                f"unknown key (allowed here: {allowed})",
            )


def _positive(src: str, fld: str, value: Any) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value <= 0
    ):
        raise ScenarioError(src, fld, value, "must be a positive number")
    return float(value)


def _optional_positive(src: str, fld: str, value: Any) -> float | None:
    return None if value is None else _positive(src, fld, value)


def _non_negative(src: str, fld: str, value: Any) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value < 0
    ):
        raise ScenarioError(src, fld, value, "must be a number >= 0")
    return float(value)


def _positive_int(src: str, fld: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ScenarioError(src, fld, value, "must be a positive whole number")
    return value


def _seed(src: str, fld: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ScenarioError(src, fld, value, "must be a whole number >= 0")
    return value
