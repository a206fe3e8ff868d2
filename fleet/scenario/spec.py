"""The scenario file's structure, described once: its tables, keys, types, ranges and defaults.

`ScenarioFile` is what ``msgspec.convert`` checks a parsed TOML file against, and what
``fleet schema scenario`` prints as JSON Schema (each key's ``description`` is the help an
editor shows). Rules that span keys or need the disk (the map exists, tasks do not overlap, a
job's part is in ``[parts]``) are checked by `fleet.scenario.reader` after conversion.

A type may carry ``Meta(extra={"rule": ...})``: the words an error uses when a value of that
type is refused. On a union the rule judges the value whole, so ``v_max = [0.5, -1]`` is one
bad speed, not a bad second number.
"""

from __future__ import annotations

import sys
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta, Struct

from fleet.printing import TASK_KINDS

__all__ = [
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


class _Table(Struct, kw_only=True, forbid_unknown_fields=True):
    """A TOML table: keys in any order, unknown keys refused."""


class ScenarioTable(_Table):
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
    latency: _Latency = "none"


class RobotsTable(_Table):
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


class ControllerTable(_Table):
    """[controller]: the controller plugin and its constructor's keyword options."""

    name: Annotated[str, Meta(description="A controller plugin (`fleet plugins`).")] = "follower"
    options: Annotated[dict[str, Any], Meta(description="Keyword arguments for the plugin.")] = {}


class DispatcherTable(_Table):
    """[dispatcher]: the dispatcher plugin and its constructor's keyword options."""

    name: Annotated[str, Meta(description="A dispatcher plugin (`fleet plugins`).")] = "greedy"
    options: Annotated[dict[str, Any], Meta(description="Keyword arguments for the plugin.")] = {}


class PrintTaskTable(_Table):
    """One print task of a scripted job, in seconds after printing starts."""

    kind: TaskKind
    start_s: NonNegative
    end_s: Positive


class ScriptedJobTable(_Table):
    """[[jobs.scripted]]: a job released at at_s to a station."""

    at_s: Annotated[NonNegative, Meta(description="Release time (s).")]
    station: Annotated[str, Meta(description="The destination station.")]
    due_s: Annotated[float | None, Meta(description="Due time (s).")] = None
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


class JobsTable(_Table):
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
    scripted: list[ScriptedJobTable] = []
    parts: Annotated[
        list[str], Meta(description="Poisson jobs print one of these parts, drawn uniformly.")
    ] = []
    max_handbacks: Annotated[
        NonNegativeInt, Meta(description="A job handed back more often than this is given up.")
    ] = 3


class PrintTable(_Table):
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


class QualityTable(_Table):
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


class FloorTable(_Table):
    """[floor]: how the scenario reads the map."""

    rough_v_max: Annotated[
        Positive | None,
        Meta(description="Every rough area of the map becomes a speed zone with this limit."),
    ] = None


class BusTable(_Table):
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


class ScenarioFile(_Table):
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
