"""Our own harness for the bus under hostile input and failure: counts, timings, digests.

Parts, each runnable alone (``all`` runs the four in turn):

``inprocess``
    --messages generated frames (default 100,000) through `fleet.bus.schema.decode`: valid
    messages of every kind, and valid ones spoilt (a field given a wrong value or type, a
    field dropped or added, bytes flipped, inserted or cut, the frame truncated, nested
    deeply, made oversized, an unknown kind or another schema version, duplicate keys or
    ids, lists past the schema's bounds, random bytes). Each decode must either return a
    message that encodes again to the same body, or raise `MessageError`; anything else is
    a crash. Prints counts per category and outcome, the median and slowest decode times,
    and the time to reject a HELLO with 20,000 ids and one duplicate.
``sockets``
    A real `fleet serve` run over tcp with two `fleet agent` processes, twice with the same
    seed: undisturbed, then while a separate process (``attack``) sends --attack hostile
    messages (default 10,000, in two waves of half) from several connections. The two runs'
    digests and job counts must match; prints what the engine counted (rejected, ignored,
    peers cut off), its log lines, and its memory (resident set before the attack and after
    each wave, and its peak in both runs).
``faults``
    A served run with three agents: one is killed (SIGKILL) and one paused (SIGSTOP for longer
    than the scenario's lost_after_s, then SIGCONT) mid-run, and replacements join for their
    robots. The run must finish with every job accounted for and both faults counted.
``curve``
    CurveZMQ: key files must be owner-only; an agent with no key and one with a key the
    engine does not know are refused (and the refusals logged), an authorised one completes
    the run.

Exits 1 if a check fails (a crash, a digest that differs, a fault not counted); timings are
reported, not judged, except that ``inprocess`` marks decodes over --budget-ms.

    python scripts/fuzz_bus.py inprocess [--messages 100000] [--seed 1]
    python scripts/fuzz_bus.py sockets [--attack 10000] [--robots 4] [--duration 3600]
    python scripts/fuzz_bus.py faults | curve | all
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import re
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fleet.bus.schema import (
    MAX_ID_CHARS,
    MAX_MESSAGE_BYTES,
    MAX_ROBOTS,
    MAX_TEXT_CHARS,
    SCHEMA_VERSION,
    MessageKind,
    decode,
    encode,
    observation_to_wire,
)
from fleet.errors import MessageError
from fleet.plugins import (
    Announcement,
    Bid,
    Command,
    ControlStatus,
    Handback,
    Neighbour,
    Observation,
    SolveReport,
    SolverOutcome,
)

REPO = Path(__file__).resolve().parents[1]
FLEET_TOML = REPO / "scenarios" / "fleet.toml"

# --- the generator ---------------------------------------------------------------------------


def _plan(rng: random.Random, n: int, t: float) -> tuple[tuple[float, float, float], ...]:
    return tuple((t + 0.25 * k, rng.uniform(0, 40), rng.uniform(0, 20)) for k in range(n))


def _observation(rng: random.Random, robot: str, t: float) -> Observation:
    neighbours = tuple(
        Neighbour(
            f"r{rng.randrange(100)}",
            rng.uniform(0, 40),
            rng.uniform(0, 20),
            rng.uniform(-1, 1),
            rng.uniform(-1, 1),
            rng.uniform(0.1, 1.0),
            rng.randrange(-5, 100),
            _plan(rng, rng.randrange(0, 12), t),
        )
        for _ in range(rng.randrange(0, 5))
    )
    return Observation(
        robot,
        rng.randrange(10_000),
        t,
        rng.uniform(0, 40),
        rng.uniform(0, 20),
        rng.uniform(-1, 1),
        rng.uniform(-1, 1),
        goal=rng.choice([None, (rng.uniform(0, 40), rng.uniform(0, 20))]),
        job=rng.choice([None, f"job-{rng.randrange(1000)}"]),
        speed_cap=rng.choice([None, rng.uniform(0, 1)]),
        neighbours=neighbours,
        speed_caps=((t, t + 20.0, 0.3), (t + 20.0, t + 60.0, 0.5))[: rng.randrange(3)],
        print_end_s=rng.choice([None, t + rng.uniform(0, 600)]),
        priority=rng.randrange(-5, 100),
        blockers=tuple(f"r{rng.randrange(100)}" for _ in range(rng.randrange(3))),
        queued=rng.randrange(5),
    )


def valid_message(rng: random.Random) -> tuple[MessageKind, str, int, dict[str, Any]]:
    """A random valid message: its kind, sender, tick and body (as `encode` takes it)."""
    kind = rng.choice(list(MessageKind))
    t = rng.uniform(0, 3600)
    robots = [f"r{i:02d}" for i in rng.sample(range(200), rng.randrange(0, 12))]
    if kind is MessageKind.HELLO:
        body: dict[str, Any] = {"robots": robots, "scenario": rng.choice(["", "0123abcd"])}
    elif kind is MessageKind.WELCOME:
        cut = rng.randrange(len(robots) + 1)
        body = {"accepted": robots[:cut], "rejected": dict.fromkeys(robots[cut:], "no")}
    elif kind is MessageKind.OBSERVE:
        body = {
            "t": t,
            "observations": [_observation(rng, r, t) for r in robots],
            "announcements": [
                Announcement(f"job-{j}", rng.uniform(0, 40), rng.uniform(0, 20), 60.0, t, None)
                for j in range(rng.randrange(3))
            ],
        }
    elif kind is MessageKind.ACT:
        body = {
            "commands": {
                r: Command(
                    rng.uniform(-1, 1),
                    rng.uniform(-1, 1),
                    rng.choice(list(ControlStatus)),
                    _plan(rng, rng.randrange(0, 26), t),
                    rng.choice(
                        [None, SolveReport(SolverOutcome.OPTIMAL, rng.random(), rng.random())]
                    ),
                )
                for r in robots
            },
            "bids": [Bid("job-1", r, rng.uniform(0, 900)) for r in robots[:3]],
            "handbacks": [Handback(r, "job-2", "blocked") for r in robots[3:4]],
        }
    elif kind is MessageKind.HEARTBEAT:
        body = {}
    else:
        body = {"reason": rng.choice(["run finished", "", "é" * 10])}
    sender = rng.choice(["exchange", "agent-1", "a"])
    return kind, sender, rng.randrange(0, 100_000), body


def _hostile_value(rng: random.Random) -> Any:
    return rng.choice(
        [
            None,
            -1,
            -1.5,
            0,
            True,
            "",
            "x",
            "fast",
            [],
            {},
            [1, 2],
            {"a": 1},
            2**70,
            1e308,
            float("nan"),
            float("inf"),
            "é\ud800",
            "x" * rng.choice([10, MAX_ID_CHARS + 1, MAX_TEXT_CHARS + 1, 100_000]),
            [0] * rng.choice([3, 1000, MAX_ROBOTS + 1]),
            _nested(rng.choice([5, 50, 400])),  # deeper: the "nested" category, as text
        ]
    )


def _nested(depth: int) -> Any:
    value: Any = []
    for _ in range(depth):
        value = [value]
    return value


def _paths(obj: Any, path: tuple = ()) -> Iterator[tuple]:
    """Every place in a parsed JSON value, as a path of keys and indices."""
    yield path
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*path, i))


def _container(obj: Any, path: tuple) -> Any:
    for step in path:
        obj = obj[step]
    return obj


def _dumps(obj: Any) -> bytes:
    # allow_nan: Python's NaN and Infinity spellings are what a careless peer sends.
    return json.dumps(obj, allow_nan=True, separators=(",", ":")).encode("utf-8", "surrogatepass")


@dataclass
class Generator:
    """Hostile frames by category, drawn from one seeded generator."""

    rng: random.Random
    _big: dict[str, bytes] = field(default_factory=dict)

    CATEGORIES = (
        ("valid", 15),
        ("field", 25),
        ("fields", 5),
        ("bytes", 10),
        ("truncated", 8),
        ("nested", 5),
        ("kind", 4),
        ("version", 4),
        ("duplicates", 4),
        ("bounds", 3),
        ("oversized", 1),
        ("random", 8),
        ("nonobject", 3),
        ("dupkeys", 5),
    )

    def frames(self, n: int) -> Iterator[tuple[str, bytes]]:
        names = [c for c, _ in self.CATEGORIES]
        weights = [w for _, w in self.CATEGORIES]
        for _ in range(n):
            category = self.rng.choices(names, weights)[0]
            yield category, getattr(self, f"_{category}")()

    def _valid_frame(self) -> bytes:
        return encode(*valid_message(self.rng))

    def _valid_object(self) -> dict[str, Any]:
        return json.loads(self._valid_frame())

    def _valid(self) -> bytes:
        return self._valid_frame()

    def _field(self) -> bytes:
        obj = self._valid_object()
        path = self.rng.choice(list(_paths(obj))[1:])
        _container(obj, path[:-1])[path[-1]] = _hostile_value(self.rng)
        return _dumps(obj)

    def _fields(self) -> bytes:
        obj = self._valid_object()
        dicts = [p for p in _paths(obj) if isinstance(_container(obj, p), dict)]
        target = _container(obj, self.rng.choice(dicts))
        if target and self.rng.random() < 0.5:
            del target[self.rng.choice(list(target))]
        else:
            target[self.rng.choice(["extra", "robot", "x", "version", ""])] = 1
        return _dumps(obj)

    def _bytes(self) -> bytes:
        frame = bytearray(self._valid_frame())
        for _ in range(self.rng.randrange(1, 6)):
            i = self.rng.randrange(len(frame))
            op = self.rng.randrange(3)
            if op == 0:
                frame[i] = self.rng.randrange(256)
            elif op == 1:
                frame.insert(i, self.rng.choice(b'{}[]",:0-.eE\\ \xff'))
            elif len(frame) > 1:
                del frame[i]
        return bytes(frame)

    def _truncated(self) -> bytes:
        frame = self._valid_frame()
        return frame[: self.rng.randrange(len(frame))]

    def _nested(self) -> bytes:
        depth = int(10 ** self.rng.uniform(1, 5.3))  # 10 to 200,000 levels
        if self.rng.random() < 0.5:
            return b"[" * depth + b"]" * depth
        inner = b"[" * depth + b"]" * depth
        return (
            b'{"version":4,"kind":"hello","sender":"a","tick":0,"body":{"robots":%s,' % (inner)
            + b'"scenario":""}}'
        )

    def _kind(self) -> bytes:
        obj = self._valid_object()
        obj["kind"] = self.rng.choice(["HELLO", "observe ", "", "ack", 4, None, ["act"]])
        return _dumps(obj)

    def _version(self) -> bytes:
        obj = self._valid_object()
        obj["version"] = self.rng.choice([0, 1, 2, 3, 5, "4", 4.0, None, -1, 2**64])
        return _dumps(obj)

    def _duplicates(self) -> bytes:
        n = self.rng.choice([2, 100, 5000])
        robots = [f"r{i}" for i in range(n)] + [f"r{self.rng.randrange(n)}"]
        self.rng.shuffle(robots)
        if self.rng.random() < 0.5:
            body: dict[str, Any] = {"robots": robots, "scenario": ""}
            return _dumps(
                {"version": SCHEMA_VERSION, "kind": "hello", "sender": "a", "tick": 0, "body": body}
            )
        body = {"accepted": robots, "rejected": {}}
        return _dumps(
            {"version": SCHEMA_VERSION, "kind": "welcome", "sender": "x", "tick": 0, "body": body}
        )

    def _bounds(self) -> bytes:
        which = self.rng.choice(
            [
                "hello20k",
                "hello20k_dup",
                "act_many",
                "long_sender",
                "act_full",
                "act_full_bad_last",
                "observe_full",
                "observe_full_bad_last",
            ]
        )
        if which not in self._big:
            self._big[which] = _big_frame(which)
        return self._big[which]

    def _oversized(self) -> bytes:
        which = self.rng.choice(["oversized_valid_json", "oversized_blank"])
        if which not in self._big:
            self._big[which] = _big_frame(which)
        return self._big[which]

    def _random(self) -> bytes:
        return self.rng.randbytes(self.rng.choice([0, 1, 8, 100, 5000]))

    def _nonobject(self) -> bytes:
        return _dumps(self.rng.choice([[], None, 4, "hello", [{"version": 4}], 1.5, True]))

    def _dupkeys(self) -> bytes:
        # JSON allows repeated keys; the text is edited, since a dict cannot hold them.
        frame = self._valid_frame()
        key = self.rng.choice([b'"version":4', b'"kind":"bye"', b'"tick":0', b'"sender":"z"'])
        return b"{" + key + b"," + frame[1:]


def hello_ids(n: int, duplicate: bool) -> bytes:
    """A HELLO naming `n` robots, the last one twice if `duplicate`."""
    robots = [f"r{i}" for i in range(n)] + ([f"r{n - 1}"] if duplicate else [])
    body = {"robots": robots, "scenario": ""}
    return _dumps(
        {"version": SCHEMA_VERSION, "kind": "hello", "sender": "a", "tick": 0, "body": body}
    )


def _big_frame(which: str) -> bytes:
    if which == "hello20k":
        return hello_ids(20_000, False)
    if which == "hello20k_dup":
        return hello_ids(20_000, True)
    if which == "act_many":
        cmd = {"ax": 0.0, "ay": 0.0, "status": "ok", "plan": [], "solve": None}
        commands = {f"r{i}": cmd for i in range(MAX_ROBOTS + 1)}
        body = {"commands": commands, "bids": [], "handbacks": []}
        return _dumps(
            {"version": SCHEMA_VERSION, "kind": "act", "sender": "a", "tick": 1, "body": body}
        )
    if which == "long_sender":
        body = {"reason": "x"}
        return _dumps(
            {
                "version": SCHEMA_VERSION,
                "kind": "bye",
                "sender": "s" * 1_000_000,
                "tick": 1,
                "body": body,
            }
        )
    if which.startswith(("act_full", "observe_full")):
        return _full_frame(which.startswith("act"), which.endswith("bad_last"))
    if which == "oversized_valid_json":
        reason = "x" * MAX_MESSAGE_BYTES
        return _dumps(
            {
                "version": SCHEMA_VERSION,
                "kind": "bye",
                "sender": "a",
                "tick": 1,
                "body": {"reason": reason},
            }
        )
    return b" " * (MAX_MESSAGE_BYTES + 1)


def _full_frame(act: bool, bad_last: bool) -> bytes:
    """An ACT or OBSERVE just under the size limit (the slowest to read), valid or with the
    last item's last field wrong (the slowest to reject: everything is read before)."""
    rng = random.Random(5)
    items: list[Any] = []
    size = 0
    while size < MAX_MESSAGE_BYTES - 50_000:
        t = rng.uniform(0, 3600)
        if act:
            plan = [list(p) for p in _plan(rng, 25, t)]
            item = {"ax": 0.1, "ay": -0.1, "status": "ok", "plan": plan, "solve": None}
        else:
            item = json.loads(
                json.dumps(observation_to_wire(_observation(rng, f"r{len(items)}", t)))
            )
        items.append(item)
        size += len(_dumps(item))
    if bad_last:
        items[-1]["ay" if act else "queued"] = -1 if not act else "fast"
    if act:
        body: dict[str, Any] = {
            "commands": {f"r{i}": c for i, c in enumerate(items)},
            "bids": [],
            "handbacks": [],
        }
    else:
        body = {"t": 1.0, "observations": items, "announcements": []}
    kind = "act" if act else "observe"
    return _dumps({"version": SCHEMA_VERSION, "kind": kind, "sender": "a", "tick": 1, "body": body})


# --- in process ------------------------------------------------------------------------------


@dataclass
class Tally:
    """What the decodes of one run of the in-process fuzz gave."""

    outcomes: dict[str, Counter] = field(default_factory=lambda: defaultdict(Counter))
    times_us: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    slowest: list[tuple[float, str, int]] = field(default_factory=list)
    crashes: list[tuple[str, str, bytes]] = field(default_factory=list)

    @property
    def total(self) -> int:
        return sum(sum(c.values()) for c in self.outcomes.values())

    def count(self, outcome: str) -> int:
        return sum(c[outcome] for c in self.outcomes.values())


def judge(frame: bytes) -> tuple[str, float]:
    """Decode `frame`: "accepted" (and it encodes again to the same message), "rejected" (a
    `MessageError`), or "crash: <what>"; and how long the decode took (s)."""
    start = time.perf_counter()
    try:
        msg = decode(frame)
    except MessageError:
        return "rejected", time.perf_counter() - start
    except Exception as exc:  # noqa: BLE001 - what the harness is looking for
        return f"crash: {type(exc).__name__}: {str(exc)[:200]}", time.perf_counter() - start
    took = time.perf_counter() - start
    try:
        again = decode(encode(msg.kind, msg.sender, msg.tick, msg.body))
    except Exception as exc:  # noqa: BLE001
        return f"crash: accepted but does not encode again: {type(exc).__name__}: {exc}", took
    if again != msg:
        return "crash: accepted but encodes to another message", took
    return "accepted", took


def fuzz_in_process(n: int, seed: int, progress: Callable[[int], None] | None = None) -> Tally:
    """Decode `n` generated frames; what came of them."""
    tally = Tally()
    for i, (category, frame) in enumerate(Generator(random.Random(seed)).frames(n)):
        outcome, took = judge(frame)
        us = took * 1e6
        kind = outcome if not outcome.startswith("crash") else "crash"
        tally.outcomes[category][kind] += 1
        tally.times_us[category].append(us)
        tally.slowest.append((us, category, len(frame)))
        if len(tally.slowest) > 64:
            tally.slowest = sorted(tally.slowest, reverse=True)[:10]
        if kind == "crash":
            tally.crashes.append((category, outcome[:300], frame[:300]))
        if progress is not None and i % 1000 == 0:
            progress(i)
    tally.slowest = sorted(tally.slowest, reverse=True)[:10]
    return tally


def reject_time_ms(frame: bytes, repeats: int = 7) -> float:
    """Median time to decode (and reject) `frame`."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        with contextlib.suppress(MessageError):
            decode(frame)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def cmd_inprocess(args: argparse.Namespace) -> int:
    print(f"in-process fuzz: {args.messages:,} frames, seed {args.seed}")
    start = time.perf_counter()
    tally = fuzz_in_process(args.messages, args.seed, _progress(args.messages))
    elapsed = time.perf_counter() - start
    if sys.stdout.isatty():
        print(f"\r{' ' * 40}\r", end="")
    head = ("category", "frames", "accepted", "rejected", "crash", "median us", "max ms")
    print("{:<12} {:>8} {:>9} {:>9} {:>6} {:>10} {:>8}".format(*head))
    for category, _ in Generator.CATEGORIES:
        c, t = tally.outcomes[category], tally.times_us[category]
        if not t:
            continue
        print(
            f"{category:<12} {len(t):>8,} {c['accepted']:>9,} {c['rejected']:>9,} {c['crash']:>6}"
            f" {statistics.median(t):>10.1f} {max(t) / 1e3:>8.2f}"
        )
    everything = [us for t in tally.times_us.values() for us in t]
    print(
        f"all: {tally.total:,} frames in {elapsed:.1f} s; accepted {tally.count('accepted'):,},"
        f" rejected {tally.count('rejected'):,}, crashes {tally.count('crash')};"
        f" median {statistics.median(everything):.1f} us, max {max(everything) / 1e3:.2f} ms"
    )
    print("slowest decodes:")
    for us, category, size in tally.slowest[:5]:
        print(f"  {us / 1e3:8.2f} ms  {category:<12} {size:>10,} bytes")
    dup = reject_time_ms(hello_ids(20_000, True))
    print(f"HELLO with 20,000 ids and a duplicate: rejected in {dup:.2f} ms (median of 7)")
    over = [s for s in tally.slowest if s[0] / 1e3 > args.budget_ms]
    for category, outcome, frame in tally.crashes[:10]:
        print(f"CRASH [{category}] {outcome}\n   frame: {frame!r}")
    if over:
        print(f"OVER BUDGET: {len(over)} of the slowest decodes took over {args.budget_ms:g} ms")
    return 1 if tally.crashes or over or dup > args.budget_ms else 0


def _progress(total: int) -> Callable[[int], None]:
    def show(i: int) -> None:
        if sys.stdout.isatty():
            print(f"\r  {i:,} / {total:,}", end="", flush=True)

    return show


# --- the attacker (a process of its own) -------------------------------------------------------


def attack(address: str, messages: int, seed: int, connections: int) -> dict:
    """Send `messages` hostile frames to the exchange at `address` from `connections` DEALER
    sockets (ZeroMQ gives each connection a routing id of its own); returns counts.

    Started once the run's agents have joined: claiming robots before they do, or taking
    over an agent's routing id, are attacks that CurveZMQ, not the schema, answers."""
    import zmq

    ctx = zmq.Context()
    sockets = []
    for _ in range(connections):
        s = ctx.socket(zmq.DEALER)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDTIMEO, 1000)
        s.connect(address)
        sockets.append(s)
    gen = Generator(random.Random(seed))
    sent = unsent = multipart = oversized = 0
    started = time.monotonic()
    for i, (_, frame) in enumerate(gen.frames(messages)):
        s = sockets[i % connections]
        if len(frame) > MAX_MESSAGE_BYTES:
            # ZeroMQ drops the connection an oversized frame comes on, and with it the frames
            # queued behind it: one connection of its own each, so the others all arrive.
            one = ctx.socket(zmq.DEALER)
            one.connect(address)
            one.send(frame)
            one.close(linger=1000)
            oversized += 1
            sent += 1
            continue
        try:
            if i % 97 == 0:
                s.send_multipart([frame, b"second frame"])
                multipart += 1
            else:
                s.send(frame)
            sent += 1
        except zmq.Again:
            unsent += 1
    elapsed = time.monotonic() - started
    for s in sockets:
        s.close(linger=30_000)  # what is still queued goes out before the process ends
    ctx.term()
    return {
        "sent": sent,
        "unsent": unsent,
        "multipart": multipart,
        "oversized": oversized,
        "seconds": round(elapsed, 2),
    }


def cmd_attack(args: argparse.Namespace) -> int:
    report = attack(args.connect, args.attack, args.seed, args.connections)
    print(json.dumps(report))
    return 0


# --- real runs -------------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def fleet(*args: str) -> list[str]:
    return [sys.executable, "-m", "fleet.cli", *args]


@dataclass
class Served:
    """A finished `fleet serve` run."""

    returncode: int
    summary: dict[str, Any]
    stderr: str
    peak_rss_kb: int


class Engine:
    """A `fleet serve` process, its log read as it comes (the bus logs joins at info level)."""

    def __init__(self, common: list[str], address: str, out: Path, *extra: str) -> None:
        self.out = out
        self.process = subprocess.Popen(
            fleet(
                "serve",
                *common,
                "--bind",
                address,
                "--out",
                str(out),
                "--quiet",
                "--no-figures",
                "--wait",
                "120",
                *extra,
            ),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self.lines.append(line)

    @property
    def pid(self) -> int:
        return self.process.pid

    def running(self) -> bool:
        """Whether the engine is still running; it is not reaped (`finish` wants its rusage)."""
        flags = os.WEXITED | os.WNOHANG | os.WNOWAIT
        return os.waitid(os.P_PID, self.pid, flags) is None

    def wait_for_joins(self, agents: int, timeout_s: float = 120.0) -> None:
        """Until `agents` agents have joined (or raise)."""
        self.wait_for_line(" joined, hosting ", agents, timeout_s)

    def wait_for_line(self, text: str, count: int = 1, timeout_s: float = 120.0) -> None:
        """Until the engine has logged `count` lines holding `text` (or raise)."""
        deadline = time.monotonic() + timeout_s
        while sum(text in line for line in self.lines) < count:
            if time.monotonic() > deadline or not self.running():
                raise SystemExit(f"engine never logged {text!r}: {''.join(self.lines)[-2000:]}")
            time.sleep(0.05)

    def finish(self, timeout_s: float = 900) -> Served:
        """Wait for the engine; its summary, log and peak memory (the kernel's rusage)."""
        deadline = time.monotonic() + timeout_s
        while True:
            pid, status, usage = os.wait4(self.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                self.process.kill()
                raise SystemExit("engine did not finish in time")
            time.sleep(0.1)
        self.process.returncode = os.waitstatus_to_exitcode(status)
        self._reader.join(timeout=10)
        path = self.out / "summary.json"
        summary = json.loads(path.read_text()) if path.exists() else {}
        return Served(self.process.returncode, summary, "".join(self.lines), usage.ru_maxrss)


def agent(common: list[str], address: str, *extra: str) -> subprocess.Popen:
    # An agent takes the scenario and fleet size, not the run's duration or seed.
    return subprocess.Popen(
        fleet("agent", *common[:3], "--connect", address, "--wait", "60", *extra),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def rss_kb(pid: int) -> int:
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmRSS:\s+(\d+)", text)[1])


def jobs_of(summary: dict[str, Any]) -> dict[str, int]:
    jobs = summary.get("jobs", {})
    return {k: jobs.get(k) for k in ("released", "completed", "failed", "in_progress")}


def bus_of(summary: dict[str, Any]) -> dict[str, int]:
    keys = ("messages_received", "messages_rejected", "messages_ignored", "peers_cut_off")
    return {k: summary.get("engine", {}).get(f"bus_{k}") for k in keys}


def served_run(
    tmp: Path,
    label: str,
    common: list[str],
    attack_messages: int = 0,
    seed: int = 1,
    waves: int = 2,
) -> tuple[Served, dict[str, Any]]:
    """One served run with two agents, attacked by `attack_messages` frames if > 0, sent in
    `waves` attacks one after the other (each a process of its own)."""
    address = f"tcp://127.0.0.1:{free_port()}"
    engine = Engine(common, address, tmp / label)
    agents = [agent(common, address, "--share", share) for share in ("1/2", "2/2")]
    info: dict[str, Any] = {}
    if attack_messages:
        engine.wait_for_joins(len(agents))
        info["rss_kb"] = [rss_kb(engine.pid)]
        info["attacks"] = []
        # Waves of the same size: memory that grows by the second is a leak, memory that
        # stays is what the first wave's queues took.
        for wave in range(waves):
            attacker = subprocess.run(
                [
                    sys.executable,
                    __file__,
                    "attack",
                    "--connect",
                    address,
                    "--attack",
                    str(attack_messages // waves),
                    "--seed",
                    str(seed + wave),
                ],
                capture_output=True,
                text=True,
                timeout=600,
            )
            if attacker.returncode != 0:
                raise SystemExit(f"attacker failed: {attacker.stderr[-2000:]}")
            info["attacks"].append(json.loads(attacker.stdout.strip().splitlines()[-1]))
            with contextlib.suppress(OSError, TypeError):
                info["rss_kb"].append(rss_kb(engine.pid))
        info["engine_running_after_attack"] = engine.running()
    served = engine.finish()
    for a in agents:
        a.communicate(timeout=120)
    info["agent_exit_codes"] = [a.returncode for a in agents]
    return served, info


def run_options(args: argparse.Namespace) -> list[str]:
    """The scenario and the options `fleet serve` takes from the harness's own (an agent
    takes the first three)."""
    return [
        str(FLEET_TOML),
        "--robots",
        str(args.robots),
        "--duration",
        str(args.duration),
        "--seed",
        str(args.seed),
    ]


def cmd_sockets(args: argparse.Namespace) -> int:
    common = run_options(args)
    with tempfile.TemporaryDirectory(prefix="fuzz-bus-") as tmp:
        print(f"socket fuzz: fleet.toml, {args.robots} robots, {args.duration:g} s, two agents")
        quiet, _ = served_run(Path(tmp), "undisturbed", common)
        loud, info = served_run(Path(tmp), "attacked", common, args.attack, args.seed)
    ok = True
    for label, run in (("undisturbed", quiet), ("attacked", loud)):
        s = run.summary
        print(
            f"{label:<12} exit {run.returncode}, digest {s.get('digest')}, jobs {jobs_of(s)},"
            f" peak RSS {run.peak_rss_kb / 1024:.1f} MiB"
        )
        ok &= run.returncode == 0
    print(
        f"attack: {info['attacks']}; engine still running after it: "
        f"{info['engine_running_after_attack']}"
    )
    mib = ", ".join(f"{kb / 1024:.1f}" for kb in info["rss_kb"])
    print(f"engine RSS (MiB) before the attack, after wave 1, after wave 2: {mib}")
    counters = bus_of(loud.summary)
    reached = counters["messages_received"] - bus_of(quiet.summary)["messages_received"]
    print(
        f"engine's bus counters (attacked): {counters}; hostile messages that reached it:"
        f" {reached:,}"
    )
    refusals = Counter(re.findall(r"dropped message from .*? \((\w+)\): ", loud.stderr))
    print(
        f"engine log: {dict(refusals)} refusal lines, "
        f"{loud.stderr.count('cut off')} cut-off lines, {len(loud.stderr.splitlines())} lines"
    )
    same = quiet.summary.get("digest") == loud.summary.get("digest") and jobs_of(
        quiet.summary
    ) == jobs_of(loud.summary)
    print("digest and jobs: " + ("the same" if same else "DIFFERENT"))
    return 0 if ok and same and info["engine_running_after_attack"] else 1


def cmd_faults(args: argparse.Namespace) -> int:
    common = run_options(args)
    shares = ("1/3", "2/3", "3/3")
    with tempfile.TemporaryDirectory(prefix="fuzz-bus-") as tmp:
        address = f"tcp://127.0.0.1:{free_port()}"
        engine = Engine(common, address, Path(tmp) / "faults")
        agents = [
            agent(common, address, "--share", s, "--name", f"a{i}") for i, s in enumerate(shares)
        ]
        engine.wait_for_joins(len(agents))
        time.sleep(args.after)
        print(f"faults: SIGKILL agent a0 {args.after:g} s into the run, then a replacement joins")
        agents[0].send_signal(signal.SIGKILL)
        agents[0].wait()
        # Its replacement is refused until the engine has found it lost.
        engine.wait_for_line("agent a0 lost")
        agents.append(agent(common, address, "--share", shares[0], "--name", "a0-again"))
        print(f"faults: SIGSTOP agent a1 for {args.pause:g} s, SIGCONT, then a replacement joins")
        agents[1].send_signal(signal.SIGSTOP)
        time.sleep(args.pause)
        agents[1].send_signal(signal.SIGCONT)
        agents[1].communicate(timeout=60)  # told it was dropped, it stops
        engine.wait_for_line("agent a1 lost")
        agents.append(agent(common, address, "--share", shares[1], "--name", "a1-again"))
        served = engine.finish()
        for a in agents[2:]:
            a.communicate(timeout=120)
    s = served.summary
    jobs = s.get("jobs", {})
    faults = s.get("faults", {})
    print(
        f"exit {served.returncode}; jobs {jobs_of(s)}, accounted {jobs.get('accounted')},"
        f" handed back {jobs.get('handed_back')}"
    )
    print(f"faults {faults}")
    print(f"agent exit codes: {[a.returncode for a in agents]} (a0 killed, a1 paused)")
    ok = (
        served.returncode == 0
        and jobs.get("accounted") is True
        and faults.get("agents_lost", 0) >= 2
        and faults.get("robots_rejoined", 0) == faults.get("robots_orphaned", -1)
    )
    print("faults: " + ("survived and counted" if ok else "NOT AS EXPECTED"))
    return 0 if ok else 1


def cmd_curve(args: argparse.Namespace) -> int:
    with tempfile.TemporaryDirectory(prefix="fuzz-bus-") as tmp:
        keys = Path(tmp) / "keys"
        authorized = Path(tmp) / "authorized"
        for name in ("engine", "agent", "stranger"):
            subprocess.run(
                fleet("keys", str(keys), "--name", name), check=True, capture_output=True
            )
        modes = {p.name: oct(p.stat().st_mode & 0o777) for p in sorted(keys.iterdir())}
        modes["(directory)"] = oct(keys.stat().st_mode & 0o777)
        secret_ok = (
            all(mode == "0o600" for name, mode in modes.items() if name.endswith("key_secret"))
            and modes["(directory)"] == "0o700"
        )
        print(f"key files: {modes}")
        authorized.mkdir()
        (authorized / "agent.key").write_bytes((keys / "agent.key").read_bytes())
        common = [str(FLEET_TOML), "--robots", "2", "--duration", "20", "--seed", "1"]
        address = f"tcp://127.0.0.1:{free_port()}"
        engine = Engine(
            common,
            address,
            Path(tmp) / "run",
            "--key",
            str(keys / "engine.key_secret"),
            "--authorized",
            str(authorized),
        )
        plain = agent(common, address, "--wait", "5", "--name", "plain")
        wrong = agent(
            common,
            address,
            "--wait",
            "5",
            "--name",
            "wrong",
            "--key",
            str(keys / "stranger.key_secret"),
            "--server-key",
            str(keys / "engine.key"),
        )
        refused = [p.communicate(timeout=60) and p.returncode for p in (plain, wrong)]
        friend = agent(
            common,
            address,
            "--name",
            "friend",
            "--key",
            str(keys / "agent.key_secret"),
            "--server-key",
            str(keys / "engine.key"),
        )
        served = engine.finish()
        friend.communicate(timeout=60)
    lines = [ln for ln in served.stderr.splitlines() if "refus" in ln.lower()]
    print(f"refused agents' exit codes (no key, wrong key): {refused}")
    print(f"engine's refusal log lines: {len(lines)}")
    for line in lines[:4]:
        print(f"  {line[:160]}")
    print(f"authorised agent exit {friend.returncode}; engine exit {served.returncode}")
    ok = secret_ok and refused == [1, 1] and friend.returncode == 0 and served.returncode == 0
    ok &= len(lines) >= 2
    print("curve: " + ("as expected" if ok else "NOT AS EXPECTED"))
    return 0 if ok else 1


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["inprocess", "sockets", "attack", "faults", "curve", "all"])
    ap.add_argument("--messages", type=int, default=100_000, help="in-process frames")
    ap.add_argument("--attack", type=int, default=10_000, help="hostile messages over sockets")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--budget-ms", type=float, default=50.0, help="flag decodes slower than this")
    ap.add_argument("--robots", type=int, default=4)
    ap.add_argument("--duration", type=float, default=3600.0, help="simulated seconds per run")
    ap.add_argument("--after", type=float, default=1.0, help="faults: seconds before the kill")
    ap.add_argument("--pause", type=float, default=6.0, help="faults: seconds of SIGSTOP")
    ap.add_argument("--connect", help="attack: the engine's address")
    ap.add_argument("--connections", type=int, default=8, help="attack: sockets to send from")
    return ap


def main() -> int:
    args = parser().parse_args()
    parts = {
        "inprocess": cmd_inprocess,
        "sockets": cmd_sockets,
        "attack": cmd_attack,
        "faults": cmd_faults,
        "curve": cmd_curve,
    }
    if args.part != "all":
        return parts[args.part](args)
    return max(parts[p](args) for p in ("inprocess", "sockets", "faults", "curve"))


if __name__ == "__main__":
    sys.exit(main())
