"""The bus under hostile input: size limits, per-peer accounting and cut-offs, over real
ZeroMQ sockets; and a small sample of each part of our harness, scripts/fuzz_bus.py."""

from __future__ import annotations

import logging
import random
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
import zmq

from fleet.bus import AgentHost, BusEvent, BusEventKind, Exchange, MessageKind, encode
from fleet.bus.ledger import CUT_OFF_AFTER, Junk, PeerLedger
from fleet.plugins import Command, Controller, ControlStatus, Observation
from tests.scripts import load_script
from tests.test_bus import Echo, act, expected, hello, local_fleet, observation, run_rounds

fuzz_bus = load_script("fuzz_bus")

WAIT_S = 10.0


def pump_until(ex: Exchange, done, timeout_s: float = WAIT_S) -> None:
    """Let the exchange take in what arrives until `done()` holds (or fail)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, f"not reached within {timeout_s} s: {ex.stats}"
        if not ex._router.take_in():
            ex._router.poll(0.02)


def ledger_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "fleet.bus"]


def test_a_peer_that_keeps_sending_junk_is_cut_off_logged_once_per_kind_and_rounds_go_on(
    caplog,
):
    caplog.set_level(logging.DEBUG, logger="fleet.bus")
    robots = ["r0", "r1"]
    ctx = zmq.Context.instance()
    with Exchange() as ex:
        local_fleet(ex, {"a": robots})
        ex.wait_for_agents(robots)
        junk = ctx.socket(zmq.DEALER)
        junk.connect(ex.address)
        try:
            kinds = [b"\x00garbage", act("nobody", 1, {"r0": Command(0.0, 0.0)})]
            for i in range(CUT_OFF_AFTER + 50):
                if i % 3 == 2:
                    junk.send_multipart([b"two", b"frames"])
                else:
                    junk.send(kinds[i % 3])
            # Its 150 and the local host's HELLO.
            pump_until(ex, lambda: ex.stats["messages_received"] >= CUT_OFF_AFTER + 51)
            run_rounds(ex, robots, 3)
        finally:
            junk.close(linger=0)
        stats = dict(ex.stats)
    assert stats["peers_cut_off"] == 1
    assert stats["messages_rejected"] == CUT_OFF_AFTER
    assert stats["messages_ignored"] == 50
    lines = [r for r in caplog.records if "dropped message from peer" in r.getMessage()]
    warnings = sorted(
        r.getMessage().split(" (")[1].split(")")[0] for r in lines if r.levelno == logging.WARNING
    )
    assert warnings == ["frames", "malformed", "stranger"]  # once per kind, then debug
    assert sum(r.levelno == logging.DEBUG for r in lines) == CUT_OFF_AFTER - 3
    cut = [m for m in ledger_lines(caplog) if "cut off" in m]
    assert len(cut) == 1 and f"after {CUT_OFF_AFTER} refused messages" in cut[0]


def test_a_known_agent_that_sends_junk_is_cut_off_and_lost():
    ctx = zmq.Context.instance()
    with Exchange(cut_off_after=5) as ex:
        local_fleet(ex, {"a": ["r0"]})
        rogue = ctx.socket(zmq.DEALER)
        rogue.setsockopt(zmq.ROUTING_ID, b"rogue")
        rogue.connect(ex.address)
        try:
            rogue.send(hello("rogue", ["r1"]))
            ex.wait_for_agents(["r0", "r1"])
            ex.take_events()
            for _ in range(5):
                rogue.send(b"not json")
            pump_until(ex, lambda: ex.stats["peers_cut_off"] == 1)
            assert ex.agents == {"a": {"r0"}}
            events = ex.take_events()
            # Its robots are unhosted and its later messages ignored, valid or not.
            rogue.send(act("rogue", 1, {"r1": Command(0.0, 0.0)}))
            result = ex.round(1, 0.25, [observation("r0", 1), observation("r1", 1)])
            pump_until(ex, lambda: ex.stats["messages_ignored"] >= 1)
        finally:
            rogue.close(linger=0)
    assert events == [
        BusEvent(BusEventKind.LOST, "rogue", ("r1",), "cut off after 5 refused messages")
    ]
    assert result == {"r0": expected(observation("r0", 1))}
    assert ex.stats["agents_lost"] == 1 and ex.stats["commands_missing"] == 1


def test_hellos_that_host_nothing_leave_no_member_behind_and_are_cut_off():
    ctx = zmq.Context.instance()
    with Exchange(cut_off_after=20) as ex:
        local_fleet(ex, {"a": ["r0"]})
        ex.wait_for_agents(["r0"])
        flood = ctx.socket(zmq.DEALER)
        flood.connect(ex.address)
        try:
            for i in range(30):  # a new name each time, for a robot the run does not have
                flood.send(hello(f"ghost-{i}", [f"nobody-{i}"]))
            pump_until(ex, lambda: ex.stats["messages_received"] >= 31)
        finally:
            flood.close(linger=0)
        assert ex.agents == {"a": {"r0"}}
        assert len(ex._roster.members) == len(ex._roster.by_name) == 1
        stats = dict(ex.stats)
    assert stats["peers_cut_off"] == 1 and stats["messages_ignored"] == 10
    assert stats["robots_rejected"] == 20


def test_the_ledger_remembers_a_bounded_number_of_peers():
    stats = {"peers_cut_off": 0, "messages_ignored": 0}
    ledger = PeerLedger(stats, logging.getLogger("test"), cut_off_after=2, max_peers=3)
    for peer in (b"p1", b"p2", b"p3", b"p4"):
        ledger.charge(peer, peer.decode(), Junk.MALFORMED, "bad")
    assert len(ledger) == 3 and ledger.refusals(b"p1") == {}  # the oldest went first
    assert ledger.refusals(b"p4") == {"malformed": 1}
    assert ledger.charge(b"p4", "p4", Junk.STRANGER, "no hello") is True
    assert ledger.ignores(b"p4") and not ledger.ignores(b"p3")
    assert stats == {"peers_cut_off": 1, "messages_ignored": 1}
    with pytest.raises(ValueError, match="cut_off_after = 0: must be an integer >= 1"):
        PeerLedger(stats, logging.getLogger("test"), cut_off_after=0)


def test_an_oversized_frame_over_tcp_drops_its_connection_unread():
    ctx = zmq.Context.instance()
    with Exchange("tcp://127.0.0.1:*", max_message_bytes=4096) as ex:
        big = ctx.socket(zmq.DEALER)
        big.setsockopt(zmq.LINGER, 0)
        big.connect(ex.address)
        small = ctx.socket(zmq.DEALER)
        small.setsockopt(zmq.LINGER, 0)
        small.connect(ex.address)
        try:
            big.send(hello("big", [f"r{i}" for i in range(1000)]))  # about 8 kB
            small.send(hello("small", ["r0"]))
            pump_until(ex, lambda: "small" in ex.agents)
            time.sleep(0.2)
            ex._router.take_in()
        finally:
            big.close()
            small.close()
        # ZeroMQ dropped the big frame with its connection: the exchange never saw it.
        assert ex.stats["messages_received"] == 1 and ex.agents == {"small": {"r0"}}


def test_an_oversized_frame_over_inproc_is_refused_by_decode_and_counted_as_such(caplog):
    ctx = zmq.Context.instance()
    with Exchange(max_message_bytes=4096) as ex:
        peer = ctx.socket(zmq.DEALER)
        peer.connect(ex.address)
        try:
            peer.send(hello("big", [f"r{i}" for i in range(1000)]))
            pump_until(ex, lambda: ex.stats["messages_rejected"] == 1)
        finally:
            peer.close(linger=0)
    assert any("(oversized): bus message of" in m for m in ledger_lines(caplog))


class Chatty(Controller):
    """Sends a plan of 2,000 samples: its ACT is far over a 4 kB limit."""

    def compute(self, obs: Observation) -> Command:
        plan = tuple((obs.t + 0.1 * k, 1.0, 2.0) for k in range(2000))
        return Command(0.0, 0.0, ControlStatus.OK, plan)


def test_messages_over_the_limit_are_not_sent_and_say_why(caplog):
    caplog.set_level(logging.ERROR, logger="fleet.bus")
    limit = 4096
    with Exchange(max_message_bytes=limit, timeout_s=0.5, lost_after_s=0.5) as ex:
        host = AgentHost(ex.address, {"r0": Chatty(), "r1": Echo()}, max_message_bytes=limit)
        ex.add_local(host)
        ex.wait_for_agents(["r0", "r1"])
        # The agent's ACT is too long: not sent, so the round has no command for either.
        result = ex.round(1, 0.25, [observation("r0", 1), observation("r1", 1)])
        assert result == {}
        # An OBSERVE too long for the limit is not sent either.
        crowd = [observation("r1", 2, blockers=tuple(f"r{i}" for i in range(2000)))]
        assert ex.round(2, 0.5, crowd) == {}
        assert ex.stats["send_failures"] == 1
    said = [r.getMessage() for r in caplog.records]
    assert any("ACT not sent" in m and f"over the bus's limit of {limit}" in m for m in said)
    assert any("not sent to agent" in m and f"limit of {limit}" in m for m in said)


def test_the_limit_is_a_scenario_setting_shared_by_engine_and_agents(tmp_path):
    from fleet.engine.agents import scenario_fingerprint
    from fleet.scenario import REPO_ROOT, load_scenario

    base = load_scenario(REPO_ROOT / "scenarios" / "fleet.toml")
    raised = load_scenario(
        REPO_ROOT / "scenarios" / "fleet.toml", {"bus.max_message_bytes": 8 * 1024 * 1024}
    )
    assert base.bus.max_message_bytes == 2 * 1024 * 1024
    assert raised.bus.max_message_bytes == 8 * 1024 * 1024
    # An agent set up with another limit is refused as set up for another scenario.
    assert scenario_fingerprint(base) != scenario_fingerprint(raised)


# --- samples of the harness ------------------------------------------------------------------


def test_fuzz_in_process_sample_finds_no_crash_and_covers_every_category():
    tally = fuzz_bus.fuzz_in_process(3000, seed=11)
    assert tally.crashes == []
    assert tally.count("accepted") > 100 and tally.count("rejected") > 1000
    seen = {c for c, counts in tally.outcomes.items() if sum(counts.values())}
    assert seen == {c for c, _ in fuzz_bus.Generator.CATEGORIES}
    # Valid messages are accepted, and nothing oversized is.
    assert tally.outcomes["valid"]["rejected"] == 0
    assert tally.outcomes["oversized"]["accepted"] == 0


def test_fuzz_judges_a_crash_as_one():
    # The oracle itself: what escapes decode's documented error is a crash.
    outcome, _ = fuzz_bus.judge(b"\xff")
    assert outcome == "rejected"
    original = fuzz_bus.decode
    try:
        fuzz_bus.decode = lambda raw: [][1]
        assert fuzz_bus.judge(b"{}")[0].startswith("crash: IndexError")
    finally:
        fuzz_bus.decode = original


def test_a_served_run_attacked_over_tcp_keeps_its_digest_and_jobs(tmp_path):
    # An hour for 2 robots lasts several times as long as the attack, even on a busy machine.
    common = [str(fuzz_bus.FLEET_TOML), "--robots", "2", "--duration", "3600", "--seed", "3"]
    # The undisturbed run goes alongside the attacked one (its own engine, agents and port):
    # the two wait on their sockets much of the time, and sharing the cores only makes the
    # attacked run last longer than its attack.
    with ThreadPoolExecutor(1) as pool:
        undisturbed = pool.submit(fuzz_bus.served_run, tmp_path, "undisturbed", common)
        loud, _ = fuzz_bus.served_run(tmp_path, "attacked", common, 600, seed=3, waves=1)
        quiet, _ = undisturbed.result()
    assert quiet.returncode == loud.returncode == 0, loud.stderr[-2000:]
    assert loud.summary["digest"] == quiet.summary["digest"]
    assert fuzz_bus.jobs_of(loud.summary) == fuzz_bus.jobs_of(quiet.summary)
    # The engine's own counters say the attack reached it while it ran.
    counters = fuzz_bus.bus_of(loud.summary)
    assert counters["messages_rejected"] + counters["messages_ignored"] > 300
    assert "Traceback" not in loud.stderr
    # `fleet serve` tells its operator who joined (at info level), and each refusal kind once
    # per connection: the attacker's malformed messages take one warning per connection.
    assert quiet.stderr.count(" joined, hosting ") == 2
    connections = fuzz_bus.parser().get_default("connections")
    assert 0 < loud.stderr.count(" (malformed): ") <= connections


def test_faults_sample_an_agent_killed_and_one_paused_leave_every_job_accounted(capsys):
    # An hour, so the run outlasts the kill, the pause and both replacements on a busy machine.
    args = fuzz_bus.parser().parse_args(
        ["faults", "--robots", "3", "--duration", "3600", "--after", "0.5", "--pause", "4"]
    )
    assert fuzz_bus.cmd_faults(args) == 0, capsys.readouterr().out


def test_curve_sample_refuses_an_agent_without_a_key_and_one_with_a_wrong_key(capsys):
    assert fuzz_bus.cmd_curve(fuzz_bus.parser().parse_args(["curve"])) == 0, capsys.readouterr().out


def test_every_decode_of_random_bytes_is_accepted_or_a_message_error():
    rng = random.Random(5)
    for _ in range(2000):
        frame = rng.randbytes(rng.randrange(60))
        assert fuzz_bus.judge(frame)[0] in ("accepted", "rejected")
    assert fuzz_bus.judge(encode(MessageKind.HEARTBEAT, "a", 1, {}))[0] == "accepted"
