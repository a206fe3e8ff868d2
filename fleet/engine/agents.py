"""Robot agents outside the engine: building a run's controllers anywhere, and worker processes.

The engine and every agent must agree on the robots (ids, specs) and on the controller: both
follow from the scenario, so an agent needs only the scenario and the ids of the robots it
hosts. `robot_specs` numbers the robots exactly as the engine (`fleet.engine.motion`) does;
`build_controllers` loads and resets the controller plugins as the engine's own host does, so a
robot computes the same commands in the engine's process, in a worker process
(`fleet run --workers W`) or on another machine (`fleet agent --connect`).
`scenario_fingerprint` is what an agent says in its HELLO: the exchange refuses agents whose
scenario differs from the run's.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import multiprocessing
import os
import signal
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from fleet.bus import AgentHost
from fleet.errors import PluginError, ScenarioError
from fleet.floor import Floor, load_floor, load_spec, slow_on_rough
from fleet.paths import PathPlanner
from fleet.plugins import Controller, ControllerContext, RobotSpec, load_controller
from fleet.scenario import Scenario

__all__ = [
    "robot_specs",
    "load_run_floor",
    "build_controllers",
    "scenario_fingerprint",
    "split_robots",
    "parse_robot_selection",
    "serve_agent",
    "AgentReport",
    "WorkerPool",
]

log = logging.getLogger("fleet.engine")


def robot_specs(scenario: Scenario) -> dict[str, RobotSpec]:
    """Every robot of the scenario by id (``r01``, ``r02``, ... in group order) with its spec."""
    total = sum(g.count for g in scenario.robots)
    width = max(2, len(str(total)))
    out: dict[str, RobotSpec] = {}
    for group in scenario.robots:
        spec = RobotSpec(group.v_max, group.a_max, group.radius, group.period_s)
        for _ in range(group.count):
            out[f"r{len(out) + 1:0{width}d}"] = spec
    return out


def load_run_floor(scenario: Scenario, floor: Floor | None = None) -> Floor:
    """The scenario's floor (or `floor`); with `rough_v_max`, every rough area is also a speed
    zone."""
    if scenario.rough_v_max is None:
        return floor if floor is not None else load_floor(scenario.map)
    spec = floor.spec if floor is not None else load_spec(scenario.map)
    return slow_on_rough(spec, scenario.rough_v_max)


def build_controllers(
    scenario: Scenario,
    floor: Floor,
    robots: Iterable[str],
    planner_for: Any = None,
) -> dict[str, Controller]:
    """Load and `reset` one controller per robot in `robots`.

    Parameters
    ----------
    planner_for:
        ``RobotSpec -> PathPlanner`` to share planners with (the engine's); default: one
        planner per distinct speed and acceleration limit, built here.

    Raises
    ------
    PluginError
        If the plugin cannot be loaded, or its options do not suit a robot; the message names
        the scenario file and its ``[controller]`` table.
    ScenarioError
        If a robot id is not one of the scenario's.
    """
    specs = robot_specs(scenario)
    if planner_for is None:
        planners: dict[tuple[float, float], PathPlanner] = {}

        def planner_for(spec: RobotSpec) -> PathPlanner:
            key = (spec.v_max, spec.a_max)
            if key not in planners:
                planners[key] = PathPlanner(floor, v_max=spec.v_max, a_max=spec.a_max)
            return planners[key]

    choice = scenario.controller
    where = f"{scenario.source}: [controller] name = {choice.name!r}, options = {choice.options!r}"
    out: dict[str, Controller] = {}
    for rid in robots:
        if rid not in specs:
            raise ScenarioError(
                scenario.source, "robots", rid, f"no such robot (the run has {_span(specs)})"
            )
        try:
            controller = load_controller(choice.name, choice.options)
        except PluginError as exc:
            raise PluginError(f"{where}: {exc}") from None
        context = ControllerContext(rid, specs[rid], floor, planner_for(specs[rid]))
        try:
            controller.reset(context)
        except (TypeError, ValueError) as exc:  # options that do not suit this robot
            raise PluginError(f"{where}: {exc}") from None
        out[rid] = controller
    return out


def scenario_fingerprint(scenario: Scenario) -> str:
    """A short hash of what agents and engine must agree on: robots, controller, floor, and
    the bus's message size limit.

    The map's contents (not its path) count, so an agent on another machine with its own copy
    of the files agrees as long as the files are the same.
    """
    body = {
        "robots": [dataclasses.asdict(g) for g in scenario.robots],
        "controller": [scenario.controller.name, scenario.controller.options],
        "map": _file_digest(Path(scenario.map)),
        "rough_v_max": scenario.rough_v_max,
        "max_message_bytes": scenario.bus.max_message_bytes,
    }
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def split_robots(robots: Sequence[str], parts: int) -> list[list[str]]:
    """`robots` in `parts` contiguous shares as even as possible (the first ones larger)."""
    if parts < 1:
        raise ValueError(f"parts = {parts!r}: must be >= 1")
    size, extra = divmod(len(robots), parts)
    out, at = [], 0
    for i in range(parts):
        n = size + (1 if i < extra else 0)
        out.append(list(robots[at : at + n]))
        at += n
    return out


def parse_robot_selection(scenario: Scenario, robots: str | None, share: str | None) -> list[str]:
    """The robots an agent hosts: ``--only r01,r03`` or ``--share K/N`` (the K-th of N even
    contiguous shares, from 1), or every robot of the run when both are None.

    Raises
    ------
    ScenarioError
        Naming the option and the bad value.
    """
    every = list(robot_specs(scenario))
    if robots is not None and share is not None:
        raise ScenarioError(
            "command line", "--robots", robots, "give --robots or --share, not both"
        )
    if robots is not None:
        chosen = [r.strip() for r in robots.split(",") if r.strip()]
        unknown = [r for r in chosen if r not in every]
        if not chosen or unknown:
            raise ScenarioError(
                "command line",
                "--only",
                robots,
                f"unknown robot ids {unknown} (the run has {_span(every)})"
                if unknown
                else "name at least one robot",
            )
        return chosen
    if share is not None:
        k, slash, n = share.partition("/")
        if not (slash and k.isdigit() and n.isdigit() and 1 <= int(k) <= int(n)):
            raise ScenarioError("command line", "--share", share, "must be K/N with 1 <= K <= N")
        return split_robots(every, int(n))[int(k) - 1]
    return every


def serve_agent(
    scenario: Scenario,
    address: str,
    robots: Sequence[str],
    *,
    name: str | None = None,
    curve: Any = None,
    idle_timeout_s: float | None = None,
) -> AgentReport:
    """Host `robots`' controllers and answer the exchange at `address` until it says BYE, or
    until nothing has come from it for `idle_timeout_s` (None: wait for ever), computing the
    scenario's ``[bus] threads`` robots' steps at once."""
    floor = load_run_floor(scenario)
    controllers = build_controllers(scenario, floor, robots)
    kwargs: dict[str, Any] = {
        "name": name,
        "scenario": scenario_fingerprint(scenario),
        "max_message_bytes": scenario.bus.max_message_bytes,
    }
    if curve is not None:
        kwargs["curve"] = curve
    with AgentHost(address, controllers, threads=scenario.bus.threads, **kwargs) as host:
        host.serve(idle_timeout_s)
        return AgentReport(
            dict(host.stats),
            None if host.accepted is None else sorted(host.accepted),
            dict(host.rejected),
            host.finished,
        )


@dataclasses.dataclass(frozen=True)
class AgentReport:
    """How an agent's service went: its counters (`fleet.bus.AGENT_STATS`), the robots the
    exchange accepted (None: it never answered the HELLO) and refused (with reasons), and
    whether the exchange ended the run with BYE."""

    stats: dict[str, int]
    accepted: list[str] | None
    rejected: dict[str, str]
    finished: bool


def _worker_main(scenario: Scenario, address: str, robots: list[str], name: str) -> None:
    # The engine stops workers itself (BYE, then terminate): a Ctrl-C meant for the engine must
    # not kill them halfway through an answer.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.basicConfig(level=logging.WARNING, format=f"{name}: %(levelname)s %(message)s")
    # A worker whose engine vanished must not live on: give up after a long silence.
    serve_agent(scenario, address, robots, name=name, idle_timeout_s=600.0)


class WorkerPool:
    """`count` worker processes hosting the robots' agents, for one run.

    Each worker is a fresh interpreter (spawn) that loads the controllers of its share of the
    robots (`split_robots`) and connects to the exchange at `address`.
    """

    def __init__(self, scenario: Scenario, address: str, count: int) -> None:
        if not isinstance(count, int) or count < 1:
            raise ValueError(f"workers = {count!r}: must be an integer >= 1")
        self.address = address
        robots = list(robot_specs(scenario))
        shares = [s for s in split_robots(robots, min(count, len(robots))) if s]
        context = multiprocessing.get_context("spawn")
        self.names = [f"worker-{os.getpid()}-{i + 1}" for i in range(len(shares))]
        self.shares: Mapping[str, list[str]] = dict(zip(self.names, shares, strict=True))
        self.processes = [
            context.Process(
                target=_worker_main,
                args=(scenario, address, share, name),
                name=name,
                daemon=True,
            )
            for name, share in self.shares.items()
        ]
        for p in self.processes:
            p.start()

    def alive(self) -> list[str]:
        """Names of the workers still running."""
        return [p.name for p in self.processes if p.is_alive()]

    def dead(self) -> list[tuple[str, int | None]]:
        """Workers that have exited, with their exit codes."""
        return [(p.name, p.exitcode) for p in self.processes if p.exitcode is not None]

    def close(self, timeout_s: float = 10.0) -> None:
        """Wait for the workers to leave (after the exchange's BYE); terminate stragglers."""
        for p in self.processes:
            p.join(timeout_s)
            if p.is_alive():
                log.warning("worker %s did not stop after the run; terminating it", p.name)
                p.terminate()
                p.join(timeout_s)


def _file_digest(path: Path) -> str:
    # A World given its floor directly may name no real map file: then the name must agree.
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return str(path)


def _span(robots: Iterable[str]) -> str:
    ids = list(robots)
    return f"{ids[0]}..{ids[-1]}" if ids else "no robots"
