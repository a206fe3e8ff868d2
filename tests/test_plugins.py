"""Plugin discovery through entry points, and the conformance kit failing plugins that cheat."""

from __future__ import annotations

import math
import sys
import textwrap
import threading
import warnings
from collections import namedtuple
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import fleet.plugins.discovery as plugins_module
from fleet.errors import PluginError
from fleet.plugins import (
    CONTROLLER_GROUP,
    DISPATCHER_GROUP,
    Assignment,
    Command,
    Controller,
    ControlStatus,
    Dispatcher,
    PluginInfo,
    PluginWarning,
    discover,
    load_controller,
    load_dispatcher,
)
from fleet.plugins.robot import brake_input
from fleet.plugins.testing import ConformanceError, check_controller, check_dispatcher
from fleet_plugins.follower import PathFollower
from fleet_plugins.greedy import GreedyDispatcher


@pytest.fixture(autouse=True)
def _fresh_discovery(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test reads the entry points itself; the process cache is restored afterwards."""
    monkeypatch.setattr(plugins_module, "_CACHE", None)


# --- a third party installed in tmp_path --------------------------------------------------------

THIRD_PARTY = '''
from fleet.plugins import Command, ControlStatus, Controller, Dispatcher


class GoodController(Controller):
    """Holds still: enough to be loadable."""

    def __init__(self, level: int = 1) -> None:
        super().__init__()
        self.level = level

    def compute(self, obs):
        return Command(0.0, 0.0, ControlStatus.IDLE)


class NotAController:
    def compute(self, obs):
        return None


class HalfController(Controller):
    """Forgot to implement compute."""


class GoodDispatcher(Dispatcher):
    def assign(self, jobs, robots, context):
        return []
'''


def install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, entry_points: str) -> str:
    """Install a distribution ``acme-fleet`` into tmp_path (appended to sys.path).

    Returns the name of its module, unique per test so no import from an earlier test is reused.
    """
    module = f"acme_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{module}.py").write_text(THIRD_PARTY)
    info = tmp_path / "acme_fleet-2.3.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-fleet\nVersion: 2.3\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points).replace("MODULE", module))
    # Appended, not prepended: the built-ins stay first on sys.path, as an installed
    # third party would be found after the project in a typical environment.
    monkeypatch.setattr(sys, "path", [*sys.path, str(tmp_path)])
    monkeypatch.delitem(sys.modules, module, raising=False)
    return module


ENTRY_POINTS = f"""
[{CONTROLLER_GROUP}]
acme = MODULE:GoodController
ghost = acme_no_such_module:Ghost
impostor = MODULE:NotAController
half = MODULE:HalfController
follower = MODULE:GoodController

[{DISPATCHER_GROUP}]
acme_dispatch = MODULE:GoodDispatcher
"""


def by_name(infos: list[PluginInfo]) -> dict[str, list[PluginInfo]]:
    out: dict[str, list[PluginInfo]] = {}
    for info in infos:
        out.setdefault(info.name, []).append(info)
    return out


# --- discovery ------------------------------------------------------------------------------------


def test_builtins_are_discovered_from_the_project_distribution() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", PluginWarning)  # the built-ins must not warn
        found = {(i.kind, i.name): i for i in discover()}
    follower = found[("controller", "follower")]
    greedy = found[("dispatcher", "greedy")]
    assert follower.factory is PathFollower and follower.error is None and follower.ok
    assert greedy.factory is GreedyDispatcher and greedy.error is None
    assert follower.group == CONTROLLER_GROUP and greedy.group == DISPATCHER_GROUP
    assert follower.value == "fleet_plugins.follower:PathFollower"
    assert follower.distribution == greedy.distribution == "mambot-fleet"
    assert follower.version == "0.1.0"
    assert follower.origin is not None and Path(follower.origin).parent.name == "follower"


def test_discover_sorts_by_kind_then_name_and_filters_by_kind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    install(tmp_path, monkeypatch, ENTRY_POINTS)
    with pytest.warns(PluginWarning):
        everything = discover(refresh=True)
    keys = [(i.kind, i.name) for i in everything]
    assert keys == sorted(keys)
    assert {i.kind for i in discover("controller")} == {"controller"}
    assert {i.kind for i in discover("dispatcher")} == {"dispatcher"}
    with pytest.raises(ValueError, match="'robot'.*controller, dispatcher"):
        discover("robot")


def test_discovery_is_cached_until_refreshed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = [i.name for i in discover("dispatcher")]
    install(tmp_path, monkeypatch, f"[{DISPATCHER_GROUP}]\nacme_dispatch = MODULE:GoodDispatcher\n")
    assert [i.name for i in discover("dispatcher")] == before  # still the cached answer
    names = [i.name for i in discover("dispatcher", refresh=True)]
    assert "acme_dispatch" in names and "acme_dispatch" not in before


def test_broken_plugins_are_skipped_with_a_warning_and_listed_with_their_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    module = install(tmp_path, monkeypatch, ENTRY_POINTS)
    with pytest.warns(PluginWarning) as caught:
        found = by_name(discover(refresh=True))
    messages = [str(w.message) for w in caught]

    ghost = found["ghost"][0]
    assert ghost.factory is None and not ghost.ok
    assert "acme_no_such_module" in ghost.error and "ModuleNotFoundError" in ghost.error
    assert ghost.distribution == "acme-fleet" and ghost.version == "2.3"
    impostor = found["impostor"][0]
    assert impostor.factory is None
    assert "not a subclass of fleet.plugins.Controller" in impostor.error
    assert impostor.origin == str(tmp_path / f"{module}.py")
    half = found["half"][0]
    assert half.factory is None and "abstract method(s) compute" in half.error

    # One warning per broken plugin, naming it, its entry point and the problem.
    for name, problem in [
        ("ghost", "acme_no_such_module"),
        ("impostor", "not a subclass"),
        ("half", "compute"),
    ]:
        hits = [m for m in messages if f"'{name}'" in m]
        assert len(hits) == 1, messages
        assert CONTROLLER_GROUP in hits[0] and "acme-fleet" in hits[0] and problem in hits[0]

    # The broken ones never stop the good ones loading.
    assert found["acme"][0].ok and found["acme_dispatch"][0].ok


def test_a_duplicate_name_keeps_the_first_plugin_and_warns_about_the_other(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    install(tmp_path, monkeypatch, ENTRY_POINTS)
    with pytest.warns(PluginWarning) as caught:
        found = by_name(discover(refresh=True))
    (message,) = [str(w.message) for w in caught if "'follower'" in str(w.message)]
    assert "acme-fleet" in message and "already taken" in message and "mambot-fleet" in message
    winner, shadowed = found["follower"]
    assert winner.factory is PathFollower and winner.distribution == "mambot-fleet"
    assert shadowed.factory is None and shadowed.distribution == "acme-fleet"
    assert isinstance(load_controller("follower"), PathFollower)


def test_a_third_party_plugin_is_found_and_loadable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    module = install(tmp_path, monkeypatch, ENTRY_POINTS)
    with pytest.warns(PluginWarning):
        discover(refresh=True)
    controller = load_controller("acme", {"level": 3})
    assert type(controller).__module__ == module and controller.level == 3
    dispatcher = load_dispatcher("acme_dispatch")
    assert isinstance(dispatcher, Dispatcher) and type(dispatcher).__name__ == "GoodDispatcher"


def test_loading_a_broken_plugin_says_why(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    install(tmp_path, monkeypatch, ENTRY_POINTS)
    with pytest.warns(PluginWarning):
        discover(refresh=True)
    with pytest.raises(PluginError, match=r"'ghost'.*cannot be used.*acme_no_such_module"):
        load_controller("ghost")
    with pytest.raises(PluginError, match=r"'impostor'.*not a subclass"):
        load_controller("impostor")


def test_unknown_names_list_the_available_plugins() -> None:
    with pytest.raises(
        PluginError, match=r"no controller plugin named 'mpc2'.*available: .*follower"
    ):
        load_controller("mpc2")
    with pytest.raises(PluginError, match=r"fleet.dispatchers.*available: .*greedy"):
        load_dispatcher("follower")  # a controller's name is not a dispatcher


def test_options_reach_the_constructor_and_bad_ones_name_plugin_and_option() -> None:
    assert load_controller("follower", {"gain": 0.25}).gain == 0.25
    assert load_dispatcher("greedy", {"metric": "travel_time"}).metric == "travel_time"
    with pytest.raises(PluginError, match=r"'follower'.*'gian'") as err:
        load_controller("follower", {"gian": 0.25})
    assert isinstance(err.value.__cause__, TypeError)
    with pytest.raises(PluginError, match=r"'greedy'.*metric = 'manhattan'.*'euclidean'"):
        load_dispatcher("greedy", {"metric": "manhattan"})


# --- the conformance kit fails plugins that break their contract ----------------------------------


class Reckless(PathFollower):
    """Follows the path but accelerates 20 % harder than the robot can."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        cmd = super().compute(obs)
        return replace(cmd, ax=cmd.ax * 1.2, ay=cmd.ay * 1.2)


class Stubborn(PathFollower):
    """Ignores the goal: always brakes."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        return super().compute(replace(obs, goal=None))


class Beeline(Controller):
    """Drives straight at the goal (PD, per-axis speed 0.9): right through the press."""

    def reset(self, context):  # type: ignore[no-untyped-def]
        self.context = context

    def compute(self, obs):  # type: ignore[no-untyped-def]
        dt, a = self.context.spec.period, self.context.spec.a_max
        v = np.array([obs.vx, obs.vy])
        if obs.goal is None:
            target = np.zeros(2)
            status = ControlStatus.IDLE
        else:
            err = np.array(obs.goal) - np.array([obs.x, obs.y])
            target = np.clip(0.5 * err, -0.9, 0.9)
            status = ControlStatus.OK
        u = np.clip((target - v) / dt, -a, a)
        return Command(float(u[0]), float(u[1]), status)


class Chatty(PathFollower):
    """Says OK instead of IDLE when it has nothing to do."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        return replace(super().compute(obs), status=ControlStatus.OK)


class Moody(PathFollower):
    """Each instance differs a little: not reproducible across processes."""

    created = 0

    def __init__(self) -> None:
        super().__init__()
        type(self).created += 1
        self.nth = type(self).created

    def compute(self, obs):  # type: ignore[no-untyped-def]
        cmd = super().compute(obs)
        return replace(cmd, plan=((float(self.nth), obs.x, obs.y),))


class Broken(PathFollower):
    """Returns a NaN acceleration."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        return replace(super().compute(obs), ax=math.nan)


PlanPoint = namedtuple("PlanPoint", "t x y")


class NamedPlan(PathFollower):
    """Plan samples as namedtuples: a tuple to Python, not a [t, x, y] triple to the bus."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        cmd = super().compute(obs)
        return replace(cmd, plan=tuple(PlanPoint(*sample) for sample in cmd.plan))


class NumpyRows(PathFollower):
    """Plan samples as numpy rows."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        cmd = super().compute(obs)
        return replace(cmd, plan=tuple(np.array(sample) for sample in cmd.plan))


class ArrayPlan(PathFollower):
    """The whole plan as one (n, 3) numpy array, which the bus cannot even test for emptiness."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        cmd = super().compute(obs)
        return replace(cmd, plan=np.array(cmd.plan).reshape(-1, 3))


class BadReset(PathFollower):
    """Fails before its first observation."""

    def reset(self, context):  # type: ignore[no-untyped-def]
        raise KeyError("robot_radius")


class Coasting(PathFollower):
    """Says IDLE when the goal goes but lets a moving robot coast on."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        if obs.goal is None:
            return Command(0.0, 0.0, ControlStatus.IDLE)
        return super().compute(obs)


class Oblivious(Controller):
    """The reference's velocities by the clock, blind to the robot's position (an earlier README
    example): fine until the engine brakes the robot, then it demands a jump back to them."""

    def reset(self, context):  # type: ignore[no-untyped-def]
        super().reset(context)
        self.reference, self.goal = None, None

    def compute(self, obs):  # type: ignore[no-untyped-def]
        spec = self.context.spec
        moving = obs.vx != 0 or obs.vy != 0
        if obs.goal is None or (obs.goal != self.goal and moving):
            ax, ay = brake_input(obs.vx, obs.vy, spec.period, spec.a_max)
            return Command(ax, ay, ControlStatus.IDLE if obs.goal is None else ControlStatus.OK)
        if obs.goal != self.goal:
            self.goal = obs.goal
            self.reference = self.context.planner.reference(
                (obs.x, obs.y), obs.goal, dt=spec.period, t0=obs.t
            )
        k = min(self.reference.index(obs.t) + 1, self.reference.steps)
        vx, vy = self.reference.velocities[k]
        return Command((vx - obs.vx) / spec.period, (vy - obs.vy) / spec.period)


@pytest.mark.parametrize(
    ("factory", "rule", "words"),
    [
        (Reckless, "accel-bound", "a_max = 0.5"),
        (Stubborn, "reach-goal", "towards (18, 7)"),
        (Beeline, "free-space", "leaves the free space"),
        (Chatty, "idle", "expected IDLE"),
        (Moody, "determinism", "fresh one"),
        (Broken, "command", "command.ax = nan: must be a finite number"),
        (NamedPlan, "command", "PlanPoint(t=1.0, x=2.0, y=5.0): must be a [t, x, y] triple"),
        (NumpyRows, "command", "array([1., 2., 5.]): must be a [t, x, y] triple"),
        (ArrayPlan, "command", "plan of type ndarray): ValueError"),
        (BadReset, "reset", "reset raised KeyError: 'robot_radius'"),
        (Coasting, "idle", "still moving at v = (0, -0.894737) after 16 ticks (4 s)"),
        (Oblivious, "accel-bound", "substituted the engine's braking for the commands of ticks"),
    ],
)
def test_check_controller_fails_a_bad_controller_naming_the_rule(
    factory: type, rule: str, words: str
) -> None:
    with pytest.raises(ConformanceError) as err:
        check_controller(factory)
    assert err.value.rule == rule
    message = str(err.value)
    assert f"rule {rule!r} broken" in message and words in message
    assert factory.__qualname__ in message


class LooseTypes(PathFollower):
    """Numbers as numpy scalars and ints, plan samples as lists, no plan as None: all of which
    the bus accepts and converts, so the kit accepts them too."""

    def compute(self, obs):  # type: ignore[no-untyped-def]
        cmd = super().compute(obs)
        ay = int(cmd.ay) if cmd.ay == int(cmd.ay) else cmd.ay
        plan = [list(sample) for sample in cmd.plan] or None
        return Command(np.float64(cmd.ax), ay, cmd.status, plan)  # type: ignore[arg-type]


def test_check_controller_accepts_what_the_bus_accepts() -> None:
    check_controller(LooseTypes)


def test_check_controller_reports_options_the_plugin_rejects() -> None:
    with pytest.raises(ConformanceError, match=r"'instantiate'.*gain = 3"):
        check_controller(PathFollower, options={"gain": 3})


class TakesTheFirst(Dispatcher):
    """Pairs jobs with robots in list order, busy or not."""

    def assign(self, jobs, robots, context):  # type: ignore[no-untyped-def]
        return [Assignment(j.id, r.robot) for j, r in zip(jobs, robots, strict=False)]


class Sorter(GreedyDispatcher):
    """Sorts the caller's job list in place."""

    def assign(self, jobs, robots, context):  # type: ignore[no-untyped-def]
        jobs.sort(key=lambda j: j.id)
        return super().assign(jobs, robots, context)


class Doubler(Dispatcher):
    """Gives every open job to the first idle robot."""

    def assign(self, jobs, robots, context):  # type: ignore[no-untyped-def]
        idle = [r for r in robots if r.idle]
        return [Assignment(j.id, idle[0].robot) for j in jobs] if idle else []


class Lazy(Dispatcher):
    """Never assigns anything."""

    def assign(self, jobs, robots, context):  # type: ignore[no-untyped-def]
        return []


class Inventor(GreedyDispatcher):
    """Adds a job nobody asked for."""

    def assign(self, jobs, robots, context):  # type: ignore[no-untyped-def]
        idle = [r for r in robots if r.idle]
        return [Assignment("made-up", idle[0].robot)] if idle and jobs else []


class RoundRobin(Dispatcher):
    """Rotates which idle robot goes first with every call: stateful, yet reproducible."""

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def assign(self, jobs, robots, context):  # type: ignore[no-untyped-def]
        self.calls += 1
        idle = sorted(r.robot for r in robots if r.idle)
        if idle:
            k = self.calls % len(idle)
            idle = idle[k:] + idle[:k]
        ordered = sorted(jobs, key=lambda j: (j.released_s, j.id))
        return [Assignment(j.id, r) for j, r in zip(ordered, idle, strict=False)]


class Unrepeatable(RoundRobin):
    """Rotates by how many instances exist: a second process would dispatch differently."""

    created = 0

    def __init__(self) -> None:
        super().__init__()
        type(self).created += 1
        self.calls = type(self).created


@pytest.mark.parametrize(
    ("factory", "rule", "words"),
    [
        (TakesTheFirst, "idle-robots", "is busy with"),
        (Sorter, "no-mutation", "an input was changed"),
        (Doubler, "unique", "assigned twice"),
        (Lazy, "progress", "nothing assigned"),
        (Inventor, "open-jobs", "'made-up' is not open"),
        (Unrepeatable, "deterministic", "given the same cases in the same order"),
    ],
)
def test_check_dispatcher_fails_a_bad_dispatcher_naming_the_rule(
    factory: type, rule: str, words: str
) -> None:
    with pytest.raises(ConformanceError) as err:
        check_dispatcher(factory)
    assert err.value.rule == rule
    assert f"rule {rule!r} broken" in str(err.value) and words in str(err.value)


def test_check_dispatcher_accepts_a_dispatcher_that_keeps_state_between_calls() -> None:
    check_dispatcher(RoundRobin)


def test_conformance_errors_are_assertion_errors_so_pytest_reports_failures() -> None:
    assert issubclass(ConformanceError, AssertionError)


def test_fleet_plugins_command_lists_broken_plugins_with_their_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from fleet.cli import main

    install(tmp_path, monkeypatch, ENTRY_POINTS)
    monkeypatch.setenv("COLUMNS", "200")
    assert main(["plugins"]) == 0
    out, err = capsys.readouterr()
    assert "acme-fleet 2.3" in out and "acme_dispatch" in out
    assert "broken: cannot import 'acme_no_such_module:Ghost'" in out  # listed with its error
    assert "warning:" in err and "'ghost'" in err


# --- discovery from many threads ------------------------------------------------------------------


@pytest.mark.parametrize("refresh", [False, True], ids=["first-read", "refresh"])
def test_threads_reading_the_registry_at_once_all_see_all_of_it(refresh: bool) -> None:
    # A Dask worker's threads start cells at the same moment, each loading its plugins: none
    # may see a registry that another thread is still filling (it used to raise KeyError).
    threads = 16
    barrier = threading.Barrier(threads)
    failures: list[BaseException] = []
    seen: list[set[str]] = []

    def load() -> None:
        try:
            barrier.wait()
            found = discover(refresh=refresh)
            load_controller("follower")
            load_dispatcher("greedy")
            seen.append({f"{i.kind}:{i.name}" for i in found if i.ok})
        except BaseException as exc:  # noqa: BLE001 - any exception is the finding
            failures.append(exc)

    workers = [threading.Thread(target=load) for _ in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=60)
    assert failures == []
    assert len(seen) == threads
    assert all(s == seen[0] for s in seen)
    assert {"controller:follower", "controller:mpc", "dispatcher:greedy"} <= seen[0]
