"""The bus's wire schema: what the engine and the robot agents say to each other, version 4.

Every message is one ZeroMQ frame holding one compact UTF-8 JSON object, the *envelope*::

    {"version": 4, "kind": "observe", "sender": "exchange", "tick": 42, "body": {...}}

`kind` says what the body holds (see `MessageKind`); `tick` is the engine's control tick the
message belongs to (0 for HELLO). Observations and commands travel as JSON objects whose fields
are exactly those of `fleet.plugins.Observation` and `fleet.plugins.Command`; small fixed
tuples travel as arrays: a goal is ``[x, y]``, a neighbour
``[robot, x, y, vx, vy, radius, priority, plan]``, a plan sample ``[t, x, y]``, a speed-cap
piece ``[start_s, end_s, cap]``, a solve report ``[outcome, solver_s, step_s]``, an
announcement ``[job, x, y, print_s, released_s, due_s]``, a bid ``[job, robot, estimate_s]``
and a handback ``[robot, job, reason]``. Every field is always present (``null`` where the
dataclass holds None), so a message either matches the schema exactly or is rejected.

History: version 2 added ``speed_caps`` and ``solve``, version 3 ``print_end_s``; version 4
(contract net and liveness) added the observation's ``priority``, ``blockers`` and ``queued``,
the neighbour's radius, priority and plan, OBSERVE's ``announcements``, ACT's ``bids`` and
``handbacks``, HELLO's ``scenario`` and the HEARTBEAT kind.

`decode` trusts nothing: it checks the JSON, the version, the kind, every field's presence and
type, that numbers are finite and that no field is extra, and raises `MessageError` saying what
is wrong with the bad value quoted. It returns OBSERVE and ACT bodies already converted to
`fleet.plugins` objects (`Observation`, `Announcement`, `Command`, `Bid`, `Handback`), so each
message is parsed and checked exactly once. Batching many robots into one message keeps the
per-robot cost to a few microseconds.
"""

from __future__ import annotations

import enum
import json
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from itertools import chain
from typing import Any

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

__all__ = [
    "SCHEMA_VERSION",
    "MessageKind",
    "Message",
    "encode",
    "decode",
    "observation_to_wire",
    "observation_from_wire",
    "command_to_wire",
    "command_from_wire",
    "announcement_to_wire",
    "bid_to_wire",
    "handback_to_wire",
]

SCHEMA_VERSION = 4
"""The version this build writes and the only one it reads."""


class MessageKind(enum.Enum):
    """What a message is for; the value is what travels in the envelope's ``kind``."""

    HELLO = "hello"
    """Agent to engine, first message: ``{"robots": [robot, ...], "scenario": fingerprint}``,
    the robots it hosts and the fingerprint of the scenario it was set up for (``""``: not
    checked)."""
    WELCOME = "welcome"
    """Engine to agent, answer to HELLO: ``{"accepted": [robot, ...], "rejected": {robot: why}}``.
    """
    OBSERVE = "observe"
    """Engine to agent, once per tick: ``{"t": seconds, "observations": [Observation, ...],
    "announcements": [Announcement, ...]}``; the agent bids for the announced jobs on behalf of
    the observed robots."""
    ACT = "act"
    """Agent to engine, answer to the same tick's OBSERVE: ``{"commands": {robot: Command},
    "bids": [Bid, ...], "handbacks": [Handback, ...]}``."""
    HEARTBEAT = "heartbeat"
    """Agent to engine, body ``{}``: "I am alive", sent while computing or idle so the engine
    can tell a slow agent from a dead one."""
    BYE = "bye"
    """Either way, last message: ``{"reason": text}``; the sender is leaving."""


@dataclass(frozen=True)
class Message:
    """One decoded, fully validated bus message.

    Attributes
    ----------
    kind:
        What the body holds.
    sender:
        Name of the sending agent or exchange (non-empty).
    tick:
        Control tick the message belongs to (>= 0).
    body:
        The body as documented on `MessageKind`: JSON values, except that OBSERVE's
        ``observations`` and ``announcements`` are lists of `Observation` and `Announcement`,
        ACT's ``commands`` maps robot ids to `Command` objects and its ``bids`` and
        ``handbacks`` are lists of `Bid` and `Handback`.
    version:
        Schema version of the message (always `SCHEMA_VERSION` once decoded).
    """

    kind: MessageKind
    sender: str
    tick: int
    body: dict[str, Any]
    version: int = SCHEMA_VERSION


# --- encoding ------------------------------------------------------------------------------------


def _unencodable(value: Any) -> Any:
    raise TypeError(f"{type(value).__name__} {_quote(value)} is not a JSON value")


# The C encoder, built once and called directly: json.dumps rebuilds it on every call, which
# costs more than encoding a small message. allow_nan=False makes NaN and infinity errors.
_c_encoder = getattr(json.encoder, "c_make_encoder", None)
if _c_encoder is not None:
    _make_chunks = _c_encoder(
        None,
        _unencodable,
        json.encoder.encode_basestring_ascii,
        None,
        ":",
        ",",
        False,
        False,
        False,
    )

    def _to_json(obj: Any) -> str:
        return "".join(_make_chunks(obj, 0))

else:  # pragma: no cover - Python builds without the _json accelerator
    _to_json = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=_unencodable).encode


def encode(kind: MessageKind, sender: str, tick: int, body: Mapping[str, Any]) -> bytes:
    """Serialise one message to compact UTF-8 JSON.

    OBSERVE observations and announcements, and ACT commands, bids and handbacks, may be given
    as `fleet.plugins` objects (converted here) or in their wire form (the dicts
    `observation_to_wire` / `command_to_wire` return, the lists `announcement_to_wire`,
    `bid_to_wire` / `handback_to_wire` return); so ``decode(encode(k, s, t, body)).body ==
    body`` for a body written with the objects (and lists).

    Raises
    ------
    MessageError
        If `kind`, `sender` or `tick` is malformed, the body lacks a field of its kind or has
        one too many, ``observations`` is not a list of observations, ``commands`` is not a
        mapping of robot ids to commands, a command, bid or handback is invalid, or the body
        holds a value JSON cannot carry (NaN, infinity, a non-JSON type); the message names
        where.
    """
    if not isinstance(kind, MessageKind):
        raise MessageError(f"cannot encode: kind = {_quote(kind)}: must be a MessageKind")
    if type(sender) is not str or not sender:
        raise MessageError(f"cannot encode: sender = {_quote(sender)}: must be a non-empty string")
    if type(tick) is not int or tick < 0:
        raise MessageError(f"cannot encode: tick = {_quote(tick)}: must be an integer >= 0")
    where = f"cannot encode {kind.name} from {sender!r} at tick {tick}: body"
    if not isinstance(body, Mapping):
        raise _fail(where, body, "must be a mapping")
    fields = _BODY_FIELDS[kind]
    if body.keys() != fields:
        _check_fields(dict(body), where, fields)
    if kind is MessageKind.OBSERVE:
        items = body["observations"]
        if not isinstance(items, list | tuple):
            raise _fail(f"{where}.observations", items, "must be a list of observations")
        wire = []
        for i, o in enumerate(items):
            if isinstance(o, Observation):
                wire.append(observation_to_wire(o))
            elif type(o) is dict:
                wire.append(o)
            else:
                raise _fail(
                    f"{where}.observations[{i}]",
                    o,
                    "must be a fleet.plugins.Observation or its wire dict",
                )
        announcements = _items_to_wire(
            body["announcements"], Announcement, announcement_to_wire, f"{where}.announcements"
        )
        body = {**body, "observations": wire, "announcements": announcements}
    elif kind is MessageKind.ACT:
        items = body["commands"]
        if not isinstance(items, Mapping):
            raise _fail(f"{where}.commands", items, "must be a mapping {robot: command}")
        commands = {}
        for robot, c in items.items():
            if isinstance(c, Command):
                try:
                    commands[robot] = command_to_wire(c)
                except MessageError as exc:
                    raise MessageError(f"cannot encode ACT for robot {robot!r}: {exc}") from None
            elif type(c) is dict:
                commands[robot] = c
            else:
                raise _fail(
                    f"{where}.commands[{robot!r}]",
                    c,
                    "must be a fleet.plugins.Command or its wire dict",
                )
        bids = _items_to_wire(body["bids"], Bid, bid_to_wire, f"{where}.bids")
        handbacks = _items_to_wire(
            body["handbacks"], Handback, handback_to_wire, f"{where}.handbacks"
        )
        body = {**body, "commands": commands, "bids": bids, "handbacks": handbacks}
    envelope = {
        "version": SCHEMA_VERSION,
        "kind": kind.value,
        "sender": sender,
        "tick": tick,
        "body": body,
    }
    try:
        return _to_json(envelope).encode()
    except (ValueError, TypeError, RecursionError) as exc:
        where = _find_unencodable(body, "body") or "body"
        raise MessageError(
            f"cannot encode {kind.name} from {sender!r} at tick {tick}: {where}: {exc}"
        ) from exc


def _items_to_wire(items: Any, cls: type, to_wire: Any, where: str) -> list:
    """`items` (objects of `cls` or their wire lists) as wire lists, for `encode`."""
    if not isinstance(items, list | tuple):
        raise _fail(where, items, f"must be a list of fleet.plugins.{cls.__name__}")
    wire = []
    for i, item in enumerate(items):
        if isinstance(item, cls):
            try:
                wire.append(to_wire(item))
            except MessageError as exc:
                raise MessageError(f"{where}[{i}]: {exc}") from None
        elif type(item) is list:
            wire.append(item)
        else:
            raise _fail(f"{where}[{i}]", item, f"must be a fleet.plugins.{cls.__name__} or a list")
    return wire


def observation_to_wire(o: Observation) -> dict[str, Any]:
    """The JSON form of an observation (numbers coerced to plain float/int, e.g. from numpy).

    A neighbour's plan goes out as it is (a tuple of ``(t, x, y)`` tuples): it is the plan
    that robot's agent sent, already checked when it arrived, and copying thousands of
    samples per tick would be most of the encoding time. A sample JSON cannot carry (NaN,
    a numpy array) still makes `encode` fail, naming where.
    """
    goal = o.goal
    return {
        "robot": o.robot,
        "tick": int(o.tick),
        "t": float(o.t),
        "x": float(o.x),
        "y": float(o.y),
        "vx": float(o.vx),
        "vy": float(o.vy),
        "goal": None if goal is None else [float(goal[0]), float(goal[1])],
        "job": o.job,
        "speed_cap": None if o.speed_cap is None else float(o.speed_cap),
        "neighbours": [
            [
                n.robot,
                float(n.x),
                float(n.y),
                float(n.vx),
                float(n.vy),
                float(n.radius),
                int(n.priority),
                n.plan,
            ]
            for n in o.neighbours
        ],
        "speed_caps": [[float(a), float(b), float(c)] for a, b, c in o.speed_caps],
        "print_end_s": None if o.print_end_s is None else float(o.print_end_s),
        "priority": int(o.priority),
        "blockers": list(o.blockers),
        "queued": int(o.queued),
    }


def command_to_wire(c: Command) -> dict[str, Any]:
    """The JSON form of a command, checked on the way out since commands come from plugins.

    Raises
    ------
    MessageError
        If `c` is not a `Command`, an acceleration or plan value is not a finite number, the
        status is not a `ControlStatus`, or a plan sample is not a ``(t, x, y)`` triple.
    """
    if not isinstance(c, Command):
        raise _fail("command", c, "must be a fleet.plugins.Command")
    status = c.status
    if not isinstance(status, ControlStatus):
        raise _fail("command.status", status, f"must be a ControlStatus ({_STATUS_NAMES})")
    plan = c.plan
    solve = c.solve
    if solve is not None:
        if not isinstance(solve, SolveReport) or not isinstance(solve.outcome, SolverOutcome):
            raise _fail("command.solve", solve, "must be None or a SolveReport")
        solve = [
            solve.outcome.value,
            _number(solve.solver_s, "command.solve", "solver_s"),
            _number(solve.step_s, "command.solve", "step_s"),
        ]
    return {
        "ax": _number(c.ax, "command", "ax"),
        "ay": _number(c.ay, "command", "ay"),
        "status": status.value,
        "plan": [_triple(p, "command.plan", i) for i, p in enumerate(plan)] if plan else [],
        "solve": solve,
    }


def announcement_to_wire(a: Announcement) -> list[Any]:
    """The JSON form of an announcement, ``[job, x, y, print_s, released_s, due_s]``.

    Raises
    ------
    MessageError
        If the job id is not a non-empty string, a number is not finite or `print_s` < 0.
    """
    _nonempty(a.job, "announcement", "job")
    print_s = _number(a.print_s, "announcement", "print_s")
    if print_s < 0:
        raise _fail("announcement.print_s", a.print_s, "must be >= 0")
    return [
        a.job,
        _number(a.x, "announcement", "x"),
        _number(a.y, "announcement", "y"),
        print_s,
        _number(a.released_s, "announcement", "released_s"),
        None if a.due_s is None else _number(a.due_s, "announcement", "due_s"),
    ]


def bid_to_wire(b: Bid) -> list[Any]:
    """The JSON form of a bid, ``[job, robot, estimate_s]``, checked (bids come from plugins).

    Raises
    ------
    MessageError
        If the job or robot id is not a non-empty string, or the estimate is not a finite
        number >= 0.
    """
    _nonempty(b.job, "bid", "job")
    _nonempty(b.robot, "bid", "robot")
    estimate = _number(b.estimate_s, "bid", "estimate_s")
    if estimate < 0:
        raise _fail("bid.estimate_s", b.estimate_s, "must be >= 0")
    return [b.job, b.robot, estimate]


def handback_to_wire(h: Handback) -> list[Any]:
    """The JSON form of a handback, ``[robot, job, reason]``.

    Raises
    ------
    MessageError
        If the robot or job id is not a non-empty string, or the reason is not a string.
    """
    _nonempty(h.robot, "handback", "robot")
    _nonempty(h.job, "handback", "job")
    if type(h.reason) is not str:
        raise _fail("handback.reason", h.reason, "must be a string")
    return [h.robot, h.job, h.reason]


# --- decoding ------------------------------------------------------------------------------------


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a finite number")


_DECODER = json.JSONDecoder(parse_constant=_reject_constant)
# The scanner alone: JSONDecoder.decode adds two regex passes for surrounding whitespace.
_scan = _DECODER.scan_once

_ENVELOPE_FIELDS = frozenset(("version", "kind", "sender", "tick", "body"))
_KINDS = {k.value: k for k in MessageKind}
_LABELS = {k: f"{k.name} message from " for k in MessageKind}
_KIND_NAMES = ", ".join(repr(k.value) for k in MessageKind)
_STATUS = {s.value: s for s in ControlStatus}
_STATUS_NAMES = ", ".join(repr(s.value) for s in ControlStatus)
_OUTCOME = {o.value: o for o in SolverOutcome}
_OUTCOME_NAMES = ", ".join(repr(o.value) for o in SolverOutcome)
_OBSERVATION_FIELDS = frozenset(
    (
        "robot",
        "tick",
        "t",
        "x",
        "y",
        "vx",
        "vy",
        "goal",
        "job",
        "speed_cap",
        "neighbours",
        "speed_caps",
        "print_end_s",
        "priority",
        "blockers",
        "queued",
    )
)
_COMMAND_FIELDS = frozenset(("ax", "ay", "status", "plan", "solve"))
_HELLO_FIELDS = frozenset(("robots", "scenario"))
_WELCOME_FIELDS = frozenset(("accepted", "rejected"))
_OBSERVE_FIELDS = frozenset(("t", "observations", "announcements"))
_ACT_FIELDS = frozenset(("commands", "bids", "handbacks"))
_HEARTBEAT_FIELDS: frozenset[str] = frozenset()
_BYE_FIELDS = frozenset(("reason",))


def decode(raw: bytes, expect: Collection[MessageKind] | None = None) -> Message:
    """Parse and validate one message.

    Parameters
    ----------
    raw:
        The frame as received.
    expect:
        Kinds the caller is ready for; any other kind is rejected. None accepts every kind.

    Returns
    -------
    Message
        The message, with OBSERVE and ACT bodies converted to `fleet.plugins` objects.

    Raises
    ------
    MessageError
        If the frame is not UTF-8 JSON, is of another schema version, of an unknown or
        unexpected kind, or any field is missing, extra, of the wrong type or not finite. The
        message says which field and quotes the bad value.
    """
    if not isinstance(raw, bytes):
        raise _fail("bus message", raw, "must be bytes")
    try:
        text = raw.decode("utf-8")
        try:
            obj, end = _scan(text, 0)
        except StopIteration:  # the scanner's way of saying "no value at index 0"
            end = -1
        if end != len(text):
            # Slow path: whitespace around the value is fine, anything else gets the parser's
            # own description of what is wrong and where.
            obj = _DECODER.decode(text)
    except UnicodeDecodeError as exc:
        raise _fail(
            "bus message", raw, f"is not UTF-8 ({exc.reason} at byte {exc.start})"
        ) from None
    except (ValueError, RecursionError) as exc:
        raise _fail("bus message", raw, f"is not valid JSON ({exc})") from None
    if type(obj) is not dict:
        raise _fail("bus message", obj, "must be a JSON object (the envelope)")
    # The version is checked before the field set: another version may have other fields.
    version = obj.get("version")
    if version != SCHEMA_VERSION or type(version) is not int:
        raise _fail(
            "bus message: version",
            version,
            f"unsupported schema version; this build speaks version {SCHEMA_VERSION}",
        )
    if obj.keys() != _ENVELOPE_FIELDS:
        _check_fields(obj, "bus message", _ENVELOPE_FIELDS)
    kind_value = obj["kind"]
    kind = _KINDS.get(kind_value) if type(kind_value) is str else None
    if kind is None:
        raise _fail("bus message: kind", kind_value, f"must be one of {_KIND_NAMES}")
    sender = obj["sender"]
    if type(sender) is not str or not sender:
        raise _fail("bus message: sender", sender, "must be a non-empty string")
    where = _LABELS[kind] + _quote(sender)
    if expect is not None and kind not in expect:
        allowed = ", ".join(sorted(k.name for k in expect)) or "nothing"
        raise MessageError(f"{where}: unexpected kind {kind.name}; expected {allowed}")
    tick = obj["tick"]
    if type(tick) is not int or tick < 0:
        raise _fail(f"{where}: tick", tick, "must be an integer >= 0")
    body = obj["body"]
    if type(body) is not dict:
        raise _fail(f"{where}: body", body, "must be a JSON object")
    return Message(kind, sender, tick, _BODY_READERS[kind](body, where), version)


def observation_from_wire(d: Any) -> Observation:
    """Validate the JSON form of an observation and build it.

    Raises
    ------
    MessageError
        Naming the field and quoting the value that is missing, extra, mistyped or not finite.
    """
    return _observation(d, "observation")


def command_from_wire(d: Any) -> Command:
    """Validate the JSON form of a command and build it.

    Raises
    ------
    MessageError
        Naming the field and quoting the value that is missing, extra, mistyped or not finite.
    """
    return _command(d, "command")


# --- body readers --------------------------------------------------------------------------------


def _hello_body(body: dict[str, Any], where: str) -> dict[str, Any]:
    if body.keys() != _HELLO_FIELDS:
        _check_fields(body, f"{where}: body", _HELLO_FIELDS)
    scenario = body["scenario"]
    if type(scenario) is not str:
        raise _fail(f"{where}: body.scenario", scenario, "must be a string ('' when unchecked)")
    return {"robots": _robot_list(body["robots"], f"{where}: body.robots"), "scenario": scenario}


def _welcome_body(body: dict[str, Any], where: str) -> dict[str, Any]:
    if body.keys() != _WELCOME_FIELDS:
        _check_fields(body, f"{where}: body", _WELCOME_FIELDS)
    accepted = _robot_list(body["accepted"], f"{where}: body.accepted")
    rejected = body["rejected"]
    if type(rejected) is not dict:
        raise _fail(f"{where}: body.rejected", rejected, "must be an object {robot: reason}")
    for robot, reason in rejected.items():
        if not robot or type(reason) is not str:
            raise _fail(
                f"{where}: body.rejected[{robot!r}]",
                reason,
                "must map a non-empty robot id to a reason string",
            )
    return {"accepted": accepted, "rejected": rejected}


def _observe_body(body: dict[str, Any], where: str) -> dict[str, Any]:
    if body.keys() != _OBSERVE_FIELDS:
        _check_fields(body, f"{where}: body", _OBSERVE_FIELDS)
    t = _number(body["t"], f"{where}: body", "t")
    items = body["observations"]
    if type(items) is not list:
        raise _fail(f"{where}: body.observations", items, "must be an array of observations")
    prefix = f"{where}: body.observations"
    observations = [_observation(d, prefix, i) for i, d in enumerate(items)]
    announcements = body["announcements"]
    if type(announcements) is not list:
        raise _fail(
            f"{where}: body.announcements", announcements, "must be an array of announcements"
        )
    prefix = f"{where}: body.announcements"
    return {
        "t": t,
        "observations": observations,
        "announcements": [_announcement(a, f"{prefix}[{i}]") for i, a in enumerate(announcements)],
    }


def _act_body(body: dict[str, Any], where: str) -> dict[str, Any]:
    if body.keys() != _ACT_FIELDS:
        _check_fields(body, f"{where}: body", _ACT_FIELDS)
    items = body["commands"]
    if type(items) is not dict:
        raise _fail(f"{where}: body.commands", items, "must be an object {robot: command}")
    prefix = f"{where}: body.commands"
    commands = {}
    for robot, d in items.items():
        if not robot:
            raise _fail(prefix, robot, "robot ids must be non-empty")
        commands[robot] = _command(d, prefix, robot)
    bids = body["bids"]
    if type(bids) is not list:
        raise _fail(f"{where}: body.bids", bids, "must be an array of [job, robot, estimate_s]")
    handbacks = body["handbacks"]
    if type(handbacks) is not list:
        raise _fail(
            f"{where}: body.handbacks", handbacks, "must be an array of [robot, job, reason]"
        )
    prefix = f"{where}: body"
    return {
        "commands": commands,
        "bids": [_bid(b, f"{prefix}.bids[{i}]") for i, b in enumerate(bids)],
        "handbacks": [_handback(h, f"{prefix}.handbacks[{i}]") for i, h in enumerate(handbacks)],
    }


def _heartbeat_body(body: dict[str, Any], where: str) -> dict[str, Any]:
    if body:
        _check_fields(body, f"{where}: body", _HEARTBEAT_FIELDS)
    return {}


def _bye_body(body: dict[str, Any], where: str) -> dict[str, Any]:
    if body.keys() != _BYE_FIELDS:
        _check_fields(body, f"{where}: body", _BYE_FIELDS)
    reason = body["reason"]
    if type(reason) is not str:
        raise _fail(f"{where}: body.reason", reason, "must be a string")
    return {"reason": reason}


_BODY_FIELDS = {
    MessageKind.HELLO: _HELLO_FIELDS,
    MessageKind.WELCOME: _WELCOME_FIELDS,
    MessageKind.OBSERVE: _OBSERVE_FIELDS,
    MessageKind.ACT: _ACT_FIELDS,
    MessageKind.HEARTBEAT: _HEARTBEAT_FIELDS,
    MessageKind.BYE: _BYE_FIELDS,
}

_BODY_READERS = {
    MessageKind.HELLO: _hello_body,
    MessageKind.WELCOME: _welcome_body,
    MessageKind.OBSERVE: _observe_body,
    MessageKind.ACT: _act_body,
    MessageKind.HEARTBEAT: _heartbeat_body,
    MessageKind.BYE: _bye_body,
}


# --- item readers (hot path: keep the happy path free of string formatting) -----------------------


def _observation(d: Any, prefix: str, index: int | None = None) -> Observation:
    if type(d) is not dict or d.keys() != _OBSERVATION_FIELDS:
        _check_fields(d, _at(prefix, index), _OBSERVATION_FIELDS)
    robot = d["robot"]
    if type(robot) is not str or not robot:
        raise _fail(f"{_at(prefix, index)}.robot", robot, "must be a non-empty string")
    tick = d["tick"]
    if type(tick) is not int or tick < 0:
        raise _fail(f"{_at(prefix, index)}.tick", tick, "must be an integer >= 0")
    goal = d["goal"]
    if goal is not None:
        if type(goal) is not list or len(goal) != 2:
            raise _fail(f"{_at(prefix, index)}.goal", goal, "must be null or [x, y]")
        goal = (
            _number(goal[0], prefix, "goal[0]", index),
            _number(goal[1], prefix, "goal[1]", index),
        )
    job = d["job"]
    if job is not None and (type(job) is not str or not job):
        raise _fail(f"{_at(prefix, index)}.job", job, "must be null or a non-empty string")
    cap = d["speed_cap"]
    if cap is not None:
        cap = _number(cap, prefix, "speed_cap", index)
        if cap < 0:
            raise _fail(f"{_at(prefix, index)}.speed_cap", cap, "must be null or >= 0")
    neighbours = d["neighbours"]
    if type(neighbours) is not list:
        raise _fail(f"{_at(prefix, index)}.neighbours", neighbours, "must be an array")
    caps = d["speed_caps"]
    if type(caps) is not list:
        raise _fail(f"{_at(prefix, index)}.speed_caps", caps, "must be an array")
    print_end = d["print_end_s"]
    if print_end is not None:
        print_end = _number(print_end, prefix, "print_end_s", index)
    priority = d["priority"]
    if type(priority) is not int:
        raise _fail(f"{_at(prefix, index)}.priority", priority, "must be an integer")
    queued = d["queued"]
    if type(queued) is not int or queued < 0:
        raise _fail(f"{_at(prefix, index)}.queued", queued, "must be an integer >= 0")
    blockers = d["blockers"]
    if type(blockers) is not list:
        raise _fail(f"{_at(prefix, index)}.blockers", blockers, "must be an array of robot ids")
    for b in blockers:
        if type(b) is not str or not b:
            raise _fail(f"{_at(prefix, index)}.blockers", b, "robot ids must be non-empty strings")
    t, x, y, vx, vy = d["t"], d["x"], d["y"], d["vx"], d["vy"]
    # Fast path: all plain floats, and x - x == 0.0 only for finite x (inf and nan give nan).
    if (
        type(t) is not float
        or type(x) is not float
        or type(y) is not float
        or type(vx) is not float
        or type(vy) is not float
        or t - t + x - x + y - y + vx - vx + vy - vy != 0.0
    ):
        t = _number(t, prefix, "t", index)
        x = _number(x, prefix, "x", index)
        y = _number(y, prefix, "y", index)
        vx = _number(vx, prefix, "vx", index)
        vy = _number(vy, prefix, "vy", index)
    return Observation(
        robot,
        tick,
        t,
        x,
        y,
        vx,
        vy,
        goal,
        job,
        cap,
        _neighbours(neighbours, prefix, index) if neighbours else (),
        _cap_pieces(caps, f"{_at(prefix, index)}.speed_caps") if caps else (),
        print_end,
        priority,
        tuple(blockers),
        queued,
    )


def _cap_pieces(caps: list, where: str) -> tuple[tuple[float, float, float], ...]:
    out = []
    previous = -float("inf")
    for i, piece in enumerate(caps):
        if type(piece) is not list or len(piece) != 3:
            raise _fail(f"{where}[{i}]", piece, "must be [start_s, end_s, cap]")
        a, b, c = (_number(v, where, f"[{i}]") for v in piece)
        if not b > a or c < 0 or a < previous:
            raise _fail(
                f"{where}[{i}]",
                piece,
                "pieces must be sorted, non-overlapping, end > start, cap >= 0",
            )
        previous = b
        out.append((a, b, c))
    return tuple(out)


_NEIGHBOUR_RULE = "must be [robot, x, y, vx, vy, radius, priority, plan]"


def _neighbours(items: list, prefix: str, index: int | None) -> tuple[Neighbour, ...]:
    # The scalars one neighbour at a time, then every plan sample of the observation in one
    # batch: with eight neighbours of ten samples each, the samples are most of an OBSERVE.
    rows = []
    plans = []
    for j, n in enumerate(items):
        if type(n) is not list or len(n) != 8:
            raise _fail(f"{_at(prefix, index)}.neighbours[{j}]", n, _NEIGHBOUR_RULE)
        robot, x, y, vx, vy, radius, priority, plan = n
        # Fast path: plain floats, finite (x - x == 0.0 only for finite x), radius > 0.
        if (
            type(robot) is not str
            or not robot
            or type(x) is not float
            or type(y) is not float
            or type(vx) is not float
            or type(vy) is not float
            or type(radius) is not float
            or x - x + y - y + vx - vx + vy - vy + radius - radius != 0.0
            or not radius > 0.0
            or type(priority) is not int
            or type(plan) is not list
        ):
            robot, x, y, vx, vy, radius, priority, plan = _neighbour(n, prefix, index, j)
        rows.append((robot, x, y, vx, vy, radius, priority))
        plans.append(plan)
    if _plain_samples(list(chain.from_iterable(plans))):
        return tuple(
            [
                Neighbour(r, x, y, vx, vy, rad, pr, tuple(map(tuple, plan)) if plan else ())
                for (r, x, y, vx, vy, rad, pr), plan in zip(rows, plans, strict=True)
            ]
        )
    # Exact path: some sample is malformed (say which) or holds ints (convert them).
    return tuple(
        [
            Neighbour(*row, _samples(plan, f"{_at(prefix, index)}.neighbours[{j}].plan"))
            for j, (row, plan) in enumerate(zip(rows, plans, strict=True))
        ]
    )


def _neighbour(n: list, prefix: str, index: int | None, j: int) -> list:
    """The fields of one wire neighbour that failed the fast check: converted, or an error."""
    robot, x, y, vx, vy, radius, priority, plan = n
    if type(robot) is not str or not robot:
        raise _fail(f"{_at(prefix, index)}.neighbours[{j}]", n, _NEIGHBOUR_RULE)
    name = f"neighbours[{j}]"
    x = _number(x, prefix, name, index)
    y = _number(y, prefix, name, index)
    vx = _number(vx, prefix, name, index)
    vy = _number(vy, prefix, name, index)
    radius = _number(radius, prefix, name, index)
    if not radius > 0.0:
        raise _fail(f"{_at(prefix, index)}.neighbours[{j}].radius", radius, "must be > 0")
    if type(priority) is not int:
        raise _fail(
            f"{_at(prefix, index)}.neighbours[{j}].priority", priority, "must be an integer"
        )
    if type(plan) is not list:
        raise _fail(
            f"{_at(prefix, index)}.neighbours[{j}].plan", plan, "must be an array of [t, x, y]"
        )
    return [robot, x, y, vx, vy, radius, priority, plan]


def _plain_samples(samples: list) -> bool:
    """Whether every item is a list of three floats, all finite (a few C-level passes instead
    of a Python loop per sample)."""
    if not samples:
        return True
    if set(map(type, samples)) != _LIST_TYPE or set(map(len, samples)) != _THREE:
        return False
    flat = list(chain.from_iterable(samples))
    if set(map(type, flat)) != _FLOAT_TYPE:
        return False
    # inf or nan if any value is; a sum that merely overflows sends valid samples down the
    # exact path, which accepts them.
    total = sum(flat)
    return total - total == 0.0


def _samples(plan: list, where: str) -> tuple[tuple[float, float, float], ...]:
    """A JSON array of ``[t, x, y]`` as a tuple of float triples."""
    if _plain_samples(plan):
        return tuple(map(tuple, plan))
    return tuple([_triple(p, where, i) for i, p in enumerate(plan)])


_LIST_TYPE = {list}
_FLOAT_TYPE = {float}
_THREE = {3}


def _announcement(a: Any, where: str) -> Announcement:
    if type(a) is not list or len(a) != 6:
        raise _fail(where, a, "must be [job, x, y, print_s, released_s, due_s]")
    job, x, y, print_s, released_s, due_s = a
    if type(job) is not str or not job:
        raise _fail(f"{where}[0]", job, "the job id must be a non-empty string")
    x = _number(x, where, "[1]")
    y = _number(y, where, "[2]")
    print_s = _number(print_s, where, "[3]")
    if print_s < 0:
        raise _fail(f"{where}[3]", print_s, "print_s must be >= 0")
    released_s = _number(released_s, where, "[4]")
    if due_s is not None:
        due_s = _number(due_s, where, "[5]")
    return Announcement(job, x, y, print_s, released_s, due_s)


def _bid(b: Any, where: str) -> Bid:
    if type(b) is not list or len(b) != 3:
        raise _fail(where, b, "must be [job, robot, estimate_s]")
    job, robot, estimate = b
    if type(job) is not str or not job:
        raise _fail(f"{where}[0]", job, "the job id must be a non-empty string")
    if type(robot) is not str or not robot:
        raise _fail(f"{where}[1]", robot, "the robot id must be a non-empty string")
    estimate = _number(estimate, where, "[2]")
    if estimate < 0:
        raise _fail(f"{where}[2]", estimate, "estimate_s must be >= 0")
    return Bid(job, robot, estimate)


def _handback(h: Any, where: str) -> Handback:
    if type(h) is not list or len(h) != 3:
        raise _fail(where, h, "must be [robot, job, reason]")
    robot, job, reason = h
    if type(robot) is not str or not robot:
        raise _fail(f"{where}[0]", robot, "the robot id must be a non-empty string")
    if type(job) is not str or not job:
        raise _fail(f"{where}[1]", job, "the job id must be a non-empty string")
    if type(reason) is not str:
        raise _fail(f"{where}[2]", reason, "the reason must be a string")
    return Handback(robot, job, reason)


def _command(d: Any, prefix: str, key: str | None = None) -> Command:
    if type(d) is not dict or d.keys() != _COMMAND_FIELDS:
        _check_fields(d, _key(prefix, key), _COMMAND_FIELDS)
    status_value = d["status"]
    status = _STATUS.get(status_value) if type(status_value) is str else None
    if status is None:
        raise _fail(f"{_key(prefix, key)}.status", status_value, f"must be one of {_STATUS_NAMES}")
    plan = d["plan"]
    if type(plan) is not list:
        raise _fail(f"{_key(prefix, key)}.plan", plan, "must be an array of [t, x, y]")
    ax, ay = d["ax"], d["ay"]
    if type(ax) is not float or type(ay) is not float or ax - ax + ay - ay != 0.0:
        ax = _number(ax, _key(prefix, key), "ax")
        ay = _number(ay, _key(prefix, key), "ay")
    solve = d["solve"]
    if solve is not None:
        solve = _solve(solve, f"{_key(prefix, key)}.solve")
    if plan:
        where = f"{_key(prefix, key)}.plan"
        plan = tuple([_triple(p, where, i) for i, p in enumerate(plan)])
        return Command(ax, ay, status, plan, solve)
    return Command(ax, ay, status, (), solve)


def _solve(s: Any, where: str) -> SolveReport:
    if type(s) is not list or len(s) != 3:
        raise _fail(where, s, "must be null or [outcome, solver_s, step_s]")
    outcome = _OUTCOME.get(s[0]) if type(s[0]) is str else None
    if outcome is None:
        raise _fail(f"{where}[0]", s[0], f"must be one of {_OUTCOME_NAMES}")
    solver_s, step_s = _number(s[1], where, "[1]"), _number(s[2], where, "[2]")
    if solver_s < 0 or step_s < 0:
        raise _fail(where, s, "times must be >= 0")
    return SolveReport(outcome, solver_s, step_s)


def _triple(p: Any, where: str, i: int) -> tuple[float, float, float]:
    if (type(p) is not list and type(p) is not tuple) or len(p) != 3:
        raise _fail(f"{where}[{i}]", p, "must be a [t, x, y] triple")
    name = f"[{i}]"
    return (_number(p[0], where, name), _number(p[1], where, name), _number(p[2], where, name))


def _number(v: Any, prefix: str, name: str, index: int | None = None) -> float:
    """`v` as a finite float; ints are accepted, bools are not."""
    kind = type(v)
    if kind is float:
        if v - v == 0.0:  # False for inf and nan
            return v
    elif kind is int:
        try:
            return float(v)
        except OverflowError:
            pass
    else:
        # numpy scalars and other float subclasses (only reachable from command_to_wire)
        try:
            if isinstance(v, float) or (hasattr(v, "__float__") and not isinstance(v, bool | str)):
                f = float(v)
                if f - f == 0.0:
                    return f
        except (TypeError, ValueError, OverflowError):
            pass
    sep = "" if name.startswith("[") else "."
    raise _fail(f"{_at(prefix, index)}{sep}{name}", v, "must be a finite number")


def _nonempty(v: Any, prefix: str, name: str) -> None:
    if type(v) is not str or not v:
        raise _fail(f"{prefix}.{name}", v, "must be a non-empty string")


def _robot_list(robots: Any, where: str) -> list[str]:
    if type(robots) is not list:
        raise _fail(where, robots, "must be an array of robot ids")
    for r in robots:
        if type(r) is not str or not r:
            raise _fail(where, r, "robot ids must be non-empty strings")
    if len(set(robots)) != len(robots):
        dupes = sorted({r for r in robots if robots.count(r) > 1})
        raise _fail(where, dupes, "robot ids must be unique")
    return robots


# --- error helpers -------------------------------------------------------------------------------

_QUOTE_MAX = 120


def _quote(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= _QUOTE_MAX else text[: _QUOTE_MAX - 3] + "..."


def _fail(where: str, value: Any, rule: str) -> MessageError:
    return MessageError(f"{where} = {_quote(value)}: {rule}")


def _at(prefix: str, index: int | None) -> str:
    return prefix if index is None else f"{prefix}[{index}]"


def _key(prefix: str, key: str | None) -> str:
    return prefix if key is None else f"{prefix}[{key!r}]"


def _check_fields(d: Any, where: str, allowed: frozenset[str]) -> None:
    """Raise unless `d` is a JSON object with exactly the fields `allowed`."""
    if type(d) is not dict:
        raise _fail(where, d, "must be a JSON object")
    missing = sorted(allowed - d.keys())
    extra = sorted(k for k in d if k not in allowed)
    names = ", ".join(sorted(allowed))
    if missing:
        raise MessageError(f"{where}: missing field(s) {', '.join(missing)} (fields: {names})")
    if extra:
        raise MessageError(
            f"{where}: unexpected field(s) {_quote(extra)}; only {names} are allowed"
        )


def _find_unencodable(value: Any, where: str) -> str | None:
    """Path of the first value JSON cannot carry, for encode's error message (slow path)."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            found = _find_unencodable(v, f"{where}.{k}")
            if found:
                return found
        return None
    if isinstance(value, Sequence) and not isinstance(value, str | bytes):
        for i, v in enumerate(value):
            found = _find_unencodable(v, f"{where}[{i}]")
            if found:
                return found
        return None
    if value is None or isinstance(value, bool | str | int):
        return None
    if isinstance(value, float):
        return None if value - value == 0.0 else f"{where} = {value!r}"
    return f"{where} = {_quote(value)} ({type(value).__name__})"
