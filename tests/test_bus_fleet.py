"""Bus protocol v4 for the fleet: contract-net fields, bids and handbacks, liveness, rejoin,
scenario fingerprints; over real ZeroMQ sockets (inproc, ipc and tcp)."""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
import zmq
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.bus import (
    SCHEMA_VERSION,
    AgentHost,
    BusEvent,
    BusEventKind,
    Exchange,
    MessageKind,
    decode,
    encode,
    observation_to_wire,
)
from fleet.bus.transport import connect_dealer
from fleet.errors import MessageError
from fleet.plugins import (
    Announcement,
    Bid,
    Command,
    Controller,
    ControlStatus,
    Handback,
    Neighbour,
    Observation,
)

# Generous: waits end as soon as the awaited thing happens; only a broken bus waits this long.
WAIT_S = 10.0


# --- helpers -------------------------------------------------------------------------------------


def observation(robot: str, tick: int, job: str | None = None, x: float = 1.0) -> Observation:
    return Observation(robot, tick, tick * 0.25, x, -2.0, 0.25, -0.5, job=job)


class Bidder(Controller):
    """Brakes; bids ``x + job.x`` (so a test can tell whose bid it is), declines job "no"."""

    def compute(self, obs: Observation) -> Command:
        return Command(0.0, 0.0, ControlStatus.OK)

    def bid(self, obs: Observation, job: Announcement) -> float | None:
        return None if job.job == "no" else obs.x + job.x


class Estimates(Bidder):
    """Bids whatever it was built with (or raises it)."""

    def __init__(self, estimate: object) -> None:
        self.estimate = estimate

    def bid(self, obs: Observation, job: Announcement) -> float | None:
        if isinstance(self.estimate, Exception):
            raise self.estimate
        return self.estimate  # type: ignore[return-value]


class BlockedOn(Bidder):
    """Answers BLOCKED while its robot holds one of `jobs`."""

    def __init__(self, *jobs: str) -> None:
        self.jobs = set(jobs)

    def compute(self, obs: Observation) -> Command:
        status = ControlStatus.BLOCKED if obs.job in self.jobs else ControlStatus.OK
        return Command(0.0, 0.0, status)


def raw(obj: object) -> bytes:
    return json.dumps(obj).encode()


def hello(name: str, robots: list[str], scenario: str = "") -> bytes:
    return encode(MessageKind.HELLO, name, 0, {"robots": robots, "scenario": scenario})


def act(name: str, tick: int, commands: dict, bids=(), handbacks=()) -> bytes:
    body = {"commands": commands, "bids": list(bids), "handbacks": list(handbacks)}
    return encode(MessageKind.ACT, name, tick, body)


def wait_until(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"gave up waiting for {what}"
        time.sleep(0.01)


def serve_in_thread(
    address: str, controllers: dict, name: str, **options
) -> tuple[threading.Thread, list[AgentHost]]:
    """A host serving `controllers` in a thread; the list receives it once serve returned."""
    done: list[AgentHost] = []

    def agent() -> None:
        # zmq sockets belong to one thread: the host is made where it is served.
        with AgentHost(address, controllers, name=name, **options) as host:
            host.serve(idle_timeout_s=30)
        done.append(host)

    worker = threading.Thread(target=agent, daemon=True)
    worker.start()
    return worker, done


@pytest.fixture
def dealer() -> Iterator[Callable[[str], zmq.Socket]]:
    """Raw DEALER sockets on the default context, closed after the test."""
    made: list[zmq.Socket] = []

    def make(address: str, routing_id: bytes | None = None) -> zmq.Socket:
        sock = zmq.Context.instance().socket(zmq.DEALER)
        if routing_id is not None:
            sock.setsockopt(zmq.ROUTING_ID, routing_id)
        sock.connect(address)
        made.append(sock)
        return sock

    yield make
    for sock in made:
        sock.close(linger=0)


# --- schema v4 and v5 -----------------------------------------------------------------------------

PLAN = ((2.0, 4.0, -2.0), (2.25, 4.05, -1.95), (2.5, 4.1, -1.9))
OBS = Observation(
    "r1",
    8,
    2.0,
    3.5,
    -2.25,
    0.5,
    -0.125,
    goal=(10.0, 4.0),
    job="job-3",
    neighbours=(
        Neighbour("r2", 4.0, -2.0, 0.2, 0.05, 0.3, 7, PLAN, 1.6, 2.0, 0.5),
        Neighbour("r3", 1.0, 1.0, 0.0, -0.2, 0.5, -1),
    ),
    priority=12,
    blockers=("r2",),
    queued=2,
)


def test_version_5_carries_the_fleet_fields_both_ways():
    # v4 added the fleet fields; v5 a neighbour's limits (r2's known, r3's not: null)
    assert SCHEMA_VERSION == 5
    offers = [Announcement("j1", 5.0, 6.0, 300.0, 1.5, None), Announcement("j2", 0, 0, 0, 0, 9)]
    body = {"t": 2.0, "observations": [OBS], "announcements": offers}
    assert decode(encode(MessageKind.OBSERVE, "exchange", 8, body)).body == body
    body = {
        "commands": {"r1": Command(0.0, 0.0, ControlStatus.BLOCKED)},
        "bids": [Bid("j1", "r1", 12.5), Bid("j2", "r1", 0.0)],
        "handbacks": [Handback("r1", "job-3", "blocked")],
    }
    assert decode(encode(MessageKind.ACT, "a", 8, body)).body == body
    body = {"robots": ["r1"], "scenario": "sha256:abc"}
    assert decode(encode(MessageKind.HELLO, "a", 0, body)).body == body
    beat = decode(encode(MessageKind.HEARTBEAT, "a", 8, {}))
    assert (beat.kind, beat.tick, beat.body) == (MessageKind.HEARTBEAT, 8, {})
    body = {"t": 2.0, "observations": [OBS], "announcements": offers}
    wire = json.loads(encode(MessageKind.OBSERVE, "exchange", 8, body))["body"]
    assert wire["announcements"] == [["j1", 5.0, 6.0, 300.0, 1.5, None], ["j2", 0, 0, 0, 0, 9]]
    assert wire["observations"][0]["neighbours"][0] == [
        "r2",
        4.0,
        -2.0,
        0.2,
        0.05,
        0.3,
        7,
        [list(p) for p in PLAN],
        1.6,
        2.0,
        0.5,
    ]
    assert wire["observations"][0]["neighbours"][1][8:] == [None, None, None]
    assert (wire["observations"][0]["priority"], wire["observations"][0]["queued"]) == (12, 2)


def test_integers_on_the_wire_become_floats_in_neighbour_plans():
    # Another implementation may write 2 for 2.0; the plan still holds floats.
    wire = observation_to_wire(OBS)
    wire["neighbours"][0][7] = [[2, 4, -2], [2.25, 4.05, -1.95]]
    env = {"version": SCHEMA_VERSION, "kind": "observe", "sender": "x", "tick": 8}
    env["body"] = {"t": 2.0, "observations": [wire], "announcements": []}
    plan = decode(raw(env)).body["observations"][0].neighbours[0].plan
    assert plan == ((2.0, 4.0, -2.0), (2.25, 4.05, -1.95))
    assert all(type(v) is float for sample in plan for v in sample)


names = st.text(min_size=1, max_size=8)
finite = st.floats(allow_nan=False, allow_infinity=False)
announcements = st.builds(
    Announcement, names, finite, finite, st.floats(0, 1e9), finite, st.none() | finite
)
bids = st.builds(Bid, names, names, st.floats(0, 1e9))
handbacks = st.builds(Handback, names, names, st.text(max_size=20))


@settings(max_examples=40, deadline=None)
@given(
    offers=st.lists(announcements, max_size=4),
    bids=st.lists(bids, max_size=4),
    handbacks=st.lists(handbacks, max_size=3),
)
def test_any_valid_announcements_bids_and_handbacks_survive_the_wire(offers, bids, handbacks):
    body = {"t": 0.0, "observations": [], "announcements": offers}
    assert decode(encode(MessageKind.OBSERVE, "exchange", 1, body)).body == body
    body = {"commands": {}, "bids": bids, "handbacks": handbacks}
    assert decode(encode(MessageKind.ACT, "a", 1, body)).body == body


def observe_with(**fields) -> bytes:
    obs = observation_to_wire(OBS)
    obs.update(fields)
    body = {"t": 1.0, "observations": [obs], "announcements": []}
    return raw(
        {"version": SCHEMA_VERSION, "kind": "observe", "sender": "x", "tick": 1, "body": body}
    )


def neighbour_with(index: int, value: object) -> bytes:
    n = json.loads(json.dumps(observation_to_wire(OBS)["neighbours"][0]))
    n[index] = value
    return observe_with(neighbours=[n])


def body_of(kind: str, **body) -> bytes:
    return raw({"version": SCHEMA_VERSION, "kind": kind, "sender": "x", "tick": 1, "body": body})


GOOD_ACT = {"commands": {}, "bids": [], "handbacks": []}

MALFORMED = [
    (observe_with(priority="high"), "observations[0].priority = 'high': must be an integer"),
    (observe_with(priority=True), "observations[0].priority = True"),
    (observe_with(queued=-1), "observations[0].queued = -1: must be an integer >= 0"),
    (observe_with(queued=1.0), "observations[0].queued = 1.0"),
    (observe_with(blockers="r2"), "observations[0].blockers = 'r2': must be an array"),
    (observe_with(blockers=["r2", ""]), "observations[0].blockers = '': robot ids must be"),
    (neighbour_with(5, 0.0), "neighbours[0].radius = 0.0: must be > 0"),
    (neighbour_with(5, -0.4), "neighbours[0].radius = -0.4: must be > 0"),
    (neighbour_with(5, "big"), "neighbours[0] = 'big': must be a finite number"),
    (neighbour_with(6, 1.5), "neighbours[0].priority = 1.5: must be an integer"),
    (neighbour_with(7, None), "neighbours[0].plan = None: must be an array of [t, x, y]"),
    (neighbour_with(7, [[2.0, 4.0]]), "neighbours[0].plan[0] = [2.0, 4.0]: must be a [t, x, y]"),
    (neighbour_with(7, [[2.0, 4.0, True]]), "neighbours[0].plan[0] = True: must be a finite"),
    (neighbour_with(7, [[2.0, 4.0, -1.0], "x"]), "neighbours[0].plan[1] = 'x'"),
    (neighbour_with(8, 0.0), "neighbours[0].v_max = 0.0: must be > 0 or null"),
    (neighbour_with(9, -2.0), "neighbours[0].a_max = -2.0: must be > 0 or null"),
    (neighbour_with(10, "slow"), "neighbours[0].period = 'slow': must be a finite number"),
    (
        observe_with(neighbours=[["r2", 4.0, -2.0, 0.2, 0.05]]),
        "must be [robot, x, y, vx, vy, radius, priority, plan, v_max, a_max, period]",
    ),
    (body_of("observe", t=0.0, observations=[]), "body: missing field(s) announcements"),
    (
        body_of("observe", t=0.0, observations=[], announcements={}),
        "body.announcements = {}: must be an array",
    ),
    (
        body_of("observe", t=0.0, observations=[], announcements=[["j", 1.0, 2.0, 3.0, 4.0]]),
        "announcements[0] = ['j', 1.0, 2.0, 3.0, 4.0]: must be [job, x, y, print_s",
    ),
    (
        body_of("observe", t=0.0, observations=[], announcements=[["j", 1, 2, -3, 4, None]]),
        "announcements[0][3] = -3.0: print_s must be >= 0",
    ),
    (
        body_of("observe", t=0.0, observations=[], announcements=[["", 1, 2, 3, 4, None]]),
        "announcements[0][0] = '': the job id must be a non-empty string",
    ),
    (
        body_of("observe", t=0.0, observations=[], announcements=[["j", 1, 2, 3, 4, "soon"]]),
        "announcements[0][5] = 'soon': must be a finite number",
    ),
    (body_of("act", commands={}, handbacks=[]), "body: missing field(s) bids"),
    (body_of("act", **{**GOOD_ACT, "bids": [["j", "r1", -1.0]]}), "bids[0][2] = -1.0: estimate"),
    (body_of("act", **{**GOOD_ACT, "bids": [["j", "r1", "1"]]}), "bids[0][2] = '1': must be"),
    (body_of("act", **{**GOOD_ACT, "bids": [["j", "", 1.0]]}), "bids[0][1] = '': the robot id"),
    (body_of("act", **{**GOOD_ACT, "bids": [["j", "r1"]]}), "bids[0] = ['j', 'r1']: must be"),
    (body_of("act", **{**GOOD_ACT, "bids": {}}), "body.bids = {}: must be an array"),
    (
        body_of("act", **{**GOOD_ACT, "handbacks": [["r1", "j", 5]]}),
        "handbacks[0][2] = 5: the reason must be a string",
    ),
    (
        body_of("act", **{**GOOD_ACT, "handbacks": [["r1", "", "x"]]}),
        "handbacks[0][1] = '': the job id must be a non-empty string",
    ),
    (body_of("hello", robots=["r1"]), "body: missing field(s) scenario"),
    (body_of("hello", robots=["r1"], scenario=None), "body.scenario = None: must be a string"),
    (body_of("heartbeat", busy=True), "HEARTBEAT message from 'x': body: unexpected field(s)"),
]


@pytest.mark.parametrize(("frame", "says"), MALFORMED, ids=[m[1][:40] for m in MALFORMED])
def test_malformed_fleet_fields_are_rejected_naming_the_field_and_value(frame, says):
    with pytest.raises(MessageError) as info:
        decode(frame)
    assert says in str(info.value)


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ({"bids": [Bid("j", "r1", math.nan)]}, "body.bids[0]: bid.estimate_s = nan: must be a"),
        ({"bids": [Bid("j", "r1", -2.0)]}, "bid.estimate_s = -2.0: must be >= 0"),
        ({"bids": [Bid("", "r1", 1.0)]}, "bid.job = '': must be a non-empty string"),
        ({"bids": [("j", "r1", 1.0)]}, "body.bids[0] = ('j', 'r1', 1.0): must be a fleet.plugins"),
        ({"handbacks": [Handback("r1", "j", None)]}, "handback.reason = None: must be a string"),
    ],
)
def test_encode_checks_bids_and_handbacks_from_plugins(body, says):
    with pytest.raises(MessageError) as info:
        encode(MessageKind.ACT, "a", 1, {**GOOD_ACT, **body})
    assert says in str(info.value)


def test_encode_checks_announcements():
    bad = Announcement("j", 0.0, 0.0, -1.0, 0.0)
    with pytest.raises(MessageError, match=r"announcements\[0\]: announcement.print_s = -1.0"):
        encode(MessageKind.OBSERVE, "x", 1, {"t": 0.0, "observations": [], "announcements": [bad]})


# --- bids and handbacks through the exchange ------------------------------------------------------


def test_agents_bid_for_their_observed_robots_and_bids_come_back_sorted():
    with Exchange() as ex:
        for name, robots in {"b": ["r3", "r4"], "a": ["r1", "r2"]}.items():
            ex.add_local(AgentHost(ex.address, {r: Bidder() for r in robots}, name=name))
        ex.wait_for_agents(["r1", "r2", "r3", "r4"])
        offers = [
            Announcement("j2", 20.0, 0, 0, 0),
            Announcement("no", 0, 0, 0, 0),
            Announcement("j1", 10.0, 0, 0, 0),
        ]
        # r2 is not due this tick: nobody bids for it.
        due = [
            observation("r4", 1, x=4.0),
            observation("r1", 1, x=1.0),
            observation("r3", 1, x=3.0),
        ]
        assert list(ex.round(1, 0.25, due, offers)) == ["r1", "r3", "r4"]
        assert ex.bids == [
            Bid("j1", "r1", 11.0),
            Bid("j1", "r3", 13.0),
            Bid("j1", "r4", 14.0),
            Bid("j2", "r1", 21.0),
            Bid("j2", "r3", 23.0),
            Bid("j2", "r4", 24.0),
        ]
        assert ex.stats["bids"] == 6 and ex.stats["bids_rejected"] == 0
        # Bids belong to their round.
        ex.round(2, 0.5, [observation("r1", 2)])
        assert ex.bids == [] and ex.handbacks == []


def test_bids_that_fail_or_are_not_estimates_are_dropped_and_logged_once_per_robot(caplog):
    caplog.set_level(logging.DEBUG, logger="fleet.bus")
    controllers = {
        "raises": Estimates(RuntimeError("no planner")),
        "nan": Estimates(math.nan),
        "negative": Estimates(-1.0),
        "text": Estimates("soon"),
        "bool": Estimates(True),
        "numpy": Estimates(np.float64(2.5)),
        "declines": Estimates(None),
    }
    with Exchange() as ex:
        host = AgentHost(ex.address, controllers, name="h")
        ex.add_local(host)
        ex.wait_for_agents(controllers)
        offers = [Announcement("j", 0, 0, 0, 0)]
        for tick in (1, 2):
            result = ex.round(tick, 0.0, [observation(r, tick) for r in controllers], offers)
            assert list(result) == sorted(controllers)  # a bad bid costs only the bid
            assert ex.bids == [Bid("j", "numpy", 2.5)]
            assert type(ex.bids[0].estimate_s) is float
    assert host.stats["bid_errors"] == 2
    assert host.stats["bids_dropped"] == 8  # nan, negative, text, bool; twice
    assert host.stats["bids_declined"] == 2 and host.stats["bids"] == 2
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    for robot in ("raises", "nan", "negative", "text", "bool"):
        assert sum(f"robot {robot}:" in r.getMessage() for r in warnings) == 1, robot
    (failure,) = [r for r in warnings if "robot raises:" in r.getMessage()]
    assert "RuntimeError: no planner" in failure.getMessage() and failure.exc_info
    assert any("bid 'soon' for job j" in r.getMessage() for r in warnings)


def test_a_blocked_robot_hands_its_job_back_once_per_job():
    with Exchange() as ex:
        host = AgentHost(ex.address, {"r1": BlockedOn("j1", "j3"), "r2": Bidder()}, name="h")
        ex.add_local(host)
        ex.wait_for_agents(["r1", "r2"])
        jobs = ["j1", "j1", "j1", "j2", "j3", "j1", None, "j1"]
        handed: list[list[Handback]] = []
        for tick, job in enumerate(jobs, 1):
            result = ex.round(
                tick, 0.0, [observation("r1", tick, job), observation("r2", tick, "j9")]
            )
            blocked = job in ("j1", "j3")
            assert result["r1"].status is (ControlStatus.BLOCKED if blocked else ControlStatus.OK)
            handed.append(ex.handbacks)
        # Once while it holds j1; again for j3; again for j1 once it had moved on in between.
        assert handed == [
            [Handback("r1", "j1", "blocked")],
            [],
            [],
            [],
            [Handback("r1", "j3", "blocked")],
            [Handback("r1", "j1", "blocked")],
            [],
            [Handback("r1", "j1", "blocked")],
        ]
        assert host.stats["handbacks"] == 4 and ex.stats["handbacks"] == 4


def test_bids_and_handbacks_of_a_remote_agent_are_checked_against_its_round(tmp_path, caplog):
    caplog.set_level(logging.WARNING, logger="fleet.bus")
    offers = [Announcement("j1", 1.0, 2.0, 30.0, 0.0, 60.0)]
    seen: list = []

    def rogue() -> None:
        sock = zmq.Context.instance().socket(zmq.DEALER)
        sock.connect(ex.address)
        try:
            sock.send(hello("rogue", ["s1", "s2"]))
            decode(sock.recv(), expect=(MessageKind.WELCOME,))
            msg = decode(sock.recv(), expect=(MessageKind.OBSERVE,))
            seen.append(msg.body)
            bids = [
                Bid("j1", "s1", 5.0),  # good
                Bid("j1", "s1", 4.0),  # the same job and robot again
                Bid("j9", "s1", 1.0),  # not announced
                Bid("j1", "s2", 1.0),  # s2 is its robot, but was not observed this round
                Bid("j1", "r1", 1.0),  # not its robot
            ]
            handbacks = [
                Handback("s2", "j7", "blocked"),  # good: s2 is its robot (observed or not)
                Handback("s1", "j8", "stuck"),  # good
                Handback("r1", "j5", "blocked"),  # not its robot
                Handback("s1", "j8", "again"),  # twice
            ]
            sock.send(act("rogue", msg.tick, {"s1": Command(0.0, 0.0)}, bids, handbacks))
            decode(sock.recv(), expect=(MessageKind.BYE,))
        finally:
            sock.close(linger=0)

    with Exchange(f"ipc://{tmp_path}/bus.sock", timeout_s=WAIT_S) as ex:
        ex.add_local(AgentHost(ex.address, {"r1": Bidder()}, name="local"))
        worker = threading.Thread(target=rogue, daemon=True)
        worker.start()
        ex.wait_for_agents(["r1", "s1", "s2"])
        result = ex.round(3, 0.75, [observation("s1", 3), observation("r1", 3)], offers)
        assert list(result) == ["r1", "s1"]
        assert ex.bids == [Bid("j1", "r1", 2.0), Bid("j1", "s1", 5.0)]
        assert ex.handbacks == [Handback("s1", "j8", "stuck"), Handback("s2", "j7", "blocked")]
        assert ex.stats["bids_rejected"] == 4 and ex.stats["handbacks_rejected"] == 2
    worker.join(timeout=WAIT_S)
    assert not worker.is_alive()
    assert seen[0]["announcements"] == offers and [o.robot for o in seen[0]["observations"]] == [
        "s1"
    ]
    assert any("dropped 4 bids of agent rogue" in r.getMessage() for r in caplog.records)


def test_round_checks_its_announcements():
    with Exchange() as ex:
        with pytest.raises(ValueError, match=r"jobs \['j'\] announced more than once"):
            ex.round(1, 0.0, [], [Announcement("j", 0, 0, 0, 0), Announcement("j", 1, 1, 0, 0)])
        with pytest.raises(MessageError, match=r"announcements\[0\]: announcement.x = nan"):
            ex.round(2, 0.0, [], [Announcement("j", math.nan, 0, 0, 0)])
        with pytest.raises(MessageError, match=r"announcements\[1\] = \{'job': 'k'\}: must be a"):
            ex.round(3, 0.0, [], [Announcement("j", 0, 0, 0, 0), {"job": "k"}])


# --- liveness, departure and rejoin ---------------------------------------------------------------


class Freezes(Controller):
    """Answers at once, except at tick `at`, where it hangs until `release` is set."""

    def __init__(self, at: int, release: threading.Event) -> None:
        self.at = at
        self.release = release

    def compute(self, obs: Observation) -> Command:
        if obs.tick == self.at:
            self.release.wait(WAIT_S)
        return Command(0.0, float(obs.tick))


def test_an_agent_that_stops_answering_is_lost_after_lost_after_s_and_a_restart_rejoins(tmp_path):
    release = threading.Event()
    # timeout_s is long: the round must end because the agent went silent, not by timing out.
    with Exchange(f"ipc://{tmp_path}/bus.sock", timeout_s=60, lost_after_s=0.3) as ex:
        controllers = {"r1": Freezes(2, release), "r2": Freezes(2, release)}
        worker, done = serve_in_thread(ex.address, controllers, "agent-7", heartbeat_s=0.05)
        ex.wait_for_agents(["r1", "r2"])
        assert ex.take_events() == [BusEvent(BusEventKind.JOINED, "agent-7", ("r1", "r2"))]
        both = lambda tick: [observation("r1", tick), observation("r2", tick)]  # noqa: E731
        assert list(ex.round(1, 0.25, both(1))) == ["r1", "r2"]

        assert ex.round(2, 0.5, both(2)) == {}  # it hangs in r1's controller
        assert ex.stats["timeouts"] == 0 and ex.stats["agents_lost"] == 1
        (event,) = ex.take_events()
        assert (event.kind, event.agent, event.robots) == ("lost", "agent-7", ("r1", "r2"))
        assert "silent for" in event.reason
        assert ex.agents == {}
        # Unhosted: absent at once, nothing to wait for.
        assert ex.round(3, 0.75, both(3)) == {}
        assert ex.stats["commands_missing"] == 4 and ex.stats["timeouts"] == 0

        # Unstuck, it hears that it was dropped and stops ...
        release.set()
        worker.join(timeout=WAIT_S)
        assert not worker.is_alive() and done[0].finished
        # ... and, restarted under the same name, is served again.
        controllers = {"r1": Freezes(0, release), "r2": Freezes(0, release)}
        worker, done = serve_in_thread(ex.address, controllers, "agent-7")
        ex.wait_for_agents(["r1", "r2"])
        assert ex.take_events() == [BusEvent(BusEventKind.JOINED, "agent-7", ("r1", "r2"))]
        assert ex.round(4, 1.0, both(4)) == {"r1": Command(0.0, 4.0), "r2": Command(0.0, 4.0)}
    worker.join(timeout=WAIT_S)
    assert not worker.is_alive() and done[0].finished


class Slow(Controller):
    def __init__(self, seconds: float) -> None:
        self.seconds = seconds

    def compute(self, obs: Observation) -> Command:
        time.sleep(self.seconds)
        return Command(0.0, float(obs.tick))


def test_heartbeats_keep_a_slow_agent_alive_while_it_computes_and_idles():
    robots = ["r1", "r2", "r3", "r4"]
    # Four robots at 0.08 s each: more than lost_after_s in all, but it heartbeats between
    # robots.
    with Exchange("tcp://127.0.0.1:*", timeout_s=60, lost_after_s=0.25) as ex:
        worker, done = serve_in_thread(
            ex.address, {r: Slow(0.08) for r in robots}, "slow", heartbeat_s=0.02
        )
        ex.wait_for_agents(robots)
        result = ex.round(1, 0.25, [observation(r, 1) for r in robots])
        assert list(result) == robots
        # The engine is busy elsewhere for longer than lost_after_s; the idle agent beats on.
        time.sleep(0.35)
        result = ex.round(2, 0.5, [observation(r, 2) for r in robots])
        assert list(result) == robots
        assert ex.stats["agents_lost"] == 0 and ex.stats["timeouts"] == 0
        assert ex.stats["heartbeats"] >= 3
    worker.join(timeout=WAIT_S)
    assert not worker.is_alive() and done[0].finished and done[0].stats["heartbeats"] >= 3


def test_an_agent_silent_since_before_the_round_is_lost_at_once_and_told_so(dealer):
    with Exchange(timeout_s=60, lost_after_s=0.05) as ex:
        mute = dealer(ex.address, b"mute")
        mute.send(hello("mute", ["r1"]))
        ex.wait_for_agents(["r1"])
        ex.take_events()
        time.sleep(0.1)  # no heartbeats meanwhile
        assert ex.round(1, 0.25, [observation("r1", 1)]) == {}
        assert ex.stats["agents_lost"] == 1 and ex.stats["timeouts"] == 0
        assert [e.kind for e in ex.take_events()] == [BusEventKind.LOST]
        kinds = []
        while mute.poll(1000):
            msg = decode(mute.recv())
            kinds.append(msg.kind)
            if msg.kind is MessageKind.BYE:
                assert "silent for" in msg.body["reason"]
                break
        assert kinds == [MessageKind.WELCOME, MessageKind.OBSERVE, MessageKind.BYE]


def test_an_agent_that_disconnects_becomes_lost(dealer):
    with Exchange(timeout_s=60, lost_after_s=0.05) as ex:
        gone = dealer(ex.address, b"gone")
        gone.send(hello("gone", ["r1"]))
        ex.wait_for_agents(["r1"])
        gone.close(linger=0)  # no BYE: the process died
        for tick in range(1, 4):
            ex.round(tick, 0.0, [observation("r1", tick)])
        lost = [e for e in ex.take_events() if e.kind == "lost"]
        assert [(e.agent, e.robots) for e in lost] == [("gone", ("r1",))]
        assert ex.agents == {} and ex.stats["agents_lost"] == 1


def test_an_agent_that_says_bye_is_reported_as_left():
    with Exchange() as ex:
        a = AgentHost(ex.address, {"r1": Bidder()}, name="a")
        b = AgentHost(ex.address, {"r2": Bidder(), "r3": Bidder()}, name="b")
        ex.add_local(a)
        ex.add_local(b)
        ex.wait_for_agents(["r1", "r2", "r3"])
        assert sorted(e.agent for e in ex.take_events() if e.kind == "joined") == ["a", "b"]
        assert a.heartbeat_s is None and b.heartbeat_s is None  # pumped: no heartbeats
        b.close()
        assert list(ex.round(1, 0.0, [observation(r, 1) for r in ("r1", "r2", "r3")])) == ["r1"]
        assert ex.take_events() == [BusEvent(BusEventKind.LEFT, "b", ("r2", "r3"), "agent closing")]
        assert ex.stats["heartbeats"] == 0


# --- scenario fingerprints ----------------------------------------------------------------------


def test_an_agent_set_up_for_another_scenario_is_refused_and_told_to_stop(caplog):
    caplog.set_level(logging.WARNING, logger="fleet.bus")
    with Exchange(scenario="sha256:aaaa") as ex:
        hosts = {
            "same": AgentHost(ex.address, {"r1": Bidder()}, name="same", scenario="sha256:aaaa"),
            "unchecked": AgentHost(ex.address, {"r2": Bidder()}, name="unchecked"),
            "other": AgentHost(ex.address, {"r3": Bidder()}, name="other", scenario="sha256:bbbb"),
        }
        for host in hosts.values():
            ex.add_local(host)
        with pytest.raises(MessageError, match=r"no agent hosts robots \['r3'\]"):
            ex.wait_for_agents(["r1", "r2", "r3"], timeout_s=0.2)
        why = "scenario differs (agent sha256:bbbb, run sha256:aaaa)"
        assert hosts["other"].rejected == {"r3": why} and hosts["other"].accepted == frozenset()
        assert hosts["other"].finished  # the exchange said BYE
        assert hosts["same"].accepted == {"r1"} and hosts["unchecked"].accepted == {"r2"}
        events = sorted(ex.take_events(), key=lambda e: e.agent)
        assert events == [
            BusEvent(BusEventKind.REFUSED, "other", ("r3",), why),
            BusEvent(BusEventKind.JOINED, "same", ("r1",)),
            BusEvent(BusEventKind.JOINED, "unchecked", ("r2",)),
        ]
        assert ex.agents == {"same": {"r1"}, "unchecked": {"r2"}}
        assert ex.stats["agents_refused"] == 1 and ex.stats["robots_rejected"] == 1
    said = f"from peer 'other' (refused): HELLO refused (1 robots claimed): r3: {why}"
    assert any(said in r.getMessage() for r in caplog.records)


def test_liveness_and_scenario_settings_are_checked():
    with pytest.raises(ValueError, match="lost_after_s = 0: must be a positive number"):
        Exchange(lost_after_s=0)
    with Exchange(timeout_s=0.5, lost_after_s=3.0) as ex:
        assert ex.lost_after_s == 0.5  # clamped: it could never fire after the timeout
        with pytest.raises(ValueError, match="heartbeat_s = 0: must be a positive number or None"):
            AgentHost(ex.address, {}, heartbeat_s=0)
        with pytest.raises(ValueError, match="scenario = 7: must be a string"):
            AgentHost(ex.address, {}, scenario=7)  # type: ignore[arg-type]


# --- CurveZMQ refusals as events ----------------------------------------------------------------


def test_a_client_the_curve_guard_refuses_is_reported_as_a_refused_event(tmp_path):
    security = pytest.importorskip("fleet.bus.security")
    for name in ("engine", "alice", "mallory"):
        security.make_keypair(tmp_path, name)
    (tmp_path / "allowed").mkdir()  # only alice may connect
    (tmp_path / "allowed" / "alice.key").write_bytes((tmp_path / "alice.key").read_bytes())
    ctx = zmq.Context()
    try:
        curve = security.ServerCurve(tmp_path / "engine.key_secret", tmp_path / "allowed")
        with Exchange("tcp://127.0.0.1:*", context=ctx, curve=curve) as ex:
            mallory = security.ClientCurve(tmp_path / "mallory.key_secret", tmp_path / "engine.key")
            intruder = connect_dealer(ctx, ex.address, b"mallory", curve=mallory)
            intruder.send(hello("mallory", ["r1"]))
            events: list[BusEvent] = []
            wait_until(lambda: events.extend(ex.take_events()) or events, "the refusal")
            (event,) = events
            assert (event.kind, event.agent, event.robots) == (
                BusEventKind.REFUSED,
                mallory.public_key,
                (),
            )
            assert event.reason.startswith("CURVE: ")
            assert ex.stats["messages_received"] == 0
            intruder.close(linger=0)
    finally:
        ctx.destroy(linger=0)
