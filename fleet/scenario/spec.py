"""The scenario file's structure, described once, and how a value it refuses is worded.

`ScenarioFile` is what `convert` checks a parsed TOML file against (with msgspec), and what
``fleet schema scenario`` prints as JSON Schema (each key's ``description`` is the help an
editor shows). Rules that span keys or need the disk (the map exists, tasks do not overlap, a
job's part is in ``[parts]``) are checked by `fleet.scenario.reader` after conversion.

A refusal becomes a `ScenarioError` naming the field and quoting the value as written. A type
may carry ``Meta(extra={"rule": ...})``: the words the error uses when a value of that type is
refused.
"""

from __future__ import annotations

import re
import sys
import types
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import msgspec
from msgspec import Meta, Struct

from fleet.errors import ScenarioError
from fleet.printing import TASK_KINDS

__all__ = [
    "convert",
    "ScenarioFile",
    "ScenarioTable",
    "RobotsTable",
    "ControllerTable",
    "DispatcherTable",
    "JobsTable",
    "ScriptedJobTable",
    "PrintTaskTable",
    "PrintTable",
    "QualityTable",
    "FloorTable",
    "BusTable",
    "BreakdownsTable",
    "BreakdownGroupTable",
    "BatteryTable",
    "ChargingTable",
    "TaskKind",
    "Positive",
    "NonNegative",
    "PositiveInt",
    "NonNegativeInt",
    "LATENCY_RULE",
]

# msgspec has no "finite" constraint; bounding by the largest float refuses TOML's inf, and nan
# fails every comparison.
_LARGEST = sys.float_info.max

Finite = Annotated[float, Meta(ge=-_LARGEST, le=_LARGEST)]
Positive = Annotated[float, Meta(gt=0, le=_LARGEST)]
NonNegative = Annotated[float, Meta(ge=0, le=_LARGEST)]
PositiveInt = Annotated[int, Meta(gt=0)]
NonNegativeInt = Annotated[int, Meta(ge=0)]

#: A print task kind (`fleet.printing.TASK_KINDS`).
TaskKind = Annotated[
    Literal[TASK_KINDS],  # subscripting with a tuple lists its items as the values
    Meta(extra={"rule": f"unknown task kind (known: {', '.join(TASK_KINDS)})"}),
]

#: A value per task kind; JSON Schema cannot say that keys are task kinds unless told.
PerKind = Annotated[
    dict[TaskKind, Positive], Meta(extra_json_schema={"propertyNames": {"enum": list(TASK_KINDS)}})
]

LATENCY_RULE = (
    'must be "none" (commands apply at once), "measured" (each command waits its '
    "controller's measured step time) or a number of seconds >= 0 (a fixed latency)"
)

_Latency = Annotated[
    NonNegative | Literal["none", "measured"],
    Meta(
        description='Compute latency: "none" (commands apply at their tick), "measured" (each '
        "command waits its controller's measured step time; not reproducible) or seconds >= 0.",
        extra={"rule": LATENCY_RULE},
    ),
]

BusAddress = Annotated[
    str,
    Meta(
        pattern="^(inproc|ipc|tcp)://",
        extra={"rule": "must start with inproc://, ipc:// or tcp://"},
    ),
]


class _Table(Struct, forbid_unknown_fields=True):
    """A TOML table: unknown keys refused (subclasses inherit this; keys go in any order)."""


class ScenarioTable(_Table, kw_only=True):
    """[scenario]: which floor, for how long, with which seed."""

    map: Annotated[str, Meta(description="The floor map file (TOML), relative to this file.")]
    name: Annotated[str | None, Meta(description="The run's name (default: the file's).")] = None
    duration_s: Annotated[Positive, Meta(description="Simulated seconds.")] = 600.0
    seed: Annotated[NonNegativeInt, Meta(description="Seed of every random draw.")] = 1
    arrival_tolerance_m: Annotated[
        Positive, Meta(description="A job is delivered when its robot rests this close (m).")
    ] = 0.05
    sensing_radius_m: Annotated[
        NonNegative,
        Meta(description="Observations list the robots this close (m; nearest 8); 0: none."),
    ] = 0.0
    deadlock_after_s: Annotated[
        NonNegative,
        Meta(description="No progress for this long (s) with robots close by: a deadlock; 0: off."),
    ] = 30.0
    station_queue: Annotated[
        bool,
        Meta(
            description="Robots with a job wait their turn short of a station that another "
            "robot with a job is nearer; false: they crowd round it."
        ),
    ] = True
    latency: _Latency = "none"
    warmup_s: Annotated[
        NonNegative,
        Meta(
            description="KPIs (throughput, lead times, waits, state shares) leave out the "
            "start-up [0, warmup_s); below duration_s."
        ),
    ] = 0.0


class RobotsTable(_Table, kw_only=True):
    """[robots] or each [[robots]]: a group of identical robots."""

    count: Annotated[PositiveInt, Meta(description="Robots in the group.")] = 4
    start: Annotated[
        list[str],
        Meta(description="Start stations, cycled (default: the floor's depots)."),
    ] = []
    v_max: Annotated[Positive, Meta(description="Speed limit per axis (m/s).")] = 1.0
    a_max: Annotated[Positive, Meta(description="Acceleration limit per axis (m/s^2).")] = 0.5
    radius: Annotated[Positive, Meta(description="Footprint radius (m).")] = 0.4
    period_s: Annotated[Positive, Meta(description="Control period (s).")] = 0.25
    return_home: Annotated[
        bool, Meta(description="Idle robots drive back to their start position.")
    ] = True
    turn_radius_m: Annotated[
        Positive | None,
        Meta(
            description="Set: a robot setting off in a new direction first turns on the spot "
            "at v_max / turn_radius_m rad/s; unset: holonomic."
        ),
    ] = None
    turn_settle_s: Annotated[NonNegative, Meta(description="Seconds a turn takes to settle.")] = 0.0


class ControllerTable(_Table, kw_only=True):
    """[controller]: the controller plugin and its constructor's keyword options."""

    name: Annotated[str, Meta(description="A controller plugin (`fleet plugins`).")] = "follower"
    options: Annotated[dict[str, Any], Meta(description="Keyword arguments for the plugin.")] = {}


class DispatcherTable(_Table, kw_only=True):
    """[dispatcher]: the dispatcher plugin and its constructor's keyword options."""

    name: Annotated[str, Meta(description="A dispatcher plugin (`fleet plugins`).")] = "greedy"
    options: Annotated[dict[str, Any], Meta(description="Keyword arguments for the plugin.")] = {}


class PrintTaskTable(_Table, kw_only=True):
    """One print task of a scripted job, in seconds after printing starts."""

    kind: TaskKind
    start_s: NonNegative
    end_s: Positive


class ScriptedJobTable(_Table, kw_only=True):
    """[[jobs.scripted]]: a job released at at_s to a station."""

    at_s: Annotated[NonNegative, Meta(description="Release time (s).")]
    station: Annotated[str, Meta(description="The destination station.")]
    due_s: Annotated[Finite | None, Meta(description="Due time (s).")] = None
    tasks: Annotated[
        list[PrintTaskTable],
        Meta(description="What is printed on the way, in order (not with part)."),
    ] = msgspec.field(default_factory=list, name="print")
    part: Annotated[
        str | None, Meta(description="A part from [parts] printed on the way (not with print).")
    ] = None
    via: Annotated[list[str], Meta(description="Stations to pass on the way, in order.")] = []
    shuttle: Annotated[
        bool,
        Meta(description="Drive round the via stations while the print lasts, then deliver."),
    ] = False


class JobsTable(_Table, kw_only=True):
    """[jobs]: where jobs come from, Poisson arrivals or a scripted list."""

    mode: Literal["poisson", "scripted"] = "poisson"
    rate_per_h: Annotated[Positive, Meta(description="Poisson jobs per hour.")] = 60.0
    stations: Annotated[
        list[str],
        Meta(description="Destinations (default: every station that is not a depot)."),
    ] = []
    due_in_s: Annotated[
        Positive | None, Meta(description="Due time after release (s), for Poisson jobs.")
    ] = None
    release_until_s: Annotated[
        Positive | None,
        Meta(
            description="Poisson jobs are released until this time (s); the fleet then works "
            "off what is left (default: to the end of the run)."
        ),
    ] = None
    scripted: list[ScriptedJobTable] = []
    parts: Annotated[
        list[str], Meta(description="Poisson jobs print one of these parts, drawn uniformly.")
    ] = []
    max_handbacks: Annotated[
        NonNegativeInt,
        Meta(
            description="A job handed back more often than this is given up (hand-backs by "
            "breakdowns not counted)."
        ),
    ] = 3


class PrintTable(_Table, kw_only=True):
    """[print]: speed caps while printing, and how G-code becomes print tasks."""

    caps: Annotated[
        PerKind
        | Annotated[
            Literal["quality"],
            Meta(
                extra={
                    "rule": 'must be a table of caps per kind, e.g. { contour = 0.3 }, or "quality"'
                    " (the QSP's fastest speed within each kind's [quality] tolerance)"
                }
            ),
        ],
        Meta(
            description='Per-axis speed cap (m/s) per task kind, or "quality": the QSP\'s fastest '
            "speed within each kind's [quality] tolerance."
        ),
    ] = {}
    enforce: Annotated[
        bool, Meta(description="false: the caps are advice for controllers, not limits.")
    ] = True
    min_task_s: Annotated[
        NonNegative, Meta(description="G-code features merge into tasks at least this long (s).")
    ] = 10.0
    classify: Annotated[
        dict[str, TaskKind], Meta(description="Overrides of the G-code feature -> kind table.")
    ] = {}


class QualityTable(_Table, kw_only=True):
    """[quality]: how printed parts are judged."""

    calibration: Annotated[
        str | None, Meta(description="A QSP calibration CSV (default: the paper's Table 1).")
    ] = None
    tolerance_mm: Annotated[
        Positive | PerKind,
        Meta(description="Allowed dimensional error (mm), or one per task kind."),
    ] = 0.05
    speed_metric: Annotated[
        Literal["mean", "max"], Meta(description="A task's speed: time-weighted mean or max.")
    ] = "mean"
    scope: Annotated[
        Literal["task", "print"],
        Meta(description="Judge every task on its own, or the whole print as one task."),
    ] = "task"


class FloorTable(_Table, kw_only=True):
    """[floor]: how the scenario reads the map."""

    rough_v_max: Annotated[
        Positive | None,
        Meta(description="Every rough area of the map becomes a speed zone with this limit."),
    ] = None


class BusTable(_Table, kw_only=True):
    """[bus]: where robot agents connect and how long the engine waits for them."""

    address: Annotated[
        BusAddress | None,
        Meta(description="Default: a private inproc:// address; ipc:// and tcp:// use sockets."),
    ] = None
    timeout_s: Annotated[
        Positive, Meta(description="Longest wait for an agent's answer in one round (s).")
    ] = 10.0
    lost_after_s: Annotated[
        Positive,
        Meta(description="An agent silent this long while a round waits is lost (s)."),
    ] = 3.0
    max_message_bytes: Annotated[
        int,
        Meta(
            ge=1024,
            le=1 << 30,
            description="Longest bus message taken in or sent (bytes); a peer sending a"
            " longer one is disconnected. Raise it for agents hosting thousands of robots.",
        ),
    ] = 2 * 1024 * 1024
    lockstep: Annotated[
        Literal["strict", "pipelined"],
        Meta(
            description='How a control round waits for the agents: "strict" (a command drives'
            " the step right after the observation it answers; the engine waits for it) or"
            ' "pipelined" (it answers the next tick\'s predicted observation and takes effect'
            " then; the engine steps the world while the agents compute). Not with a latency."
        ),
    ] = "strict"
    threads: Annotated[
        int,
        Meta(
            ge=1,
            le=256,
            description="Robots' steps each agent host (the engine's own, each worker, each"
            " `fleet agent`) computes at once, in threads: their solves overlap on as many"
            " cores. The commands, and the run's digest, are the same with any count.",
        ),
    ] = 1


class BreakdownGroupTable(_Table, kw_only=True):
    """One entry of [breakdowns] groups: one [[robots]] group's own times (unset: the table's)."""

    mtbf_s: Annotated[
        NonNegative | None,
        Meta(description="This group's mean time between failures (s); 0: it never breaks down."),
    ] = None
    mttr_s: Annotated[
        Positive | None, Meta(description="This group's mean time to repair (s).")
    ] = None


class BreakdownsTable(_Table, kw_only=True):
    """[breakdowns]: robots break down at random, stop where they are and are repaired there."""

    mtbf_s: Annotated[
        NonNegative,
        Meta(
            description="Mean time between failures per robot (s in service: from the start or "
            "the last repair to the next failure); 0: no breakdowns."
        ),
    ]
    mttr_s: Annotated[Positive, Meta(description="Mean time to repair (s).")]
    failures: Annotated[
        Literal["exponential", "fixed"],
        Meta(description="Times between failures: exponential (memoryless) or fixed at mtbf_s."),
    ] = "exponential"
    repairs: Annotated[
        Literal["exponential", "lognormal", "fixed"],
        Meta(description="Repair times: exponential, lognormal (mean mttr_s) or fixed at mttr_s."),
    ] = "exponential"
    repair_cv: Annotated[
        Positive,
        Meta(description="Coefficient of variation (std / mean) of lognormal repair times."),
    ] = 0.5
    groups: Annotated[
        list[BreakdownGroupTable],
        Meta(description="One entry per [[robots]] group, in order, with that group's own times."),
    ] = []


class BatteryTable(_Table, kw_only=True):
    """[battery]: every robot's battery and its draw (absent: robots never run out)."""

    capacity_wh: Annotated[Positive, Meta(description="Usable capacity (Wh).")] = 500.0
    drive_wh_per_m: Annotated[NonNegative, Meta(description="Energy per metre driven (Wh/m).")] = (
        0.05
    )
    print_w: Annotated[NonNegative, Meta(description="Draw while printing (W = Wh per hour).")] = (
        60.0
    )
    idle_w: Annotated[
        NonNegative, Meta(description="Draw at all times, moving or not (W; electronics).")
    ] = 0.0
    initial_share: Annotated[
        float,
        Meta(
            gt=0,
            le=1,
            description="Charge at the start, a share of the capacity (0 < share <= 1).",
            extra={"rule": "must be a share of the capacity, > 0 and <= 1"},
        ),
    ] = 1.0
    charge_w: Annotated[
        Positive, Meta(description="Rate at which a charger fills the battery (W = Wh per hour).")
    ] = 300.0


class ChargingTable(_Table, kw_only=True):
    """[charging]: the charging-policy plugin and its options (used with [battery])."""

    name: Annotated[
        str, Meta(description="A charging-policy plugin (`fleet plugins`): threshold, opportunity.")
    ] = "threshold"
    options: Annotated[dict[str, Any], Meta(description="Keyword arguments for the plugin.")] = {}


class ScenarioFile(_Table, kw_only=True):
    """A scenario file: which floor, which fleet, which plugins, which jobs, for how long."""

    scenario: ScenarioTable
    robots: Annotated[
        RobotsTable
        | Annotated[
            list[RobotsTable],
            Meta(min_length=1, extra={"rule": "needs at least one [[robots]] group"}),
        ],
        Meta(description="One group of robots, or several [[robots]] groups."),
    ] = msgspec.field(default_factory=RobotsTable)
    controller: ControllerTable = msgspec.field(default_factory=ControllerTable)
    dispatcher: DispatcherTable = msgspec.field(default_factory=DispatcherTable)
    jobs: JobsTable = msgspec.field(default_factory=JobsTable)
    parts: Annotated[
        dict[str, Annotated[str, Meta(extra={"rule": "must be a G-code file name (string)"})]],
        Meta(description="Parts jobs may print: name = G-code file, relative to this file."),
    ] = {}
    printing: PrintTable = msgspec.field(default_factory=PrintTable, name="print")
    quality: QualityTable = msgspec.field(default_factory=QualityTable)
    floor: FloorTable = msgspec.field(default_factory=FloorTable)
    bus: BusTable = msgspec.field(default_factory=BusTable)
    battery: Annotated[
        BatteryTable | None, Meta(description="Robots' batteries; absent: they never run out.")
    ] = None
    charging: ChargingTable = msgspec.field(default_factory=ChargingTable)
    breakdowns: Annotated[
        BreakdownsTable | None,
        Meta(description="Random breakdowns and repairs of robots (absent: none)."),
    ] = None


# -- what msgspec refused, restated ------------------------------------------------------------
# msgspec says where a value broke the structure ("... - at `$.robots[1].period_s`") but not the
# value, and in its own words. `_refusal` follows the path through the raw tables and the
# declared types together, to quote the value as written and say what its type allows: the rule
# the type carries, the alternatives of a `Literal`, or msgspec's words in ours.

# "<what> - at `$.a[0].b`", or for a dict's key "<what> - at `key` in `$.a`"; no path at `$`.
_MESSAGE = re.compile(r"(?P<what>.*?)(?: - at `(?P<at>[^`]*)`(?: in `(?P<key_of>[^`]*)`)?)?")
_STEP = re.compile(r"\.(\w+)|\[(\d+|\.\.\.)\]")
_FIELD = re.compile(r"Object (?P<kind>contains unknown|missing required) field `(?P<name>\w+)`")
_TYPES = re.compile(r"Expected `(?P<expected>[^`]+)`, got `\w+`")
_BOUND = re.compile(r"Expected `(?P<type>int|float)` (?P<op>[<>]=?) (?P<bound>\S+)")

#: How the rules name msgspec's types (as the scenario reader always has: Python's names).
_TYPE_NAMES = {"float": "int or float", "array": "list", "object": "dict"}


def convert(value: Any, declared: Any, source: str, where: str = "") -> Any:
    """`value` converted to the `declared` type, or a `ScenarioError` naming `source`.

    `where` is the field `value` sits at (empty for a whole file): errors name fields below it.
    """
    try:
        return msgspec.convert(value, declared)
    except msgspec.ValidationError as exc:
        raise _refusal(str(exc), value, declared, source, where) from None


def _refusal(message: str, value: Any, declared: Any, source: str, where: str) -> ScenarioError:
    """The `ScenarioError` msgspec's `message` about converting `value` to `declared` means."""
    match = _MESSAGE.fullmatch(message)
    assert match is not None  # every message matches: its location is optional
    what, at, key_of = match["what"], match["at"] or "$", match["key_of"]
    steps = [name or index for name, index in _STEP.findall(key_of or at)]
    if key_of:
        steps.append("...")  # the bad key of the dict at `key_of`
    field = where
    for step in steps:
        bare = _bare(_member(declared, value))
        if step == "...":
            key, declared = _bad_entry(bare, value)
            field, value = f"{field}.{key}", value[key]
        elif step.isdigit():
            index = int(step)
            items = get_args(bare)
            declared = items[index] if get_origin(bare) is tuple else items[0]
            field, value = f"{field}[{index}]", value[index]
        else:
            declared = _fields(bare)[step]
            field, value = f"{field}.{step}" if field else step, value[step]

    known = _FIELD.fullmatch(what)
    if known is None:
        return ScenarioError(source, field, value, _rule(what, declared, value))
    name = known["name"]
    inner = f"{field}.{name}" if field else name
    if known["kind"] == "missing required":
        return ScenarioError(source, inner, None, "is required")
    allowed = ", ".join(sorted(_fields(_bare(_member(declared, value)))))
    return ScenarioError(source, inner, value[name], f"unknown key (allowed here: {allowed})")


def _rule(what: str, declared: Any, value: Any) -> str:
    """What `declared` allows, for a `value` msgspec refused with `what`."""
    member = _member(declared, value)
    # A union's own rule first: it covers every alternative (latency = "fast" is no bad Literal).
    rule = _own_rule(declared) or _own_rule(member)
    if rule:
        return rule
    if what.startswith("Invalid enum value"):
        return "must be " + " or ".join(repr(v) for v in get_args(_bare(member)))
    if expected := _TYPES.fullmatch(what):
        names = [_TYPE_NAMES.get(t, t) for t in expected["expected"].split(" | ") if t != "null"]
        return f"must be of type {' or '.join(names)}"
    if bound := _BOUND.fullmatch(what):
        number = "whole number" if bound["type"] == "int" else "number"
        op, limit = bound["op"], float(bound["bound"])
        if abs(limit) == _LARGEST:
            return "must be a finite number"
        # msgspec states an int's "> 0" as ">= 1".
        if (op, limit) == (">", 0) or (number == "whole number" and (op, limit) == (">=", 1)):
            return f"must be a positive {number}"
        return f"must be a {number} {op} {limit:g}"
    return what


def _own_rule(declared: Any) -> str | None:
    """The rule `declared` carries in its ``Meta(extra={"rule": ...})``, if any."""
    for meta in getattr(declared, "__metadata__", ()):
        if isinstance(meta, msgspec.Meta) and meta.extra and "rule" in meta.extra:
            return meta.extra["rule"]
    return None


def _bare(declared: Any) -> Any:
    """`declared` without its `Annotated` metadata."""
    return get_args(declared)[0] if get_origin(declared) is Annotated else declared


def _member(declared: Any, value: Any) -> Any:
    """The member of the union `declared` that a TOML value like `value` is meant for.

    A table goes to a struct or a dict, an array to a list or a tuple, a string to a `Literal`
    or a str, a number to a number: the member whose shape fits, whatever else is wrong with
    the value. Not a union, or no member fits: `declared` itself.
    """
    if get_origin(_bare(declared)) not in (Union, types.UnionType):
        return declared
    return next((m for m in get_args(_bare(declared)) if _fits(m, value)), declared)


def _fits(declared: Any, value: Any) -> bool:
    """Whether a TOML value like `value` has the shape of `declared` (not its range)."""
    bare = _bare(declared)
    origin = get_origin(bare) or bare
    if origin is Literal:
        shapes: tuple[type, ...] = tuple({type(v) for v in get_args(bare)})
    elif isinstance(origin, type) and issubclass(origin, msgspec.Struct):
        shapes = (dict,)
    elif origin in (list, tuple):
        shapes = (list,)
    elif origin is float:
        shapes = (int, float)
    else:
        shapes = (origin,) if isinstance(origin, type) else ()
    # TOML's true and false are Python ints too; they are never numbers here.
    return isinstance(value, shapes) and (bool in shapes or not isinstance(value, bool))


def _fields(struct: type[msgspec.Struct]) -> dict[str, Any]:
    """A struct's declared types by the keys the file uses."""
    return {f.encode_name: f.type for f in msgspec.structs.fields(struct)}


def _bad_entry(declared: Any, table: dict[str, Any]) -> tuple[str, Any]:
    """The first key of `table` whose key or value `declared` (a dict type) refuses, and the
    type that refuses it (the key's or the value's)."""
    key_type, value_type = get_args(declared)
    for key, item in table.items():
        for type_, part in ((key_type, key), (value_type, item)):
            try:
                msgspec.convert(part, type_)
            except msgspec.ValidationError:
                return key, type_
    raise AssertionError("msgspec refused an entry that every check accepts")
