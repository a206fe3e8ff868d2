"""A new plugin package, written from a template (`fleet new-plugin NAME --kind KIND`).

`write_plugin` writes a distribution that installs as it stands (``pip install -e``): a
``pyproject.toml`` with its build-system table and the entry point, a package under ``src/``
with a minimal plugin that works (a controller that follows the path layer's reference, or a
dispatcher that gives the oldest job to the idle robot with the smallest id, or a charging
policy that charges below a quarter to the nearest free charger), and a test that
runs the conformance kit (`fleet.plugins.testing`) on it and checks that discovery finds it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from fleet.errors import InputError

__all__ = ["KINDS", "NAME_RULE", "NewPlugin", "write_plugin"]

#: Plugin kinds a package can be made for, with their entry-point groups.
KINDS: dict[str, str] = {
    "controller": "fleet.controllers",
    "dispatcher": "fleet.dispatchers",
    "charging": "fleet.charging",
}

_NAME = re.compile(r"^[a-z][a-z0-9_]{0,63}$")
NAME_RULE = (
    "a plugin name is a Python identifier in lower case (letters, digits, '_'; starting with a "
    "letter), e.g. slow_follower: it names the entry point, the package and the folder"
)


@dataclass(frozen=True)
class NewPlugin:
    """What `write_plugin` wrote."""

    #: The distribution's folder.
    root: Path
    #: Its files, in the order written.
    files: tuple[Path, ...]
    #: The entry point's name, what a scenario writes as ``[controller] name = ...``.
    name: str
    kind: str
    #: ``module:Class``, the entry point's value.
    target: str


def write_plugin(name: str, kind: str, parent: Path) -> NewPlugin:
    """Write the package of a new `kind` plugin called `name` into ``parent/name``.

    Raises
    ------
    InputError
        If `name` or `kind` is not allowed, or ``parent/name`` exists and is not empty (nothing
        is overwritten).
    """
    if not _NAME.match(name):
        raise InputError("new-plugin", "NAME", name, NAME_RULE)
    if kind not in KINDS:
        raise InputError("new-plugin", "--kind", kind, f"must be one of {', '.join(KINDS)}")
    root = Path(parent) / name
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise InputError(
            str(root),
            "(directory)",
            str(root),
            "already exists and is not empty; nothing is overwritten: choose another name or "
            "remove it",
        )
    cls = "".join(part.capitalize() for part in name.split("_") if part) or "Plugin"
    module = {"controller": "control", "dispatcher": "dispatch", "charging": "policy"}[kind]
    fields = {
        "name": name,
        "dist": name.replace("_", "-"),
        "cls": cls,
        "module": module,
        "group": KINDS[kind],
        "kind": kind,
    }
    files = {
        "pyproject.toml": _PYPROJECT,
        "README.md": _README,
        f"src/{name}/__init__.py": _INIT,
        f"src/{name}/{module}.py": _PLUGIN[kind],
        f"tests/test_{name}.py": _TEST[kind],
    }
    written = []
    for rel, template in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(template.format(**fields), encoding="utf-8")
        written.append(path)
    return NewPlugin(root, tuple(written), name, kind, f"{name}.{module}:{cls}")


# The templates are str.format strings: literal braces are doubled.
_PYPROJECT = """\
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "{dist}"
version = "0.1.0"
description = "A mambot-fleet {kind} plugin"
requires-python = ">=3.11"
dependencies = ["mambot-fleet"]

[project.optional-dependencies]
test = ["pytest>=8"]

# How mambot-fleet finds the plugin: `fleet plugins` lists it, and a scenario selects it with
# [{kind}] name = "{name}".
[project.entry-points."{group}"]
{name} = "{name}.{module}:{cls}"

[tool.setuptools.packages.find]
where = ["src"]
"""

_README = """\
# {dist}

A {kind} plugin for mambot-fleet, made by `fleet new-plugin {name} --kind {kind}`.

```sh
pip install -e .          # into the environment mambot-fleet is installed in
fleet plugins             # lists {name}
python -m pytest tests    # the conformance kit, fleet.plugins.testing
```

A scenario uses it with `[{kind}] name = "{name}"`; options in `[{kind}.options]` are passed
to `{cls}(...)` as keyword arguments.
"""

_INIT = '''\
"""{dist}: a mambot-fleet {kind} plugin (entry point `{name}`)."""

from {name}.{module} import {cls}

__all__ = ["{cls}"]
'''

_CONTROLLER = '''\
"""The {name} controller: follows the path layer's timed reference to each goal."""

from __future__ import annotations

from fleet.plugins import Command, Controller, ControllerContext, ControlStatus, Observation
from fleet.plugins.robot import brake_input


class {cls}(Controller):
    """Track the reference the path layer plans to the goal; brake when there is none.

    A start for your own controller: `compute` gets an `Observation` every control period and
    returns the acceleration for the next one.
    """

    def reset(self, context: ControllerContext) -> None:
        super().reset(context)
        self.reference = None
        self.goal: tuple[float, float] | None = None

    def compute(self, obs: Observation) -> Command:
        spec = self.context.spec
        if self.reference is not None:
            x, y = self.reference.positions[self.reference.index(obs.t)]
            if abs(x - obs.x) + abs(y - obs.y) > 1e-3:  # knocked off it: stop, then replan
                self.reference, self.goal = None, None
        moving = obs.vx != 0 or obs.vy != 0
        if obs.goal is None or (obs.goal != self.goal and moving):
            ax, ay = brake_input(obs.vx, obs.vy, spec.period, spec.a_max)
            return Command(ax, ay, ControlStatus.IDLE if obs.goal is None else ControlStatus.OK)
        if obs.goal != self.goal:  # at rest with a new goal: plan from here
            self.goal = obs.goal
            self.reference = self.context.planner.reference(
                (obs.x, obs.y), obs.goal, dt=spec.period, t0=obs.t
            )
        k = min(self.reference.index(obs.t) + 1, self.reference.steps)
        vx, vy = self.reference.velocities[k]
        return Command((vx - obs.vx) / spec.period, (vy - obs.vy) / spec.period)
'''

_DISPATCHER = '''\
"""The {name} dispatcher: the oldest open job to the idle robot with the smallest id."""

from __future__ import annotations

from collections.abc import Sequence

from fleet.plugins import Assignment, DispatchContext, Dispatcher, Job, RobotStatus


class {cls}(Dispatcher):
    """Oldest open job first, each to the idle robot with the smallest id.

    A start for your own dispatcher: `assign` gets the open jobs and every robot's state and
    returns which robot takes which job.
    """

    def assign(
        self, jobs: Sequence[Job], robots: Sequence[RobotStatus], context: DispatchContext
    ) -> list[Assignment]:
        idle = sorted((r for r in robots if r.idle), key=lambda r: r.robot)
        ordered = sorted(jobs, key=lambda j: (j.released_s, j.id))
        return [Assignment(job.id, robot.robot) for job, robot in zip(ordered, idle)]
'''

_TEST_CONTROLLER = '''\
"""{name} meets the controller contract, and mambot-fleet finds it through its entry point."""

from fleet.plugins import discover, load_controller
from fleet.plugins.testing import check_controller

from {name} import {cls}


def test_{name}_conforms():
    check_controller({cls})  # closed loop on a small floor: bounds, goal, safety, determinism


def test_{name}_is_found_by_its_entry_point():
    info = {{p.name: p for p in discover("controller")}}["{name}"]
    assert info.error is None, info.error
    assert isinstance(load_controller("{name}"), {cls})
'''

_TEST_DISPATCHER = '''\
"""{name} meets the dispatcher contract, and mambot-fleet finds it through its entry point."""

from fleet.plugins import discover, load_dispatcher
from fleet.plugins.testing import check_dispatcher

from {name} import {cls}


def test_{name}_conforms():
    check_dispatcher({cls})  # only idle robots, only open jobs, no doubles, deterministic


def test_{name}_is_found_by_its_entry_point():
    info = {{p.name: p for p in discover("dispatcher")}}["{name}"]
    assert info.error is None, info.error
    assert isinstance(load_dispatcher("{name}"), {cls})
'''

_CHARGING = '''\
"""The {name} charging policy: below a quarter, to the nearest free charger, back at 90 %."""

from __future__ import annotations

import math

from fleet.plugins import BatteryStatus, ChargingPolicy


class {cls}(ChargingPolicy):
    """Below `low` (a share of the capacity) go to the nearest free charger (the nearest one
    when all are taken) after the current job, and charge to `high`, taking no jobs meanwhile.

    A start for your own policy: the engine asks it about each robot at each of its ticks.
    """

    def __init__(self, low: float = 0.25, high: float = 0.9) -> None:
        super().__init__()
        self.low, self.high = low, high

    def go_charge(self, status: BatteryStatus) -> str | None:
        if status.charge >= self.low or not status.chargers:
            return None
        free = [c for c in status.chargers if c.occupant in (None, status.robot)]
        nearest = min(
            free or status.chargers, key=lambda c: math.hypot(c.x - status.x, c.y - status.y)
        )
        return nearest.name

    def leave(self, status: BatteryStatus) -> bool:
        return status.charge >= self.high
'''

_TEST_CHARGING = '''\
"""{name} meets the charging-policy contract, and mambot-fleet finds it through its entry point."""

from fleet.plugins import discover, load_charging_policy
from fleet.plugins.testing import check_charging_policy

from {name} import {cls}


def test_{name}_conforms():
    check_charging_policy({cls})  # names given chargers, sends flat robots, lets full ones go


def test_{name}_is_found_by_its_entry_point():
    info = {{p.name: p for p in discover("charging")}}["{name}"]
    assert info.error is None, info.error
    assert isinstance(load_charging_policy("{name}"), {cls})
'''

#: Each kind's plugin module and test templates.
_PLUGIN = {"controller": _CONTROLLER, "dispatcher": _DISPATCHER, "charging": _CHARGING}
_TEST = {"controller": _TEST_CONTROLLER, "dispatcher": _TEST_DISPATCHER, "charging": _TEST_CHARGING}
