"""The bus: wire schema, address checks, and exchange/agent round trips over real ZeroMQ sockets."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import multiprocessing
import random
import re
import socket
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import zmq
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.bus import (
    SCHEMA_VERSION,
    AddressError,
    AgentHost,
    Exchange,
    MessageKind,
    braking_command,
    command_from_wire,
    command_to_wire,
    decode,
    encode,
    observation_from_wire,
    observation_to_wire,
    parse_address,
    transport,
)
from fleet.bus.schema import MAX_MESSAGE_BYTES, MAX_ROBOTS, MAX_TEXT_CHARS
from fleet.bus.transport import new_inproc_address
from fleet.errors import FleetError, MessageError
from fleet.plugins import (
    Announcement,
    Bid,
    Command,
    Controller,
    ControllerContext,
    ControlStatus,
    Handback,
    Neighbour,
    Observation,
    RobotSpec,
    SolveReport,
    SolverOutcome,
)
from fleet.plugins.robot import brake_input

# --- test plugins and helpers --------------------------------------------------------------------


class Echo(Controller):
    """Answers ``ax = -vx, ay = tick`` so a test can tell which observation a command answers."""

    def compute(self, obs: Observation) -> Command:
        return Command(-obs.vx, float(obs.tick), ControlStatus.OK, ((obs.t, obs.x, obs.y),))


class Exploding(Controller):
    def compute(self, obs: Observation) -> Command:
        raise RuntimeError(f"boom at tick {obs.tick}")


class ReturnsNaN(Controller):
    def compute(self, obs: Observation) -> Command:
        return Command(math.nan, 0.0)


def with_spec(controller: Controller, spec: RobotSpec) -> Controller:
    # Braking needs only the spec; the floor and planner play no part in these tests.
    controller.reset(ControllerContext("r", spec, floor=None, planner=None))  # type: ignore[arg-type]
    return controller


def observation(robot: str, tick: int, vx: float = 0.25, **kw) -> Observation:
    return Observation(robot, tick, tick * 0.25, 1.0 + tick, -2.0, vx, -0.5, **kw)


def expected(obs: Observation) -> Command:
    return Command(-obs.vx, float(obs.tick), ControlStatus.OK, ((obs.t, obs.x, obs.y),))


def hello(name: str, robots: list[str], scenario: str = "") -> bytes:
    """A raw agent's HELLO frame."""
    return encode(MessageKind.HELLO, name, 0, {"robots": robots, "scenario": scenario})


def act(name: str, tick: int, commands: dict, bids=(), handbacks=()) -> bytes:
    """A raw agent's ACT frame."""
    body = {"commands": commands, "bids": list(bids), "handbacks": list(handbacks)}
    return encode(MessageKind.ACT, name, tick, body)


def heartbeat(name: str, tick: int = 0) -> bytes:
    """A raw agent's HEARTBEAT frame."""
    return encode(MessageKind.HEARTBEAT, name, tick, {})


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_rounds(exchange: Exchange, robots: list[str], rounds: int, seed: int = 7) -> None:
    """Drive `rounds` ticks, each with a random subset of robots due, and check every answer."""
    rng = random.Random(seed)
    for tick in range(1, rounds + 1):
        due = [r for r in robots if rng.random() < 0.8] or robots[:1]
        obs = [observation(r, tick, vx=rng.uniform(-1, 1)) for r in due]
        rng.shuffle(obs)  # the result must not depend on the order observations come in
        result = exchange.round(tick, tick * 0.25, obs)
        assert list(result) == sorted(due)
        assert result == {o.robot: expected(o) for o in obs}


def serve_in_thread(address: str, controllers: dict, name: str) -> tuple[threading.Thread, list]:
    """Start a host serving `controllers` in a thread; the list receives it once it is done."""
    done: list[AgentHost] = []

    def agent() -> None:
        # zmq sockets belong to one thread: the host is made where it is served.
        with AgentHost(address, controllers, name=name) as host:
            host.serve(idle_timeout_s=30)
        done.append(host)

    worker = threading.Thread(target=agent, daemon=True)
    worker.start()
    return worker, done


def flood(address: str, first: bytes, frame: bytes, stop: threading.Event) -> tuple:
    """A thread that sends `first`, then `frame` over and over until `stop` is set.

    Gives up after 5 s; the returned list then holds True, telling the test that what it was
    waiting for did not end while the flood was going on.
    """
    outlasted: list[bool] = []

    def spam() -> None:
        sock = zmq.Context.instance().socket(zmq.DEALER)
        sock.connect(address)
        sock.send(first)
        give_up = time.monotonic() + 5.0
        try:
            while not stop.is_set():
                if time.monotonic() > give_up:
                    outlasted.append(True)
                    return
                with contextlib.suppress(zmq.Again):  # full queue: the exchange is busy
                    sock.send(frame, zmq.NOBLOCK)
        finally:
            sock.close(linger=0)

    worker = threading.Thread(target=spam, daemon=True)
    worker.start()
    return worker, outlasted


def serve_echo(address: str, robots: list[str], name: str) -> None:
    """Target of the agent process in the tcp test (must be importable by a spawned child)."""
    with AgentHost(address, {r: Echo() for r in robots}, name=name) as host:
        host.serve(idle_timeout_s=60)


# --- schema: round trips -------------------------------------------------------------------------

OBS_FULL = Observation(
    "r1",
    7,
    1.75,
    3.5,
    -2.25,
    0.5,
    -0.125,
    goal=(10.0, 4.0),
    job="job-3",
    speed_cap=0.3,
    neighbours=(
        Neighbour("r2", 4.0, -2.0, 0.1, 0.0, 0.35, 3, ((1.75, 4.0, -2.0), (2.0, 4.025, -2.0))),
        Neighbour("r3", 1.0, 1.0, 0.0, -0.2),
    ),
    speed_caps=((1.75, 21.0, 0.3), (21.0, 51.0, 0.5)),
    print_end_s=1242.5,
    priority=-2,
    blockers=("r2", "r3"),
    queued=1,
)
OBS_IDLE = Observation("r2", 7, 1.75, 0.0, 0.0, 0.0, 0.0)  # goal None, no job, no neighbours
CMD_PLAN = Command(
    0.5,
    -0.25,
    ControlStatus.FALLBACK,
    ((2.0, 3.5, -2.0), (2.25, 3.6, -1.9)),
    SolveReport(SolverOutcome.NO_SOLUTION, 0.25, 0.2625),
)

BODIES = {
    MessageKind.HELLO: {"robots": ["r1", "r2"], "scenario": "sha256:0f3a"},
    MessageKind.WELCOME: {"accepted": ["r1"], "rejected": {"r2": "already hosted by agent 'a'"}},
    MessageKind.OBSERVE: {
        "t": 1.75,
        "observations": [OBS_FULL, OBS_IDLE],
        "announcements": [
            Announcement("job-4", 3.0, -1.5, 120.0, 1.5, 900.0),
            Announcement("job-5", 0.0, 2.0, 0.0, 1.75),
        ],
    },
    MessageKind.ACT: {
        "commands": {"r1": CMD_PLAN, "r2": Command(0.0, 0.0, ControlStatus.BLOCKED)},
        "bids": [Bid("job-4", "r1", 42.5), Bid("job-5", "r2", 0.0)],
        "handbacks": [Handback("r2", "job-1", "blocked")],
    },
    MessageKind.HEARTBEAT: {},
    MessageKind.BYE: {"reason": "run finished"},
}


@pytest.mark.parametrize("kind", list(MessageKind))
def test_every_message_kind_round_trips(kind):
    raw = encode(kind, "agent-1", 7, BODIES[kind])
    msg = decode(raw)
    assert (msg.kind, msg.sender, msg.tick, msg.version) == (kind, "agent-1", 7, SCHEMA_VERSION)
    assert msg.body == BODIES[kind]
    # Compact JSON, UTF-8, one object, the kind's value on the wire.
    text = raw.decode("utf-8")
    assert ", " not in text and ": " not in text
    assert json.loads(text)["kind"] == kind.value


def test_observation_round_trips_with_neighbours_plan_and_none_goal():
    for obs in (OBS_FULL, OBS_IDLE):
        wire = observation_to_wire(obs)
        assert observation_from_wire(json.loads(json.dumps(wire))) == obs
    assert observation_to_wire(OBS_IDLE)["goal"] is None
    assert json.loads(json.dumps(observation_to_wire(OBS_FULL)["neighbours"])) == [
        ["r2", 4.0, -2.0, 0.1, 0.0, 0.35, 3, [[1.75, 4.0, -2.0], [2.0, 4.025, -2.0]]]
        + [None, None, None],
        ["r3", 1.0, 1.0, 0.0, -0.2, 0.4, 0, [], None, None, None],
    ]


@pytest.mark.parametrize("outcome", list(SolverOutcome))
def test_solve_reports_round_trip_with_every_outcome(outcome):
    cmd = Command(0.1, 0.2, ControlStatus.OK, (), SolveReport(outcome, 0.004, 0.005))
    assert command_from_wire(json.loads(json.dumps(command_to_wire(cmd)))) == cmd
    assert command_to_wire(Command(0.0, 0.0))["solve"] is None


@pytest.mark.parametrize("status", list(ControlStatus))
def test_command_round_trips_with_every_status(status):
    cmd = Command(CMD_PLAN.ax, CMD_PLAN.ay, status, CMD_PLAN.plan)
    assert command_from_wire(json.loads(json.dumps(command_to_wire(cmd)))) == cmd
    assert command_to_wire(cmd)["status"] == status.value


def test_encode_accepts_wire_dicts_as_well_as_objects():
    offer = Announcement("j", 1.0, 2.0, 3.0, 4.0)
    body = {
        "t": 1.75,
        "observations": [observation_to_wire(OBS_FULL)],
        "announcements": [["j", 1.0, 2.0, 3.0, 4.0, None]],
    }
    got = decode(encode(MessageKind.OBSERVE, "x", 7, body)).body
    assert got == {"t": 1.75, "observations": [OBS_FULL], "announcements": [offer]}
    body = {
        "commands": {"r1": command_to_wire(CMD_PLAN)},
        "bids": [["j", "r1", 2]],
        "handbacks": [["r1", "j", "blocked"]],
    }
    assert decode(encode(MessageKind.ACT, "x", 7, body)).body == {
        "commands": {"r1": CMD_PLAN},
        "bids": [Bid("j", "r1", 2.0)],
        "handbacks": [Handback("r1", "j", "blocked")],
    }


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
names = st.text(min_size=1, max_size=12)
samples = st.lists(st.tuples(finite, finite, finite), max_size=4).map(tuple)
neighbours = st.builds(
    Neighbour,
    names,
    finite,
    finite,
    finite,
    finite,
    st.floats(min_value=0.0, exclude_min=True, allow_infinity=False),
    st.integers(-(2**40), 2**40),
    samples,
)
observations = st.builds(
    Observation,
    names,
    st.integers(0, 2**53),
    finite,
    finite,
    finite,
    finite,
    finite,
    st.none() | st.tuples(finite, finite),
    st.none() | names,
    st.none() | st.floats(0, 1e6),
    st.lists(neighbours, max_size=3).map(tuple),
    st.just(()),
    st.none() | finite,
    st.integers(-(2**40), 2**40),
    st.lists(names, max_size=3).map(tuple),
    st.integers(0, 2**40),
)
commands = st.builds(
    Command,
    finite,
    finite,
    st.sampled_from(ControlStatus),
    st.lists(st.tuples(finite, finite, finite), max_size=4).map(tuple),
)


@settings(max_examples=60, deadline=None)
@given(obs=observations, cmd=commands, tick=st.integers(0, 2**40))
def test_any_finite_observation_and_command_survive_the_wire_exactly(obs, cmd, tick):
    body = {"t": 0.0, "observations": [obs], "announcements": []}
    msg = decode(encode(MessageKind.OBSERVE, "exchange", tick, body))
    assert msg.body["observations"] == [obs]
    body = {"commands": {obs.robot: cmd}, "bids": [], "handbacks": []}
    msg = decode(encode(MessageKind.ACT, "a", tick, body))
    assert msg.body["commands"] == {obs.robot: cmd}


# --- schema: rejection ---------------------------------------------------------------------------


def envelope(**over) -> dict:
    env = {
        "version": SCHEMA_VERSION,
        "kind": "bye",
        "sender": "a",
        "tick": 3,
        "body": {"reason": "x"},
    }
    env.update(over)
    return env


def observe_with(**fields) -> dict:
    obs = observation_to_wire(OBS_FULL)
    obs.update(fields)
    return envelope(kind="observe", body={"t": 1.0, "observations": [obs], "announcements": []})


def act_with(**fields) -> dict:
    cmd = command_to_wire(CMD_PLAN)
    cmd.update(fields)
    return envelope(kind="act", body={"commands": {"r1": cmd}, "bids": [], "handbacks": []})


def raw(obj: object) -> bytes:
    return json.dumps(obj).encode()


def test_a_hello_with_many_ids_names_exactly_the_duplicates():
    robots = [f"r{i}" for i in range(MAX_ROBOTS - 3)] + ["r7", f"r{MAX_ROBOTS - 4}", "r7"]
    body = {"robots": robots, "scenario": ""}
    names = str(sorted(["r7", f"r{MAX_ROBOTS - 4}"]))
    with pytest.raises(MessageError, match=re.escape(f"body.robots = {names}: robot ids")):
        decode(raw(envelope(kind="hello", body=body)))


def test_a_hello_naming_more_robots_than_allowed_is_rejected_by_its_length():
    robots = [f"r{i}" for i in range(2 * MAX_ROBOTS)] + ["r7"]
    body = {"robots": robots, "scenario": ""}
    with pytest.raises(MessageError, match=f"holds {2 * MAX_ROBOTS + 1:,} items: at most"):
        decode(raw(envelope(kind="hello", body=body)))


@pytest.mark.parametrize(
    ("body", "said"),
    [
        ({"reason": "x" * (MAX_TEXT_CHARS + 1)}, "body.reason = 'xxx"),
        ({"reason": "ok", "extra": ["x"] * 10}, "unexpected field(s) ['extra']"),
    ],
)
def test_a_bye_with_too_long_a_reason_or_an_extra_field_is_rejected(body, said):
    with pytest.raises(MessageError, match=re.escape(said)):
        decode(raw(envelope(kind="bye", body=body)))


def test_a_frame_over_the_size_limit_is_rejected_unread():
    frame = raw(envelope(kind="bye", body={"reason": "x" * 100}))
    assert decode(frame, max_bytes=len(frame)).body == {"reason": "x" * 100}
    with pytest.raises(MessageError, match=f"of {len(frame):,} bytes: longer than"):
        decode(frame, max_bytes=len(frame) - 1)
    with pytest.raises(MessageError, match="longer than the bus's limit of 2,097,152 bytes"):
        decode(b"[" * (MAX_MESSAGE_BYTES + 1))


MALFORMED = [
    (b"\xff\xfe garbage", "is not UTF-8"),
    (b"{not json", "is not valid JSON"),
    (b'{"version": 1} trailing', "is not valid JSON"),
    (raw([1, 2, 3]), "must be a JSON object"),
    (raw(envelope(version=1)), "version = 1: unsupported schema version"),
    (raw(envelope(version=3)), "version = 3: unsupported schema version"),
    (raw(envelope(version=4)), "version = 4: unsupported schema version"),
    (raw(envelope(version=6)), "version = 6: unsupported schema version"),
    (raw(envelope(version="1")), "version = '1'"),
    (raw({"kind": "bye"}), "version = None"),
    (raw(envelope(kind="shout")), "kind = 'shout': must be one of 'hello'"),
    (raw(envelope(sender="")), "sender = '': must be a non-empty string"),
    (raw(envelope(tick=-1)), "tick = -1: must be an integer >= 0"),
    (raw(envelope(tick=True)), "tick = True"),
    (raw(envelope(tick=1.5)), "tick = 1.5"),
    (raw(envelope(extra=1)), "unexpected field(s) ['extra']"),
    (raw({k: v for k, v in envelope().items() if k != "body"}), "missing field(s) body"),
    (raw(envelope(body={"reason": "x", "more": 1})), "BYE message from 'a': body: unexpected"),
    (raw(envelope(body=[])), "body = []: must be a JSON object"),
    (raw(envelope(kind="hello", body={"robots": ["r1", "r1"], "scenario": ""})), "must be unique"),
    (raw(envelope(kind="hello", body={"robots": ["r1", 7], "scenario": ""})), "robots = 7"),
    (raw(observe_with(vx="fast")), "observations[0].vx = 'fast': must be a finite number"),
    (raw(observe_with(x=True)), "observations[0].x = True: must be a finite number"),
    (
        raw(observe_with(y=12345.5)).replace(b"12345.5", b"1e999"),  # overflows to inf
        "observations[0].y = inf: must be a finite number",
    ),
    (raw(observe_with(goal=[1.0])), "observations[0].goal = [1.0]: must be null or [x, y]"),
    (raw(observe_with(goal=[1.0, None])), "observations[0].goal[1] = None"),
    (raw(observe_with(robot="")), "observations[0].robot = ''"),
    (raw(observe_with(tick=-3)), "observations[0].tick = -3"),
    (raw(observe_with(speed_cap=-1.0)), "speed_cap = -1.0: must be null or >= 0"),
    (raw(observe_with(neighbours=[["r2", 1.0, 2.0]])), "neighbours[0] = ['r2', 1.0, 2.0]"),
    (raw(observe_with(neighbours=[["r2", 1, 2, "a", 4, 0.4, 0, []]])), "neighbours[0] = 'a'"),
    (
        raw(observe_with(neighbours=[["r2", 1, 2, 3, 4]])),
        "neighbours[0] = ['r2', 1, 2, 3, 4]: must be [robot, x, y, vx, vy, radius, priority, plan,"
        " v_max, a_max, period]",
    ),
    (raw(observe_with(colour="red")), "unexpected field(s) ['colour']"),
    (raw(act_with(status="panic")), "status = 'panic': must be one of 'ok'"),
    (raw(act_with(ax=None)), "commands['r1'].ax = None: must be a finite number"),
    (raw(act_with(plan=[[0.0, 1.0]])), "plan[0] = [0.0, 1.0]: must be a [t, x, y] triple"),
    (raw(act_with(plan=[[0.0, 1.0, 12345.5]])).replace(b"12345.5", b"-1e400"), "plan[0] = -inf"),
    (raw(act_with(plan={"t": 1})), "plan = {'t': 1}: must be an array"),
    (raw(observe_with(speed_caps=None)), "speed_caps = None: must be an array"),
    (raw(observe_with(print_end_s="soon")), "print_end_s = 'soon': must be a finite number"),
    (raw(observe_with(speed_caps=[[0.0, 1.0]])), "speed_caps[0] = [0.0, 1.0]: must be"),
    (raw(observe_with(speed_caps=[[2.0, 1.0, 0.3]])), "speed_caps[0] = [2.0, 1.0, 0.3]"),
    (
        raw(observe_with(speed_caps=[[0.0, 2.0, 0.3], [1.0, 3.0, 0.5]])),
        "speed_caps[1] = [1.0, 3.0, 0.5]: pieces must be sorted, non-overlapping",
    ),
    (raw(act_with(solve=["great", 0.1, 0.2])), "solve[0] = 'great': must be one of 'optimal'"),
    (raw(act_with(solve=["optimal", -0.1, 0.2])), "solve[1] = -0.1: must be >= 0"),
    (raw(act_with(solve=["optimal", 0.1])), "solve = ['optimal', 0.1]: must be null or"),
    (raw({k: v for k, v in act_with().items()} | {"version": 1}), "unsupported schema version"),
]


@pytest.mark.parametrize(("frame", "says"), MALFORMED, ids=[m[1][:40] for m in MALFORMED])
def test_malformed_messages_are_rejected_saying_what_is_wrong(frame, says):
    with pytest.raises(MessageError) as info:
        decode(frame)
    assert says in str(info.value)
    assert isinstance(info.value, FleetError)


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_json_constants_for_non_finite_numbers_are_rejected(constant):
    text = json.dumps(observe_with(x=0.0)).replace('"x": 0.0', f'"x": {constant}')
    with pytest.raises(MessageError, match=f"{constant} is not a finite number"):
        decode(text.encode())


def test_long_bad_values_are_quoted_truncated():
    with pytest.raises(MessageError) as info:
        decode(raw(observe_with(job=["x" * 5000])))
    text = str(info.value)
    assert "observations[0].job = ['xxxx" in text and "..." in text
    assert len(text) < 400


def test_unexpected_kind_is_rejected_naming_what_was_expected():
    frame = hello("a", [])
    with pytest.raises(MessageError, match="unexpected kind HELLO; expected ACT, BYE"):
        decode(frame, expect=(MessageKind.ACT, MessageKind.BYE))


def test_encode_refuses_non_finite_values_and_names_where():
    bad = Observation("r1", 1, 0.0, math.inf, 0.0, 0.0, 0.0)
    with pytest.raises(MessageError, match=r"body.observations\[0\].x = inf"):
        body = {"t": 0.0, "observations": [bad], "announcements": []}
        encode(MessageKind.OBSERVE, "exchange", 1, body)
    with pytest.raises(MessageError, match="robot 'r7'.*command.ay = nan"):
        act("a", 1, {"r7": Command(0.0, math.nan)})
    with pytest.raises(MessageError, match="tick = -1"):
        encode(MessageKind.BYE, "a", -1, {"reason": ""})


@pytest.mark.parametrize(
    ("kind", "body", "says"),
    [
        (
            MessageKind.ACT,
            {},
            "ACT from 'a' at tick 1: body: missing field(s) bids, commands, handbacks",
        ),
        (
            MessageKind.ACT,
            {"commands": [1.0], "bids": [], "handbacks": []},
            "body.commands = [1.0]: must be a mapping",
        ),
        (
            MessageKind.ACT,
            {"commands": {"r1": (0.0, 0.0)}, "bids": [], "handbacks": []},
            "body.commands['r1'] = (0.0, 0.0): must be a fleet.plugins.Command",
        ),
        (
            MessageKind.OBSERVE,
            {"observations": [], "announcements": []},
            "body: missing field(s) t",
        ),
        (
            MessageKind.OBSERVE,
            {"t": 0.0, "observations": None, "announcements": []},
            "body.observations = None: must be a list",
        ),
        (
            MessageKind.OBSERVE,
            {"t": 0.0, "observations": ["r1"], "announcements": []},
            "body.observations[0] = 'r1': must be a fleet.plugins.Observation",
        ),
        (
            MessageKind.HELLO,
            {"robots": [], "scenario": "", "colour": 1},
            "unexpected field(s) ['colour']",
        ),
        (MessageKind.HEARTBEAT, {"alive": True}, "unexpected field(s) ['alive']"),
        (MessageKind.BYE, None, "BYE from 'a' at tick 1: body = None: must be a mapping"),
    ],
)
def test_encode_refuses_malformed_bodies_naming_the_field(kind, body, says):
    with pytest.raises(MessageError) as info:
        encode(kind, "a", 1, body)
    assert says in str(info.value)


def test_command_to_wire_checks_what_plugins_return():
    with pytest.raises(MessageError, match="must be a fleet.plugins.Command"):
        command_to_wire((0.0, 0.0))  # type: ignore[arg-type]
    with pytest.raises(MessageError, match="command.status = 'ok'"):
        command_to_wire(Command(0.0, 0.0, "ok"))  # type: ignore[arg-type]
    with pytest.raises(MessageError, match=r"command.plan\[1\] = \(1.0, 2.0\)"):
        command_to_wire(Command(0.0, 0.0, plan=((0.0, 1.0, 2.0), (1.0, 2.0))))  # type: ignore[arg-type]


def test_the_wire_format_is_version_5_as_documented():
    env = json.loads(encode(MessageKind.OBSERVE, "exchange", 7, BODIES[MessageKind.OBSERVE]))
    assert list(env) == ["version", "kind", "sender", "tick", "body"]
    assert env["version"] == SCHEMA_VERSION == 5
    assert (env["kind"], env["sender"], env["tick"]) == ("observe", "exchange", 7)
    assert list(env["body"]) == ["t", "observations", "announcements"]
    obs = env["body"]["observations"][0]
    assert list(obs) == [f.name for f in dataclasses.fields(Observation)]
    assert obs == {
        "robot": "r1",
        "tick": 7,
        "t": 1.75,
        "x": 3.5,
        "y": -2.25,
        "vx": 0.5,
        "vy": -0.125,
        "goal": [10.0, 4.0],
        "job": "job-3",
        "speed_cap": 0.3,
        "neighbours": [
            ["r2", 4.0, -2.0, 0.1, 0.0, 0.35, 3, [[1.75, 4.0, -2.0], [2.0, 4.025, -2.0]]]
            + [None, None, None],
            ["r3", 1.0, 1.0, 0.0, -0.2, 0.4, 0, [], None, None, None],
        ],
        "speed_caps": [[1.75, 21.0, 0.3], [21.0, 51.0, 0.5]],
        "print_end_s": 1242.5,
        "priority": -2,
        "blockers": ["r2", "r3"],
        "queued": 1,
    }
    assert env["body"]["announcements"] == [
        ["job-4", 3.0, -1.5, 120.0, 1.5, 900.0],
        ["job-5", 0.0, 2.0, 0.0, 1.75, None],
    ]
    assert json.loads(encode(MessageKind.ACT, "a", 7, BODIES[MessageKind.ACT]))["body"] == {
        "commands": {
            "r1": {
                "ax": 0.5,
                "ay": -0.25,
                "status": "fallback",
                "plan": [[2.0, 3.5, -2.0], [2.25, 3.6, -1.9]],
                "solve": ["no_solution", 0.25, 0.2625],
            },
            "r2": {"ax": 0.0, "ay": 0.0, "status": "blocked", "plan": [], "solve": None},
        },
        "bids": [["job-4", "r1", 42.5], ["job-5", "r2", 0.0]],
        "handbacks": [["r2", "job-1", "blocked"]],
    }


def test_frames_written_by_other_json_writers_are_read():
    # Spaces, \u escapes, integers for floats: any JSON spelling of the same message.
    obs = observation_to_wire(replace(OBS_FULL, robot="rö", t=2.0))
    obs["t"] = 2
    body = {"t": 1, "observations": [obs], "announcements": []}
    frame = json.dumps(envelope(kind="observe", sender="ä", body=body), indent=2).encode()
    msg = decode(frame)
    assert msg.sender == "ä"
    assert msg.body == {
        "t": 1.0,
        "observations": [replace(OBS_FULL, robot="rö", t=2.0)],
        "announcements": [],
    }
    assert type(msg.body["t"]) is float and type(msg.body["observations"][0].t) is float


def test_decode_takes_only_bytes():
    with pytest.raises(MessageError, match="bus message = '{}': must be bytes"):
        decode("{}")  # type: ignore[arg-type]


def test_commands_with_numpy_numbers_go_out_as_plain_floats():
    cmd = Command(
        np.float64(0.5),
        np.float32(0.25),
        ControlStatus.OK,
        ((np.float64(1.0), 2, np.float32(3.5)),),
        SolveReport(SolverOutcome.OPTIMAL, np.float64(0.125), 1),
    )
    wire = command_to_wire(cmd)  # type: ignore[arg-type]
    assert all(type(v) is float for v in (wire["ax"], wire["ay"], *wire["plan"][0]))
    assert command_from_wire(json.loads(json.dumps(wire))) == Command(
        0.5,
        0.25,
        ControlStatus.OK,
        ((1.0, 2.0, 3.5),),
        SolveReport(SolverOutcome.OPTIMAL, 0.125, 1.0),
    )


def test_encode_checks_even_what_goes_out_as_it_is():
    # A neighbour's plan and wire dicts are not copied, but the body is checked as a whole:
    # msgspec alone would write NaN as null.
    plan = ((0.0, 1.0, 2.0), (0.5, math.nan, 2.0))
    neighbour = Neighbour("r2", 0.0, 0.0, 0.0, 0.0, 0.4, 0, plan)
    body = {
        "t": 0.0,
        "observations": [replace(OBS_IDLE, neighbours=(neighbour,))],
        "announcements": [],
    }
    with pytest.raises(MessageError) as info:
        encode(MessageKind.OBSERVE, "exchange", 1, body)
    assert str(info.value) == (
        "cannot encode OBSERVE from 'exchange' at tick 1: body.observations[0].neighbours[0]"
        ".plan[1] = nan: must be a finite number"
    )
    body = {"t": math.inf, "observations": [observation_to_wire(OBS_IDLE)], "announcements": []}
    with pytest.raises(MessageError, match=r"body.t = inf: must be a finite number"):
        encode(MessageKind.OBSERVE, "exchange", 1, body)
    with pytest.raises(MessageError, match="body.robots = '': robot ids must be non-empty strings"):
        encode(MessageKind.HELLO, "a", 0, {"robots": [""], "scenario": ""})
    with pytest.raises(MessageError, match="body.reason: surrogates not allowed"):
        encode(MessageKind.BYE, "a", 1, {"reason": "\ud800"})


# --- schema: anything else is a MessageError -----------------------------------------------------


def decodes_or_says_why(frame: bytes) -> None:
    """`decode` returns a message or raises a MessageError whose text stays short."""
    try:
        msg = decode(frame)
    except MessageError as exc:
        assert len(str(exc)) < 1000, str(exc)
    else:
        assert isinstance(msg.kind, MessageKind) and msg.version == SCHEMA_VERSION


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_decode_or_raise_message_error(frame):
    decodes_or_says_why(frame)


VALID_FRAMES = [encode(kind, "agent-1", 7, body) for kind, body in BODIES.items()]
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)


def containers(node: dict | list):
    """`node` and every object and array in it."""
    yield node
    for child in node.values() if isinstance(node, dict) else node:
        if isinstance(child, dict | list):
            yield from containers(child)


@settings(max_examples=500, deadline=None)
@given(frame=st.sampled_from(VALID_FRAMES), data=st.data())
def test_mutated_messages_decode_or_raise_message_error(frame, data):
    obj = json.loads(frame)
    node = data.draw(st.sampled_from(list(containers(obj))))
    keys = list(node) if isinstance(node, dict) else list(range(len(node)))
    action = data.draw(st.sampled_from(["replace", "drop", "add"] if keys else ["add"]))
    if action == "add":
        value = data.draw(json_values)
        if isinstance(node, dict):
            node[data.draw(st.text(max_size=6))] = value
        else:
            node.insert(data.draw(st.integers(0, len(node))), value)
    else:
        key = data.draw(st.sampled_from(keys))
        if action == "drop":
            del node[key]
        else:
            node[key] = data.draw(json_values)
    decodes_or_says_why(json.dumps(obj).encode())  # NaN and Infinity included


@settings(max_examples=300, deadline=None)
@given(frame=st.sampled_from(VALID_FRAMES), data=st.data())
def test_cut_or_altered_frames_decode_or_raise_message_error(frame, data):
    at = data.draw(st.integers(0, len(frame) - 1))
    if data.draw(st.booleans()):
        frame = frame[:at]
    else:
        frame = frame[:at] + bytes([data.draw(st.integers(0, 255))]) + frame[at + 1 :]
    decodes_or_says_why(frame)


def bye_with(reason: bytes = b'"x"', tick: bytes = b"3") -> bytes:
    return b'{"version":5,"kind":"bye","sender":"a","tick":%s,"body":{"reason":%s}}' % (
        tick,
        reason,
    )


@pytest.mark.parametrize(
    ("frame", "says"),
    [
        (b"[" * 100_000 + b"]" * 100_000, "nests too deeply to be read"),
        (bye_with(reason=b"[" * 100_000 + b"]" * 100_000), "at `$.body.reason`"),
        (bye_with(tick=b"1" + b"0" * 5000), "cannot be read (Integer value out of range"),
        (bye_with(tick=b"1" + b"0" * 400 + b".0"), "BYE message from 'a': tick = inf: must be"),
        (raw(envelope(sender="s" * 5_000_000, tick=-1)), "holds 5,000,000 characters: at most"),
        (b"\xff" * 5_000_000, "is not UTF-8"),
        (b" " * 5_000_000, "is not valid JSON"),
        (raw(envelope(body={"reason": ["x"] * 1_000_000})), "body.reason = ['x', 'x'"),
    ],
    ids=[
        "deep",
        "deep field",
        "long integer",
        "long float",
        "long sender",
        "not UTF-8",
        "blank",
        "long array",
    ],
)
def test_huge_or_deeply_nested_frames_are_rejected_briefly(frame, says):
    with pytest.raises(MessageError) as info:
        decode(frame, max_bytes=len(frame))  # past the size check: the parser's own errors
    assert says in str(info.value) and len(str(info.value)) < 400


def test_huge_valid_messages_are_read():
    body = {
        "t": 1.75,
        "observations": [replace(OBS_FULL, robot=f"r{i}") for i in range(2000)],
        "announcements": [],
    }
    frame = encode(MessageKind.OBSERVE, "exchange", 7, body)
    assert decode(frame).body == body
    reason = "é" * MAX_TEXT_CHARS  # 2 bytes each in UTF-8: the limit counts characters
    assert decode(encode(MessageKind.BYE, "a", 1, {"reason": reason})).body == {"reason": reason}


# --- addresses -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("address", "bind"),
    [
        ("inproc://fleet-1", False),
        ("ipc:///tmp/fleet.sock", False),
        ("tcp://127.0.0.1:5555", False),
        ("tcp://[::1]:5555", False),
        ("tcp://robot-host.local:5555", False),
        ("tcp://*:5555", True),
        ("tcp://127.0.0.1:*", True),
    ],
)
def test_good_addresses_parse(address, bind):
    assert str(parse_address(address, bind=bind)) == address


@pytest.mark.parametrize(
    ("address", "says"),
    [
        ("localhost:5555", "must look like '<transport>://<target>'"),
        ("inproc://", "must look like"),
        ("udp://127.0.0.1:5555", "transport 'udp' is not supported"),
        ("tcp://127.0.0.1", "tcp needs '<host>:<port>'"),
        ("tcp://127.0.0.1:70000", "tcp port '70000' must be an integer in 1..65535"),
        ("tcp://127.0.0.1:http", "tcp port 'http'"),
        ("tcp://bad host:1", "must not contain whitespace"),
        ("tcp://127.0.0.1:*", "only allowed when binding"),
        ("tcp://*:5555", "only allowed when binding"),
        ("ipc://" + "/x" * 60, "at most 107"),
        ("ipc://*", "explicit socket path"),
    ],
)
def test_bad_addresses_are_refused_saying_what_is_allowed(address, says):
    with pytest.raises(AddressError) as info:
        parse_address(address)
    assert says in str(info.value)
    assert repr(address) in str(info.value) and "inproc://<name>" in str(info.value)
    assert isinstance(info.value, ValueError) and isinstance(info.value, MessageError)


def test_address_errors_and_the_docs_spell_the_transports_alike():
    with pytest.raises(AddressError) as info:
        parse_address("udp://127.0.0.1:5555")
    allowed = "'inproc://<name>', 'ipc://<path>' or 'tcp://<host>:<port>'"
    assert allowed in str(info.value)
    for spelling in ("``inproc://<name>``", "``ipc://<path>``", "``tcp://<host>:<port>``"):
        assert spelling in transport.__doc__


def test_over_inproc_an_agent_may_connect_before_the_exchange_binds():
    address = new_inproc_address()
    host = AgentHost(address, {"r1": Echo()}, name="early")
    with Exchange(address) as ex:
        ex.add_local(host)
        ex.wait_for_agents(["r1"])
        assert ex.round(1, 0.25, [observation("r1", 1)]) == {"r1": expected(observation("r1", 1))}


@pytest.mark.parametrize("name", ["", "x" * 256, "\u00e9" * 128, "\0agent"])
def test_an_agent_name_must_fit_a_zeromq_routing_id(name):
    with Exchange() as ex, pytest.raises(ValueError, match="at most 255 UTF-8 bytes"):
        AgentHost(ex.address, {}, name=name)


def test_binding_an_address_in_use_is_a_clear_error():
    with Exchange() as first, pytest.raises(AddressError, match="cannot bind the bus to"):
        Exchange(first.address)


# --- exchange and agents in one process ----------------------------------------------------------


def local_fleet(exchange: Exchange, split: dict[str, list[str]]) -> dict[str, AgentHost]:
    hosts = {}
    for name, robots in split.items():
        host = AgentHost(exchange.address, {r: Echo() for r in robots}, name=name)
        exchange.add_local(host)
        hosts[name] = host
    return hosts


def test_two_local_hosts_over_inproc_answer_100_rounds_in_robot_order():
    robots = [f"r{i}" for i in range(7)]
    with Exchange() as ex:
        assert ex.address.startswith("inproc://fleet-")
        local_fleet(ex, {"a": robots[::2], "b": robots[1::2]})
        ex.wait_for_agents(robots)
        assert ex.agents == {"a": frozenset(robots[::2]), "b": frozenset(robots[1::2])}
        run_rounds(ex, robots, 100)
        stats = dict(ex.stats)
    assert stats["rounds"] == 100
    for counter in (
        "messages_rejected",
        "stale",
        "commands_missing",
        "timeouts",
        "robots_rejected",
    ):
        assert stats[counter] == 0, counter


def test_a_robot_nobody_hosts_is_simply_absent():
    with Exchange() as ex:
        local_fleet(ex, {"a": ["r1"]})
        ex.wait_for_agents(["r1"])
        result = ex.round(1, 0.25, [observation("r1", 1), observation("r2", 1)])
        assert list(result) == ["r1"]
        assert ex.stats["commands_missing"] == 1 and ex.stats["timeouts"] == 0


def test_a_robot_claimed_twice_stays_with_its_first_host():
    with Exchange() as ex:
        first, second = local_fleet(ex, {"first": ["r1"], "second": ["r1", "r2"]}).values()
        ex.wait_for_agents(["r1", "r2"])
        result = ex.round(1, 0.25, [observation("r1", 1), observation("r2", 1)])
        assert result == {
            "r1": expected(observation("r1", 1)),
            "r2": expected(observation("r2", 1)),
        }
        assert ex.agents == {"first": {"r1"}, "second": {"r2"}}
        assert second.accepted == {"r2"}
        assert second.rejected == {"r1": "already hosted by agent 'first'"}
        assert first.rejected == {}
        assert ex.stats["robots_rejected"] == 1


def test_a_controller_that_raises_gets_its_robot_braking_with_error_status(caplog):
    spec = RobotSpec(a_max=0.5, period=0.25)
    controllers = {
        "hot": with_spec(Exploding(), spec),
        "nospec": Exploding(),
        "nan": with_spec(ReturnsNaN(), spec),
        "ok": Echo(),
    }
    with Exchange() as ex:
        ex.add_local(AgentHost(ex.address, controllers, name="h"))
        ex.wait_for_agents(controllers)
        caplog.set_level(logging.WARNING, logger="fleet.bus")
        for tick in (1, 2):
            obs = [
                Observation("hot", tick, 0.0, 0.0, 0.0, 0.05, -1.0),
                Observation("nospec", tick, 0.0, 0.0, 0.0, 0.05, -1.0),
                Observation("nan", tick, 0.0, 0.0, 0.0, -1.0, 0.0),
                observation("ok", tick),
            ]
            result = ex.round(tick, 0.0, obs)
            # Along the line of travel: the faster axis (vy/dt = -4) is held to a_max = 0.5,
            # so both axes are scaled by 0.5 / 4 = 0.125.
            assert result["hot"] == Command(-0.025, 0.5, ControlStatus.ERROR)
            assert result["nospec"] == Command(0.0, 0.0, ControlStatus.ERROR)
            assert result["nan"] == Command(0.5, 0.0, ControlStatus.ERROR)
            assert result["ok"] == expected(observation("ok", tick))
    lines = [r.getMessage() for r in caplog.records]
    assert any("robot hot" in m and "RuntimeError: boom at tick 1" in m for m in lines)
    assert any("robot nan" in m and "command.ax = nan" in m for m in lines)
    # The traceback is logged once per robot, not every tick.
    assert sum(1 for r in caplog.records if r.exc_info and "robot hot" in r.getMessage()) == 1


def test_braking_command_never_exceeds_a_max():
    brake = with_spec(Exploding(), RobotSpec(a_max=0.5, period=0.25))
    for v in (-10.0, -0.1, 0.0, 0.1, 10.0):
        cmd = braking_command(brake, Observation("r", 0, 0.0, 0.0, 0.0, v, v))
        assert abs(cmd.ax) <= 0.5 and cmd.ax * v <= 0 and cmd.status is ControlStatus.ERROR


speeds = st.floats(-5.0, 5.0, allow_nan=False)


@settings(max_examples=80, deadline=None)
@given(vx=speeds, vy=speeds)
def test_braking_command_brakes_along_the_line_of_travel(vx, vy):
    spec = RobotSpec(a_max=0.5, period=0.25)
    cmd = braking_command(with_spec(Exploding(), spec), Observation("r", 0, 0.0, 0.0, 0.0, vx, vy))
    # The same braking as the engine's, which keeps the robot on its line.
    assert (cmd.ax, cmd.ay) == tuple(a + 0.0 for a in brake_input(vx, vy, 0.25, 0.5))
    assert max(abs(cmd.ax), abs(cmd.ay)) <= 0.5 + 1e-12
    # Acceleration against the velocity, parallel to it: the next velocity keeps its heading.
    assert cmd.ax * vx + cmd.ay * vy <= 0.0
    assert math.isclose(cmd.ax * vy, cmd.ay * vx, rel_tol=1e-9, abs_tol=1e-12)


def test_braking_command_does_not_bend_the_path():
    # The reviewer's case: at (1.0, 0.2) m/s per-axis braking stopped vy first and turned the
    # robot onto the x axis; the next velocity must point the same way as this one.
    spec = RobotSpec(1.0, 0.5, 0.4, 0.25)
    cmd = braking_command(
        with_spec(Exploding(), spec), Observation("r", 0, 0.0, 0.0, 0.0, 1.0, 0.2)
    )
    vx, vy = 1.0 + 0.25 * cmd.ax, 0.2 + 0.25 * cmd.ay
    assert math.isclose(vy / vx, 0.2) and vx < 1.0


def test_an_agent_that_says_bye_loses_its_robots_without_stalling_rounds():
    with Exchange(timeout_s=30) as ex:
        hosts = local_fleet(ex, {"a": ["r1"], "b": ["r2"]})
        ex.wait_for_agents(["r1", "r2"])
        hosts["b"].close()
        result = ex.round(1, 0.25, [observation("r1", 1), observation("r2", 1)])
        assert list(result) == ["r1"]
        assert ex.agents == {"a": {"r1"}}
        assert ex.stats["commands_missing"] == 1 and ex.stats["timeouts"] == 0


def test_rounds_must_advance_and_observe_each_robot_once():
    with Exchange() as ex:
        local_fleet(ex, {"a": ["r1"]})
        ex.wait_for_agents(["r1"])
        ex.round(5, 1.25, [observation("r1", 5)])
        with pytest.raises(ValueError, match="round tick = 5: must be an integer > 5"):
            ex.round(5, 1.25, [observation("r1", 5)])
        with pytest.raises(ValueError, match="two observations of robot 'r1'"):
            ex.round(6, 1.5, [observation("r1", 6), observation("r1", 6)])


def test_wait_for_agents_times_out_naming_the_robots_without_host():
    with Exchange() as ex:
        local_fleet(ex, {"a": ["r1"]})
        with pytest.raises(MessageError, match=r"no agent hosts robots \['r7'\].*\['a'\]"):
            ex.wait_for_agents(["r1", "r7"], timeout_s=0.05)


def test_local_hosts_must_share_the_exchange_context_and_address():
    other = zmq.Context()
    try:
        with Exchange() as ex:
            with pytest.raises(ValueError, match="another zmq.Context"):
                ex.add_local(AgentHost(ex.address, {}, context=other))
            with Exchange() as ex2, pytest.raises(ValueError, match="not to this exchange"):
                ex.add_local(AgentHost(ex2.address, {}))
    finally:
        other.destroy(linger=0)


# --- misbehaving peers ---------------------------------------------------------------------------


def test_injected_garbage_is_dropped_and_counted_while_rounds_go_on():
    robots = ["r0", "r1", "r2", "r3"]
    ctx = zmq.Context.instance()
    with Exchange() as ex:
        local_fleet(ex, {"a": robots[:2], "b": robots[2:]})
        ex.wait_for_agents(robots)
        intruder = ctx.socket(zmq.DEALER)
        stranger = ctx.socket(zmq.DEALER)
        intruder.connect(ex.address)
        stranger.connect(ex.address)
        try:
            run_rounds(ex, robots, 3)
            # An agent claiming a robot already hosted and one not in the run.
            intruder.send(hello("intruder", ["r0", "ghost"]))
            intruder.send(b"\x00garbage")
            intruder.send_multipart([b"two", b"frames"])
            intruder.send(raw(envelope(version=99)))
            cmds = {"r0": Command(9.0, 9.0)}
            # Its HELLO accepted nothing, so it is no agent: its ACTs are a stranger's.
            intruder.send(act("intruder", 2, cmds))
            intruder.send(act("intruder", 4, cmds))
            intruder.send(encode(MessageKind.OBSERVE, "intruder", 4, BODIES[MessageKind.OBSERVE]))
            intruder.send(act("impostor", 4, cmds))
            stranger.send(act("stranger", 4, cmds))  # never said HELLO
            result = ex.round(4, 1.0, [observation(r, 4) for r in robots])
            assert result == {r: expected(observation(r, 4)) for r in robots}
            welcome = decode(intruder.recv(), expect=(MessageKind.WELCOME,))
            agents = ex.agents
        finally:
            intruder.close(linger=0)
            stranger.close(linger=0)
        stats = dict(ex.stats)
    assert welcome.body["accepted"] == []
    assert welcome.body["rejected"] == {
        "r0": "already hosted by agent 'a'",
        "ghost": "unknown robot: not part of this run",
    }
    assert sorted(agents) == ["a", "b"]
    assert stats["robots_rejected"] == 2
    assert stats["stale"] == 0
    # garbage, two frames, version 99, three ACTs and an OBSERVE from no agent, a stranger's
    assert stats["messages_rejected"] == 8
    assert stats["commands_missing"] == 0 and stats["timeouts"] == 0
    assert stats["peers_cut_off"] == 0


def test_commands_for_robots_not_asked_are_rejected_and_silent_robots_missing():
    ctx = zmq.Context.instance()
    with Exchange(timeout_s=30) as ex:
        ready = threading.Event()

        def sloppy_agent() -> None:
            sock = ctx.socket(zmq.DEALER)
            sock.connect(ex.address)
            sock.send(hello("sloppy", ["s1", "s2"]))
            decode(sock.recv(), expect=(MessageKind.WELCOME,))
            ready.set()
            msg = decode(sock.recv(), expect=(MessageKind.OBSERVE,))
            # Answers s1, forgets s2, and invents a robot.
            cmds = {"s1": Command(1.0, 1.0), "zz": Command(2.0, 2.0)}
            sock.send(act("sloppy", msg.tick, cmds))
            decode(sock.recv(), expect=(MessageKind.BYE,))
            sock.close(linger=0)

        worker = threading.Thread(target=sloppy_agent)
        worker.start()
        ex.wait_for_agents(["s1", "s2"])
        result = ex.round(1, 0.25, [observation("s1", 1), observation("s2", 1)])
        assert result == {"s1": Command(1.0, 1.0)}
        assert ex.stats["commands_rejected"] == 1
        assert ex.stats["commands_missing"] == 1 and ex.stats["timeouts"] == 0
    worker.join(timeout=30)
    assert ready.is_set() and not worker.is_alive()


def test_an_agent_that_does_not_answer_in_time_costs_only_its_robots():
    ctx = zmq.Context.instance()
    stop = threading.Event()
    with Exchange(timeout_s=0.2) as ex:
        local_fleet(ex, {"a": ["r1"]})

        def late_agent() -> None:
            # Alive (it keeps heartbeating) but it never answers in time: timed out, not lost.
            sock = ctx.socket(zmq.DEALER)
            sock.connect(ex.address)
            sock.send(hello("late", ["r2"]))
            while not stop.wait(0.02):
                sock.send(heartbeat("late"))
            sock.send(act("late", 1, {"r2": Command(0, 0)}))
            sock.close()

        worker = threading.Thread(target=late_agent, daemon=True)
        worker.start()
        try:
            ex.wait_for_agents(["r1", "r2"])
            result = ex.round(1, 0.25, [observation("r1", 1), observation("r2", 1)])
            assert list(result) == ["r1"]
            assert ex.stats["timeouts"] == 1 and ex.stats["commands_missing"] == 1
            assert ex.stats["agents_lost"] == 0 and ex.agents["late"] == {"r2"}
            assert ex.stats["heartbeats"] > 0
        finally:
            stop.set()
            worker.join(timeout=30)
        # Its late answer arrives during the next round and is dropped as stale.
        result = ex.round(2, 0.5, [observation("r1", 2)])
        assert list(result) == ["r1"]
        assert ex.stats["stale"] == 1


def test_a_flood_of_stale_answers_does_not_postpone_the_round_timeout(caplog):
    caplog.set_level(logging.ERROR, logger="fleet.bus")  # thousands of warnings otherwise
    stop = threading.Event()
    with Exchange(timeout_s=0.2) as ex:
        stale = act("spammer", 0, {})
        worker, outlasted = flood(ex.address, hello("spammer", ["r1"]), stale, stop)
        try:
            ex.wait_for_agents(["r1"])
            # The spammer never answers tick 1; the round must give up while it keeps sending.
            assert ex.round(1, 0.25, [observation("r1", 1)]) == {}
        finally:
            stop.set()
            worker.join(timeout=30)
        assert not outlasted, "the round only returned once the flood stopped"
        assert ex.stats["timeouts"] == 1 and ex.stats["commands_missing"] == 1
        assert ex.stats["stale"] > 0


def test_a_flood_of_garbage_does_not_postpone_the_wait_for_agents_timeout(caplog):
    caplog.set_level(logging.ERROR, logger="fleet.bus")
    stop = threading.Event()
    with Exchange() as ex:
        worker, outlasted = flood(ex.address, b"garbage", b"garbage", stop)
        try:
            with pytest.raises(MessageError, match=r"no agent hosts robots \['r1'\]"):
                ex.wait_for_agents(["r1"], timeout_s=0.2)
        finally:
            stop.set()
            worker.join(timeout=30)
        assert not outlasted, "wait_for_agents only gave up once the flood stopped"
        assert ex.stats["messages_rejected"] > 0


def test_an_agent_whose_queue_is_full_keeps_its_robots():
    # A context whose sockets queue at most one message each way: an agent that does not read
    # fills its queue at once, and the next send fails with EAGAIN, not EHOSTUNREACH.
    ctx = zmq.Context()
    ctx.setsockopt(zmq.SNDHWM, 1)
    ctx.setsockopt(zmq.RCVHWM, 1)
    read_now, caught_up, stop = threading.Event(), threading.Event(), threading.Event()
    kinds: list[MessageKind] = []
    last: list = []

    def behind_agent() -> None:
        # Alive (it heartbeats every few ms, so it is never declared lost) but it reads
        # nothing until told to; then it catches up and waits for one more OBSERVE.
        sock = ctx.socket(zmq.DEALER)
        sock.setsockopt(zmq.ROUTING_ID, b"behind")
        sock.connect(ex.address)
        sock.send(hello("behind", ["r1"]))

        def beat_until(event: threading.Event) -> None:
            while not event.wait(0.005):
                with contextlib.suppress(zmq.Again):  # one still queued says it all
                    sock.send(heartbeat("behind"), zmq.NOBLOCK)

        try:
            beat_until(read_now)
            while sock.poll(100):
                kinds.append(decode(sock.recv()).kind)
            caught_up.set()
            while not stop.is_set() and not last:
                with contextlib.suppress(zmq.Again):
                    sock.send(heartbeat("behind"), zmq.NOBLOCK)
                if sock.poll(5):
                    last.append(decode(sock.recv()))
        finally:
            sock.close(linger=0)

    try:
        with Exchange(context=ctx, timeout_s=0.05) as ex:
            worker = threading.Thread(target=behind_agent, daemon=True)
            worker.start()
            try:
                ex.wait_for_agents(["r1"])
                tick = 0
                while ex.stats["send_failures"] == 0 and tick < 20:
                    tick += 1
                    assert ex.round(tick, 0.0, [observation("r1", tick)]) == {}
                assert ex.stats["send_failures"] == 1 and ex.stats["agents_lost"] == 0
                assert ex.agents == {"behind": {"r1"}}
                # Once it has caught up it is asked again.
                read_now.set()
                assert caught_up.wait(30)
                assert kinds[0] is MessageKind.WELCOME
                assert kinds[1:] == [MessageKind.OBSERVE] * (len(kinds) - 1)
                ex.round(tick + 1, 0.0, [observation("r1", tick + 1)])
            finally:
                stop.set()
                worker.join(timeout=30)
            assert (last[0].kind, last[0].tick) == (MessageKind.OBSERVE, tick + 1)
            assert ex.stats["send_failures"] == 1
    finally:
        ctx.destroy(linger=0)


def test_the_agent_drops_bad_messages_and_keeps_serving():
    ctx = zmq.Context.instance()
    engine = ctx.socket(zmq.ROUTER)
    address = "inproc://fake-engine"
    engine.bind(address)
    host = AgentHost(address, {"r1": Echo()}, name="h", heartbeat_s=None)
    try:
        peer, frame = engine.recv_multipart()
        assert decode(frame).body == {"robots": ["r1"], "scenario": ""}

        def deliver(frame: bytes) -> None:
            engine.send_multipart([peer, frame])
            assert host.pump(timeout_ms=5000)

        def observe(sender: str, tick: int, robots: list[str]) -> bytes:
            obs = [observation(r, tick) for r in robots]
            body = {"t": 0.0, "observations": obs, "announcements": []}
            return encode(MessageKind.OBSERVE, sender, tick, body)

        deliver(b"[1, 2")  # garbage
        deliver(observe("engine", 1, ["r1"]))  # before WELCOME
        welcome = {"accepted": ["r1"], "rejected": {}}
        deliver(encode(MessageKind.WELCOME, "engine", 0, welcome))
        deliver(act("engine", 1, {}))  # wrong kind for agents
        deliver(observe("someone-else", 2, ["r1"]))  # unknown sender
        deliver(raw(envelope(kind="observe", version=0)))  # wrong version
        assert host.stats["messages_rejected"] == 5
        deliver(observe("engine", 3, ["r1", "r9"]))  # r9 is not ours
        ident, answer = engine.recv_multipart()
        answered = decode(answer, expect=(MessageKind.ACT,))
        assert (ident, answered.tick, answered.body["commands"]) == (
            peer,
            3,
            {"r1": expected(observation("r1", 3))},
        )
        assert host.stats["unknown_robots"] == 1
        deliver(observe("engine", 2, ["r1"]))  # stale: tick 3 was answered
        assert host.stats["stale"] == 1
        assert not engine.poll(50)  # nothing was answered for the stale tick
        deliver(encode(MessageKind.BYE, "engine", 3, {"reason": "done"}))
        assert host.finished
        host.serve()  # returns at once: the exchange already said BYE
    finally:
        host.close()
        engine.close(linger=0)
    assert host.stats["messages_rejected"] == 5 and host.stats["observations"] == 1


def test_after_a_stall_the_agent_answers_only_the_newest_observe():
    computed: list[int] = []

    class Recording(Echo):
        def compute(self, obs: Observation) -> Command:
            computed.append(obs.tick)
            return super().compute(obs)

    engine = zmq.Context.instance().socket(zmq.ROUTER)
    address = new_inproc_address()
    engine.bind(address)
    host = AgentHost(address, {"r1": Recording()}, name="h", heartbeat_s=None)
    try:
        peer, _ = engine.recv_multipart()
        assert peer == b"h"  # the name is the routing id

        def observe(tick: int) -> bytes:
            body = {"t": 0.0, "observations": [observation("r1", tick)], "announcements": []}
            return encode(MessageKind.OBSERVE, "engine", tick, body)

        def answered() -> int:
            assert engine.poll(5000)
            return decode(engine.recv_multipart()[1], expect=(MessageKind.ACT,)).tick

        welcome = encode(MessageKind.WELCOME, "engine", 0, {"accepted": ["r1"], "rejected": {}})
        # Three ticks pile up while the host is stalled: the exchange gave up on 1 and 2.
        for frame in (welcome, observe(1), observe(2), observe(3)):
            engine.send_multipart([peer, frame])
        assert host.pump(5000) and host.accepted == {"r1"}
        assert host.pump(5000)
        assert answered() == 3
        assert not engine.poll(50)
        assert computed == [3] and host.stats["skipped"] == 2 and host.stats["stale"] == 0
        # What comes after the newest OBSERVE is still handled, in order.
        for frame in (observe(4), observe(5), encode(MessageKind.BYE, "engine", 5, {"reason": ""})):
            engine.send_multipart([peer, frame])
        assert host.pump(5000)
        assert answered() == 5 and host.finished
        assert computed == [3, 5] and host.stats["skipped"] == 3
        assert host.stats["messages_received"] == 7 and host.stats["observations"] == 2
    finally:
        host.close()
        engine.close(linger=0)


# --- across threads and processes ----------------------------------------------------------------


def test_a_host_in_another_thread_over_ipc(tmp_path):
    robots = ["r1", "r2", "r3"]
    hosts: list[AgentHost] = []
    with Exchange(f"ipc://{tmp_path}/bus.sock") as ex:

        def agent() -> None:
            # zmq sockets belong to one thread: the host is made where it is served.
            with AgentHost(ex.address, {r: Echo() for r in robots}, name="ipc-agent") as host:
                hosts.append(host)
                host.serve(idle_timeout_s=30)

        worker = threading.Thread(target=agent)
        worker.start()
        ex.wait_for_agents(robots)
        run_rounds(ex, robots, 100)
        assert ex.stats["commands_missing"] == 0 and ex.stats["messages_rejected"] == 0
    worker.join(timeout=30)
    assert not worker.is_alive()
    assert hosts[0].finished and hosts[0].stats["observations"] > 0


def test_a_host_in_another_process_over_tcp():
    robots = ["r1", "r2", "r3", "r4"]
    port = free_tcp_port()
    spawn = multiprocessing.get_context("spawn")
    with Exchange(f"tcp://127.0.0.1:{port}", timeout_s=60) as ex:
        assert ex.address == f"tcp://127.0.0.1:{port}"
        procs = [
            spawn.Process(target=serve_echo, args=(ex.address, robots[:2], "p1")),
            spawn.Process(target=serve_echo, args=(ex.address, robots[2:], "p2")),
        ]
        for p in procs:
            p.start()
        try:
            ex.wait_for_agents(robots)
            run_rounds(ex, robots, 100)
            assert ex.stats["commands_missing"] == 0 and ex.stats["messages_rejected"] == 0
        finally:
            ex.close()  # BYE ends the agents' serve()
            for p in procs:
                p.join(timeout=60)
                if p.is_alive():
                    p.kill()
    assert [p.exitcode for p in procs] == [0, 0]


def test_an_agent_whose_connection_drops_and_comes_back_keeps_its_robots():
    blip = threading.Event()
    done: list[AgentHost] = []
    with Exchange("tcp://127.0.0.1:*", timeout_s=30) as ex:

        def agent() -> None:
            with AgentHost(ex.address, {"r1": Echo()}, name="remote") as host:
                while not host.finished:
                    if blip.is_set():
                        blip.clear()
                        # What ZeroMQ does after a network blip: a new connection, same peer.
                        host.socket.disconnect(ex.address)
                        host.socket.connect(ex.address)
                    host.pump(20)
            done.append(host)

        worker = threading.Thread(target=agent, daemon=True)
        worker.start()
        ex.wait_for_agents(["r1"])
        assert ex.round(1, 0.25, [observation("r1", 1)]) == {"r1": expected(observation("r1", 1))}
        monitor = ex.socket.get_monitor_socket(zmq.EVENT_HANDSHAKE_SUCCEEDED)
        try:
            blip.set()
            # The new connection is through its handshake at the exchange's end.
            assert monitor.poll(30_000)
        finally:
            ex.socket.disable_monitor()
            monitor.close(linger=0)
        for tick in range(2, 6):
            obs = observation("r1", tick)
            assert ex.round(tick, tick * 0.25, [obs]) == {"r1": expected(obs)}
        assert ex.agents == {"remote": {"r1"}}
        assert ex.stats["send_failures"] == 0 and ex.stats["timeouts"] == 0
    # The exchange's BYE reached the agent over its new connection.
    worker.join(timeout=30)
    assert not worker.is_alive() and done[0].finished


def test_a_slow_local_host_does_not_use_up_the_remote_hosts_timeout(tmp_path):
    # Over ipc/tcp even a local host's OBSERVE takes a moment to arrive, so the exchange's first
    # look at the host may find nothing; `Late` makes that happen every round instead of by
    # chance. The local controller then takes twice timeout_s, which must not count: the
    # remote host, answering 50 ms after the local one, is in time.
    local_done = threading.Event()

    class Late(AgentHost):
        hold = True

        def pump(self, timeout_ms: int | None = 0) -> bool:
            if self.hold:
                self.hold = False
                return False
            return super().pump(timeout_ms)

    class SlowLocal(Echo):
        def compute(self, obs: Observation) -> Command:
            time.sleep(0.6)
            local_done.set()
            return super().compute(obs)

    class AfterLocal(Echo):
        host: AgentHost

        def compute(self, obs: Observation) -> Command:
            # It keeps heartbeating while it waits (as a host does between robots), so the
            # exchange knows it is alive, only busy.
            give_up = time.monotonic() + 30
            while not local_done.wait(0.02) and time.monotonic() < give_up:
                self.host.heartbeat()
            local_done.clear()
            time.sleep(0.05)
            return super().compute(obs)

    done: list[AgentHost] = []

    def remote() -> None:
        controller = AfterLocal()
        with AgentHost(ex.address, {"remote": controller}, name="remote") as host:
            controller.host = host
            host.serve(idle_timeout_s=30)
        done.append(host)

    with Exchange(f"ipc://{tmp_path}/bus.sock", timeout_s=0.3) as ex:
        local = Late(ex.address, {"local": SlowLocal()}, name="local")
        ex.add_local(local)
        worker = threading.Thread(target=remote, daemon=True)
        worker.start()
        ex.wait_for_agents(["local", "remote"])
        for tick in (1, 2):
            local.hold = True
            obs = [observation("local", tick), observation("remote", tick)]
            assert ex.round(tick, tick * 0.25, obs) == {o.robot: expected(o) for o in obs}
        assert ex.stats["timeouts"] == 0 and ex.stats["commands_missing"] == 0
    worker.join(timeout=30)
    assert not worker.is_alive() and done[0].finished


def ipv6_loopback_problem() -> str | None:
    """Why ``[::1]`` cannot be used here, or None if it can."""
    if not socket.has_ipv6:
        return "Python was built without IPv6"
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_STREAM) as s:
            s.bind(("::1", 0))
    except OSError as exc:
        return f"binding ::1 fails ({exc})"
    return None


def test_tcp_over_the_ipv6_loopback():
    problem = ipv6_loopback_problem()
    if problem is not None:
        pytest.skip(f"no IPv6 loopback on this machine: {problem}")
    robots = ["r1", "r2"]
    with Exchange("tcp://[::1]:*", timeout_s=30) as ex:
        assert ex.address.startswith("tcp://[::1]:")
        worker, done = serve_in_thread(ex.address, {r: Echo() for r in robots}, "v6")
        ex.wait_for_agents(robots)
        run_rounds(ex, robots, 20)
        assert ex.stats["commands_missing"] == 0
    worker.join(timeout=30)
    assert not worker.is_alive() and done[0].finished


def test_binding_tcp_port_star_reports_the_real_port():
    with Exchange("tcp://127.0.0.1:*") as ex:
        host, port = ex.address.removeprefix("tcp://").rsplit(":", 1)
        assert host == "127.0.0.1" and 1 <= int(port) <= 65535
