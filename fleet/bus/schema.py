"""The bus's wire schema: what the engine and the robot agents say to each other, version 5.

Every message is one ZeroMQ frame holding one compact UTF-8 JSON object, the *envelope*::

    {"version": 5, "kind": "observe", "sender": "exchange", "tick": 42, "body": {...}}

`kind` says what the body holds (see `MessageKind`); `tick` is the engine's control tick the
message belongs to (0 for HELLO). Observations and commands travel as JSON objects whose fields are
exactly those of `fleet.plugins.Observation` and `fleet.plugins.Command`; small fixed tuples travel
as arrays: a goal is ``[x, y]``, a neighbour ``[robot, x, y, vx, vy, radius, priority, plan, v_max,
a_max, period]``, a plan sample ``[t, x, y]``, a speed-cap piece ``[start_s, end_s, cap]``, a solve
report ``[outcome, solver_s, step_s]``, an announcement ``[job, x, y, print_s, released_s,
due_s]``, a bid ``[job, robot, estimate_s]`` and a handback ``[robot, job, reason]``. Every field
is always present (``null`` where the dataclass holds None), so a message either matches the schema
exactly or is rejected. Numbers are finite; ids (robots, jobs, senders) are non-empty strings;
ticks, ``queued``, cap values, ``print_s``, bid estimates and solve times are >= 0, a neighbour's
radius and its limits (``null`` where not known) > 0, speed-cap pieces sorted and non-overlapping,
and a HELLO's (WELCOME's) robots unique. Sizes are bounded: a frame by `MAX_MESSAGE_BYTES` (or the
``max_bytes`` given to `decode`), arrays and strings by the other ``MAX_*`` constants below.

History: version 2 added ``speed_caps`` and ``solve``, version 3 ``print_end_s``; version 4
(contract net and liveness) added the observation's ``priority``, ``blockers`` and ``queued``, the
neighbour's radius, priority and plan, OBSERVE's ``announcements``, ACT's ``bids`` and
``handbacks``, HELLO's ``scenario`` and the HEARTBEAT kind; version 5 the neighbour's ``v_max``,
``a_max`` and ``period`` (a fleet may mix robots, and how far a neighbour can stray unseen depends
on its own limits: `fleet.plugins.robot.neighbour_stray`).

The schema is written once, as msgspec types (the ``_Wire`` structs and the array aliases
below), and msgspec checks it in C: `decode` parses and validates a frame in one pass and
returns OBSERVE and ACT bodies converted to `fleet.plugins` objects (`Observation`,
`Announcement`, `Command`, `Bid`, `Handback`); `encode` converts the body to the same types
before writing it, so nothing goes out that breaks them (msgspec alone would write NaN as
``null``). The few rules a type cannot state (radius > 0, sorted cap pieces, unique robots)
`decode` checks while converting.

A rejected message raises `MessageError` saying the message's kind and sender, the field's
full path and the bad value quoted, e.g. ``OBSERVE message from 'exchange':
body.observations[3].vx = 'fast': must be a finite number``. msgspec names only the path, so
the value is found by walking it through the frame parsed again without types, which happens
only once a frame has failed.
"""

from __future__ import annotations

import contextlib
import enum
import functools
import gc
import re
import reprlib
import sys
from collections import Counter
from collections.abc import Callable, Collection, Iterator, Mapping
from dataclasses import dataclass, fields
from numbers import Real
from types import NoneType, UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import msgspec
from msgspec import Meta, Struct

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
    "MAX_MESSAGE_BYTES",
    "MAX_ROBOTS",
    "MAX_ITEMS",
    "MAX_BIDS",
    "MAX_ID_CHARS",
    "MAX_TEXT_CHARS",
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

SCHEMA_VERSION = 5
"""The version this build writes and the only one it reads."""

# Bounds on what one message may hold, so that no message costs more than a few tens of
# milliseconds to read or to reject (docs/fleet.md, "Hostile input", has the measurements).
MAX_MESSAGE_BYTES = 2 * 1024 * 1024
"""Default largest frame (bytes) `decode` reads and the bus's sockets take in (ZeroMQ's
``MAXMSGSIZE``); a scenario's ``[bus] max_message_bytes`` changes it. One agent hosting 80 MPC
robots sends ACTs of about 8 kB and is sent OBSERVEs of about 44 kB."""
MAX_ROBOTS = 10_000
"""Most robots a HELLO or WELCOME names, and most observations or commands in one message."""
MAX_ITEMS = 10_000
"""Most items in any other array of a message (a plan's samples, an observation's neighbours,
speed-cap pieces and blockers, announcements, handbacks), except bids."""
MAX_BIDS = 100_000
"""Most bids in one ACT (each robot of the agent may bid for each announced job)."""
MAX_ID_CHARS = 1024
"""Longest id (robot, job, sender), in characters."""
MAX_TEXT_CHARS = 4096
"""Longest free text (a BYE's or handback's reason, a rejection's, a scenario fingerprint)."""


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


# --- the wire types ------------------------------------------------------------------------------
#
# Besides constraints, a type's Meta says how errors read: `title` names the value where the
# path does not (an array item reported by index: "the job id must be ..."), `description`
# says what the value must be where the type alone would say it badly, and extra["at"] where
# errors inside an array are reported: at the array itself (""), under a name (".plan"), or,
# without it, at the item's index.

_MAX = sys.float_info.max
# JSON cannot carry NaN or infinities (msgspec would write null): both bounds exclude them,
# which matters when encode converts Python values; parsed JSON numbers are finite anyway.
_Finite = Annotated[float, Meta(ge=-_MAX, le=_MAX)]
_NonNegative = Annotated[float, Meta(ge=0.0, le=_MAX)]
_Count = Annotated[int, Meta(ge=0)]
_Name = Annotated[str, Meta(min_length=1, max_length=MAX_ID_CHARS)]
_RobotId = Annotated[str, Meta(min_length=1, max_length=MAX_ID_CHARS, title="the robot id")]
_JobId = Annotated[str, Meta(min_length=1, max_length=MAX_ID_CHARS, title="the job id")]
_Text = Annotated[str, Meta(max_length=MAX_TEXT_CHARS)]
_ListedId = Annotated[
    str,
    Meta(min_length=1, max_length=MAX_ID_CHARS, title="robot ids", description="non-empty strings"),
]
_RobotIds = Annotated[
    list[_ListedId],
    Meta(description="an array of robot ids", max_length=MAX_ROBOTS, extra={"at": ""}),
]

_Sample = Annotated[
    tuple[_Finite, _Finite, _Finite], Meta(description="a [t, x, y] triple", extra={"at": ""})
]
_Plan = Annotated[
    tuple[_Sample, ...], Meta(description="an array of [t, x, y]", max_length=MAX_ITEMS)
]
_Goal = Annotated[tuple[_Finite, _Finite], Meta(description="[x, y]")]
_CapPiece = Annotated[
    tuple[_Finite, _Finite, _Finite],
    Meta(description="[start_s, end_s, cap]", extra={"at": ""}),
]
# A neighbour's numbers are reported at the neighbour, its priority and plan by name (the
# radius > 0 and limits > 0 rules are checked in _observation, so that the error names them).
_Neighbour = Annotated[
    tuple[
        _RobotId,
        _Finite,
        _Finite,
        _Finite,
        _Finite,
        _Finite,
        int,
        _Plan,
        _Finite | None,
        _Finite | None,
        _Finite | None,
    ],
    Meta(
        description="[robot, x, y, vx, vy, radius, priority, plan, v_max, a_max, period]",
        extra={"at": ("", "", "", "", "", "", ".priority", ".plan", ".v_max", ".a_max", ".period")},
    ),
]
_Announcement = Annotated[
    tuple[
        _JobId,
        _Finite,
        _Finite,
        Annotated[float, Meta(ge=0.0, le=_MAX, title="print_s")],
        _Finite,
        _Finite | None,
    ],
    Meta(description="[job, x, y, print_s, released_s, due_s]"),
]
_Bid = Annotated[
    tuple[_JobId, _RobotId, Annotated[float, Meta(ge=0.0, le=_MAX, title="estimate_s")]],
    Meta(description="[job, robot, estimate_s]"),
]
_Handback = Annotated[
    tuple[_RobotId, _JobId, Annotated[str, Meta(max_length=MAX_TEXT_CHARS, title="the reason")]],
    Meta(description="[robot, job, reason]"),
]
_Solve = Annotated[
    tuple[SolverOutcome, _NonNegative, _NonNegative],
    Meta(description="[outcome, solver_s, step_s]"),
]


class _Wire(Struct, forbid_unknown_fields=True, gc=False):
    """A JSON object with exactly these fields (gc=False: parsed values hold no cycles)."""


class _Observation(_Wire):
    robot: _Name
    tick: _Count
    t: _Finite
    x: _Finite
    y: _Finite
    vx: _Finite
    vy: _Finite
    goal: _Goal | None
    job: _Name | None
    speed_cap: _NonNegative | None
    neighbours: Annotated[tuple[_Neighbour, ...], Meta(max_length=MAX_ITEMS)]
    speed_caps: Annotated[tuple[_CapPiece, ...], Meta(max_length=MAX_ITEMS)]
    print_end_s: _Finite | None
    priority: int
    blockers: Annotated[
        tuple[_ListedId, ...],
        Meta(description="an array of robot ids", max_length=MAX_ITEMS, extra={"at": ""}),
    ]
    queued: _Count


class _Command(_Wire):
    ax: _Finite
    ay: _Finite
    status: ControlStatus
    plan: _Plan
    solve: _Solve | None


class _HelloBody(_Wire):
    robots: _RobotIds
    scenario: _Text


class _WelcomeBody(_Wire):
    accepted: _RobotIds
    rejected: Annotated[dict[_RobotId, _Text], Meta(max_length=MAX_ROBOTS)]


class _ObserveBody(_Wire):
    t: _Finite
    observations: Annotated[list[_Observation], Meta(max_length=MAX_ROBOTS)]
    announcements: Annotated[list[_Announcement], Meta(max_length=MAX_ITEMS)]


class _ActBody(_Wire):
    commands: Annotated[dict[_RobotId, _Command], Meta(max_length=MAX_ROBOTS)]
    bids: Annotated[list[_Bid], Meta(max_length=MAX_BIDS)]
    handbacks: Annotated[list[_Handback], Meta(max_length=MAX_ITEMS)]


class _HeartbeatBody(_Wire):
    pass


class _ByeBody(_Wire):
    reason: _Text


class _Envelope(_Wire, tag_field="kind"):
    version: Literal[5]  # SCHEMA_VERSION
    sender: _Name
    tick: _Count


class _Hello(_Envelope, tag=MessageKind.HELLO.value):
    body: _HelloBody


class _Welcome(_Envelope, tag=MessageKind.WELCOME.value):
    body: _WelcomeBody


class _Observe(_Envelope, tag=MessageKind.OBSERVE.value):
    body: _ObserveBody


class _Act(_Envelope, tag=MessageKind.ACT.value):
    body: _ActBody


class _Heartbeat(_Envelope, tag=MessageKind.HEARTBEAT.value):
    body: _HeartbeatBody


class _Bye(_Envelope, tag=MessageKind.BYE.value):
    body: _ByeBody


_ENVELOPES: dict[MessageKind, type[_Envelope]] = {
    MessageKind.HELLO: _Hello,
    MessageKind.WELCOME: _Welcome,
    MessageKind.OBSERVE: _Observe,
    MessageKind.ACT: _Act,
    MessageKind.HEARTBEAT: _Heartbeat,
    MessageKind.BYE: _Bye,
}
_KIND_OF = {cls: kind for kind, cls in _ENVELOPES.items()}
_BODIES: dict[MessageKind, type[_Wire]] = {
    MessageKind.HELLO: _HelloBody,
    MessageKind.WELCOME: _WelcomeBody,
    MessageKind.OBSERVE: _ObserveBody,
    MessageKind.ACT: _ActBody,
    MessageKind.HEARTBEAT: _HeartbeatBody,
    MessageKind.BYE: _ByeBody,
}
_BODY_FIELDS = {
    kind: frozenset(f.name for f in msgspec.structs.fields(cls)) for kind, cls in _BODIES.items()
}

_DECODER = msgspec.json.Decoder(_Hello | _Welcome | _Observe | _Act | _Heartbeat | _Bye)
# Only for frames that failed, untyped, to find and quote the bad value; the float hook (out
# of range numbers become inf) costs twice the time, so only frames that need it get it.
_PLAIN_DECODER = msgspec.json.Decoder()
_RAW_DECODER = msgspec.json.Decoder(float_hook=float)
_ENCODER = msgspec.json.Encoder()


# --- encoding ------------------------------------------------------------------------------------


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
        mapping of robot ids to commands, a command, bid or handback is invalid, or any value
        breaks the schema (NaN, infinity, a wrong type, a non-JSON type); the message names
        where.
    """
    if not isinstance(kind, MessageKind):
        raise MessageError(f"cannot encode: kind = {_quote(kind)}: must be a MessageKind")
    if type(sender) is not str or not sender:
        raise MessageError(f"cannot encode: sender = {_quote(sender)}: must be a non-empty string")
    if type(tick) is not int or tick < 0:
        raise MessageError(f"cannot encode: tick = {_quote(tick)}: must be an integer >= 0")
    where = f"cannot encode {kind.name} from {sender!r} at tick {tick}"
    if not isinstance(body, Mapping):
        raise _fail(f"{where}: body", body, "must be a mapping")
    if body.keys() != _BODY_FIELDS[kind]:
        raise _fields_error(dict(body), f"{where}: body", _BODY_FIELDS[kind])
    if kind is MessageKind.OBSERVE:
        body = {
            "t": body["t"],
            "observations": _observations_to_wire(
                body["observations"], f"{where}: body.observations"
            ),
            "announcements": _items_to_wire(
                body["announcements"],
                Announcement,
                announcement_to_wire,
                f"{where}: body.announcements",
            ),
        }
    elif kind is MessageKind.ACT:
        body = {
            "commands": _commands_to_wire(body["commands"], f"{where}: body.commands"),
            "bids": _items_to_wire(body["bids"], Bid, bid_to_wire, f"{where}: body.bids"),
            "handbacks": _items_to_wire(
                body["handbacks"], Handback, handback_to_wire, f"{where}: body.handbacks"
            ),
        }
    envelope = {
        "version": SCHEMA_VERSION,
        "kind": kind.value,
        "sender": sender,
        "tick": tick,
        "body": _checked(body, _BODIES[kind], where, "body"),
    }
    try:
        return _ENCODER.encode(envelope)
    except UnicodeEncodeError as exc:  # what the schema lets through but UTF-8 cannot carry
        found = _not_unicode({**envelope, "body": body}, "")
        raise MessageError(f"{where}: {found.lstrip('.') or 'a string'}: {exc.reason}") from None


def _not_unicode(value: Any, path: str) -> str:
    """Where in `value` a string (or key) holds a lone surrogate; "" if nowhere."""
    if isinstance(value, str):
        return "" if value.isascii() or _encodes(value) else path
    if isinstance(value, Mapping):
        for k, v in value.items():
            found = _not_unicode(k, f"{path} key {k!r}") or _not_unicode(v, f"{path}.{k}")
            if found:
                return found
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            found = _not_unicode(v, f"{path}[{i}]")
            if found:
                return found
    return ""


def _encodes(text: str) -> bool:
    try:
        text.encode()
    except UnicodeEncodeError:
        return False
    return True


def _observations_to_wire(items: Any, where: str) -> list[dict[str, Any]]:
    """`items` (observations or their wire dicts, at `where`) as wire dicts."""
    if not isinstance(items, list | tuple):
        raise _fail(where, items, "must be a list of observations")
    wire = []
    for i, o in enumerate(items):
        if isinstance(o, Observation):
            try:
                wire.append(observation_to_wire(o))
            except (TypeError, ValueError, OverflowError) as exc:
                raise MessageError(f"{where}[{i}]: {exc}") from None
        elif type(o) is dict:
            wire.append(o)
        else:
            raise _fail(
                f"{where}[{i}]",
                o,
                "must be a fleet.plugins.Observation or its wire dict",
            )
    return wire


def _commands_to_wire(items: Any, where: str) -> dict[Any, Any]:
    """`items` (robot ids to commands or their wire dicts, at `where`) to wire dicts."""
    if not isinstance(items, Mapping):
        raise _fail(where, items, "must be a mapping {robot: command}")
    wire = {}
    for robot, c in items.items():
        if isinstance(c, Command):
            try:
                wire[robot] = command_to_wire(c)
            except MessageError as exc:
                raise MessageError(f"cannot encode ACT for robot {robot!r}: {exc}") from None
        elif type(c) is dict:
            wire[robot] = c
        else:
            raise _fail(
                f"{where}[{robot!r}]",
                c,
                "must be a fleet.plugins.Command or its wire dict",
            )
    return wire


def _items_to_wire(items: Any, cls: type, to_wire: Any, where: str) -> list[Any]:
    """`items` (objects of `cls` or their wire lists, at `where`) as wire lists."""
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
    samples per tick would be most of the encoding time. `encode` checks the whole body
    against the schema, so a sample the bus cannot carry (NaN, a numpy array) still makes it
    fail, naming where.
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
                None if n.v_max is None else float(n.v_max),
                None if n.a_max is None else float(n.a_max),
                None if n.period is None else float(n.period),
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

    Numbers of other types (numpy's, ints) become plain floats.

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
    solve = c.solve
    if solve is not None:
        if not isinstance(solve, SolveReport) or not isinstance(solve.outcome, SolverOutcome):
            raise _fail("command.solve", solve, "must be None or a SolveReport")
        solve = [solve.outcome.value, _plain(solve.solver_s), _plain(solve.step_s)]
    plan = c.plan
    if isinstance(plan, list | tuple) and not _SAMPLE_TYPES.issuperset(map(type, plan)):
        # Exactly tuples or lists, as documented for plugins: msgspec would take a namedtuple.
        i, p = next((i, p) for i, p in enumerate(plan) if type(p) not in _SAMPLE_TYPES)
        raise _fail(f"command.plan[{i}]", p, "must be a [t, x, y] triple")
    wire = {
        "ax": _plain(c.ax),
        "ay": _plain(c.ay),
        "status": status.value,
        "plan": plan if plan else (),
        "solve": solve,
    }
    try:
        msgspec.convert(wire, _Command)
    except msgspec.ValidationError:
        # Most plans hold plain floats already; only a failing one is copied with its numbers
        # made plain, then checked again (and reported if still wrong).
        if isinstance(plan, list | tuple):
            wire["plan"] = [tuple(map(_plain, p)) for p in plan]
        _checked(wire, _Command, "", "command")
    return wire


def announcement_to_wire(a: Announcement) -> list[Any]:
    """The JSON form of an announcement, ``[job, x, y, print_s, released_s, due_s]``.

    Raises
    ------
    MessageError
        If the job id is not a non-empty string, a number is not finite or `print_s` < 0.
    """
    wire = [
        a.job,
        _plain(a.x),
        _plain(a.y),
        _plain(a.print_s),
        _plain(a.released_s),
        _plain(a.due_s),
    ]
    _checked(wire, _ANNOUNCEMENT_ATTRIBUTES, "", "announcement")
    return wire


def bid_to_wire(b: Bid) -> list[Any]:
    """The JSON form of a bid, ``[job, robot, estimate_s]``, checked (bids come from plugins).

    Raises
    ------
    MessageError
        If the job or robot id is not a non-empty string, or the estimate is not a finite
        number >= 0.
    """
    wire = [b.job, b.robot, _plain(b.estimate_s)]
    _checked(wire, _BID_ATTRIBUTES, "", "bid")
    return wire


def handback_to_wire(h: Handback) -> list[Any]:
    """The JSON form of a handback, ``[robot, job, reason]``.

    Raises
    ------
    MessageError
        If the robot or job id is not a non-empty string, or the reason is not a string.
    """
    wire = [h.robot, h.job, h.reason]
    _checked(wire, _HANDBACK_ATTRIBUTES, "", "handback")
    return wire


def _plain(v: Any) -> Any:
    """`v` as a plain float if it is a real number of another type (numpy's, an int, not a
    bool); anything else as it is, for the schema check to reject with the value quoted."""
    if type(v) is float or isinstance(v, bool) or not isinstance(v, Real):
        return v
    try:
        return float(v)
    except (OverflowError, ValueError):
        return v


def _by_attribute(array: Any, cls: type) -> Any:
    """`array`, the wire type of a `cls` object, with errors reported under `cls`'s attribute
    names: what the ``*_to_wire`` functions check is the object, not a message."""
    base, meta = get_args(array)
    names = tuple(f".{f.name}" for f in fields(cls))
    return Annotated[base, Meta(description=meta.description, extra={"at": names})]


_ANNOUNCEMENT_ATTRIBUTES = _by_attribute(_Announcement, Announcement)
_BID_ATTRIBUTES = _by_attribute(_Bid, Bid)
_HANDBACK_ATTRIBUTES = _by_attribute(_Handback, Handback)
_STATUS_NAMES = ", ".join(repr(s.value) for s in ControlStatus)
_SAMPLE_TYPES = frozenset((tuple, list))


# --- decoding ------------------------------------------------------------------------------------


def decode(
    raw: bytes,
    expect: Collection[MessageKind] | None = None,
    *,
    max_bytes: int = MAX_MESSAGE_BYTES,
) -> Message:
    """Parse and validate one message.

    Every check is linear in the frame's size, and the frame's size is bounded, so that no
    message costs more than a stated time to read or reject (docs/fleet.md, "Hostile input").

    Parameters
    ----------
    raw:
        The frame as received.
    expect:
        Kinds the caller is ready for; any other kind is rejected. None accepts every kind.
    max_bytes:
        Longest frame read; a longer one is rejected unread.

    Returns
    -------
    Message
        The message, with OBSERVE and ACT bodies converted to `fleet.plugins` objects.

    Raises
    ------
    MessageError
        If the frame is longer than `max_bytes`, not UTF-8 JSON, of another schema version,
        of an unknown or unexpected kind, nested deeper or holding more than the schema
        allows, or any field is missing, extra, of the wrong type or not finite. The message
        says which field and quotes the bad value.
    """
    if not isinstance(raw, bytes):
        raise _fail("bus message", raw, "must be bytes")
    if len(raw) > max_bytes:
        raise MessageError(
            f"bus message of {len(raw):,} bytes: longer than the bus's limit of {max_bytes:,}"
            " bytes (max_message_bytes); not read"
        )
    with _collector_paused():
        try:
            envelope = _DECODER.decode(raw)
        except (msgspec.MsgspecError, UnicodeDecodeError) as exc:
            raise _rejection(raw, exc) from None
        kind = _KIND_OF[type(envelope)]
        if expect is not None and kind not in expect:
            allowed = ", ".join(sorted(k.name for k in expect)) or "nothing"
            raise MessageError(
                f"{_label(envelope)}: unexpected kind {kind.name}; expected {allowed}"
            )
        body = _READERS[kind](envelope)
    return Message(kind, envelope.sender, envelope.tick, body, SCHEMA_VERSION)


def observation_from_wire(d: Any) -> Observation:
    """Validate the JSON form of an observation and build it.

    Raises
    ------
    MessageError
        Naming the field and quoting the value that is missing, extra, mistyped or not finite.
    """
    return _observation(_checked(d, _Observation, "", "observation"), "observation")


def command_from_wire(d: Any) -> Command:
    """Validate the JSON form of a command and build it.

    Raises
    ------
    MessageError
        Naming the field and quoting the value that is missing, extra, mistyped or not finite.
    """
    return _command(_checked(d, _Command, "", "command"))


def _label(envelope: _Envelope) -> str:
    return f"{_KIND_OF[type(envelope)].name} message from {_quote(envelope.sender)}"


# --- body readers: the wire types to fleet.plugins objects, and the rules types cannot state ---


def _hello(m: _Hello) -> dict[str, Any]:
    return {"robots": _unique(m.body.robots, m, "robots"), "scenario": m.body.scenario}


def _welcome(m: _Welcome) -> dict[str, Any]:
    return {"accepted": _unique(m.body.accepted, m, "accepted"), "rejected": m.body.rejected}


def _observe(m: _Observe) -> dict[str, Any]:
    body = m.body
    return {
        "t": body.t,
        "observations": [_observation(o, m, i) for i, o in enumerate(body.observations)],
        "announcements": [Announcement(*a) for a in body.announcements],
    }


def _act(m: _Act) -> dict[str, Any]:
    body = m.body
    return {
        "commands": {robot: _command(c) for robot, c in body.commands.items()},
        "bids": [Bid(*b) for b in body.bids],
        "handbacks": [Handback(*h) for h in body.handbacks],
    }


def _heartbeat(m: _Heartbeat) -> dict[str, Any]:
    return {}


def _bye(m: _Bye) -> dict[str, Any]:
    return {"reason": m.body.reason}


_READERS: dict[MessageKind, Callable[[Any], dict[str, Any]]] = {
    MessageKind.HELLO: _hello,
    MessageKind.WELCOME: _welcome,
    MessageKind.OBSERVE: _observe,
    MessageKind.ACT: _act,
    MessageKind.HEARTBEAT: _heartbeat,
    MessageKind.BYE: _bye,
}


def _observation(o: _Observation, m: _Envelope | str, index: int = 0) -> Observation:
    """`o` as an `Observation`; `m` (its message, or a name for it) and `index` say where it
    is for errors."""
    neighbours = tuple([Neighbour(*n) for n in o.neighbours]) if o.neighbours else ()
    for j, n in enumerate(neighbours):
        if not n.radius > 0.0:
            raise _fail(f"{_where(m, index)}.neighbours[{j}].radius", n.radius, "must be > 0")
        for name in ("v_max", "a_max", "period"):
            value = getattr(n, name)
            if value is not None and not value > 0.0:
                raise _fail(
                    f"{_where(m, index)}.neighbours[{j}].{name}", value, "must be > 0 or null"
                )
    caps = o.speed_caps
    previous = -_MAX
    for k, (start, end, cap) in enumerate(caps):
        if not end > start or cap < 0.0 or start < previous:
            raise _fail(
                f"{_where(m, index)}.speed_caps[{k}]",
                [start, end, cap],
                "pieces must be sorted, non-overlapping, end > start, cap >= 0",
            )
        previous = end
    return Observation(
        o.robot,
        o.tick,
        o.t,
        o.x,
        o.y,
        o.vx,
        o.vy,
        o.goal,
        o.job,
        o.speed_cap,
        neighbours,
        caps,
        o.print_end_s,
        o.priority,
        o.blockers,
        o.queued,
    )


def _where(m: _Envelope | str, index: int) -> str:
    return m if isinstance(m, str) else f"{_label(m)}: body.observations[{index}]"


def _command(c: _Command) -> Command:
    solve = c.solve
    return Command(c.ax, c.ay, c.status, c.plan, None if solve is None else SolveReport(*solve))


def _unique(robots: list[str], m: _Envelope, field: str) -> list[str]:
    if len(set(robots)) != len(robots):
        # Counted in one pass: list.count per id made a 20,000-id HELLO cost seconds.
        dupes = sorted(r for r, n in Counter(robots).items() if n > 1)
        raise _fail(f"{_label(m)}: body.{field}", dupes, "robot ids must be unique")
    return robots


# --- errors --------------------------------------------------------------------------------------


def _checked(value: Any, wire: Any, where: str, path: str) -> Any:
    """`value` converted to the wire type `wire`, or a `MessageError` naming what is wrong at
    `where`: `path`."""
    try:
        return msgspec.convert(value, wire)
    except msgspec.ValidationError as exc:
        raise _invalid(where, path, value, wire, exc) from None


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector (if on) while a frame is decoded.

    A big frame makes hundreds of thousands of objects (and a failed one as many again, read
    untyped to find the bad value), each allocation a step towards a collection: rejecting a
    2 MB frame took twice as long, and with a million objects alive elsewhere in the process
    a decode that set off a full collection took 112 ms instead of 15. None of these objects
    can be part of a cycle; the collector runs as due once the decode is over.
    """
    if not gc.isenabled():
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


def _rejection(raw: bytes, error: Exception) -> MessageError:
    """Why the frame `raw` failed to decode (with `error`), said as a `MessageError`."""
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        return _fail("bus message", raw, f"is not UTF-8 ({exc.reason} at byte {exc.start})")
    try:
        try:
            obj = _PLAIN_DECODER.decode(raw)
        except msgspec.ValidationError:  # a number out of range: read again, as inf
            obj = _RAW_DECODER.decode(raw)
    except msgspec.ValidationError:  # valid JSON msgspec cannot hold untyped (a huge integer)
        return _fail("bus message", raw, f"cannot be read ({error})")
    except msgspec.DecodeError as exc:
        return _fail("bus message", raw, f"is not valid JSON ({_json_problem(raw, exc)})")
    except RecursionError:
        return _fail("bus message", raw, f"nests too deeply to be read ({error})")
    if type(obj) is not dict:
        return _fail("bus message", obj, "must be a JSON object (the envelope)")
    # The version first: another version may have other fields.
    version = obj.get("version")
    if version != SCHEMA_VERSION or type(version) is not int:
        return _fail(
            "bus message: version",
            version,
            f"unsupported schema version; this build speaks version {SCHEMA_VERSION}",
        )
    kind_value = obj.get("kind")
    kind = _KINDS.get(kind_value) if type(kind_value) is str else None
    if kind is None:
        return _fail("bus message: kind", kind_value, f"must be one of {_KIND_NAMES}")
    sender = obj.get("sender")
    label = "bus message"
    if type(sender) is str and sender:
        label = f"{kind.name} message from {_quote(sender)}"
    if not isinstance(error, msgspec.ValidationError):  # a fault only the typed parse sees
        return _fail(label, raw, f"is not valid ({error})")
    return _invalid(label, "", obj, _ENVELOPES[kind], error)


_KINDS = {k.value: k for k in MessageKind}
_KIND_NAMES = ", ".join(repr(k.value) for k in MessageKind)
_AT_BYTE = re.compile(r"\(byte (\d+)\)")


def _json_problem(raw: bytes, error: msgspec.DecodeError) -> str:
    """msgspec's reason, except that Python's spellings of non-finite numbers (``json.dumps``
    writes them by default) are called what they are."""
    found = _AT_BYTE.search(str(error))
    if found:
        at = int(found[1])
        for constant in (b"NaN", b"Infinity"):
            if raw.startswith(constant, at):
                sign = "-" if raw[at - 1 : at] == b"-" else ""
                return f"{sign}{constant.decode()} is not a finite number, at byte {at}"
    return str(error)


# msgspec's path: `$` then `.field`, `[index]` or `[...]` (a dict's value, key not said).
_STEP = re.compile(r"\.(\w+)|\[(\d+)\]|\[\.\.\.\]")


def _invalid(
    where: str, path: str, value: Any, wire: Any, error: msgspec.ValidationError
) -> MessageError:
    """msgspec's `error`, raised checking `value` against the wire type `wire`, as a
    `MessageError` that says where (`where`: `path`, then the path msgspec gives), quotes the
    bad value (found by walking that path through `value`) and says what it must be."""
    reason, _, at = str(error).partition(" - at `")
    of_key = at.startswith("key` in `")
    at = at.removeprefix("key` in `").removesuffix("`")
    named = True
    try:
        for step in _STEP.finditer(at, 1):
            field, index = step.groups()
            container, meta = _resolve(wire, value)
            if field is not None:
                wire, value = _field_types(container)[field], value[field]
                path, named = f"{path}.{field}", True
            elif index is not None:
                wire, value, suffix = _item(container, meta, value, int(index))
                path, named = path + suffix, suffix.startswith(".")
            else:
                return _invalid_in(where, path, value, get_args(container)[1])
        if of_key:
            key_wire = get_args(_resolve(wire, value)[0])[0]
            bad = next(k for k in value if not _conforms(k, key_wire))
            return _fail(f"{_at(where, path)} key", bad, _rule(key_wire, bad, False))
        if reason.startswith(("Object missing required field", "Object contains unknown field")):
            struct = _resolve(wire, value)[0]
            names = frozenset(_field_types(struct)) | {struct.__struct_config__.tag_field} - {None}
            return _fields_error(value, _at(where, path), names)
        return _fail(_at(where, path), _as_read(value, wire), _rule(wire, value, named))
    except (LookupError, TypeError, ValueError, AttributeError, StopIteration):
        # The path does not lead through `value` as expected: say what msgspec said.
        return MessageError(f"{_at(where, path)}: {error}")


def _item(array: Any, meta: Meta | None, value: Any, i: int) -> tuple[Any, Any, str]:
    """Item `i` of `value`, an array of type `array` (with `meta`): its type, its value and how
    its path goes on (see extra["at"] above)."""
    args = get_args(array)
    fixed = get_origin(array) is tuple and args[-1] is not ...
    report = meta.extra.get("at") if meta is not None and meta.extra else None
    suffix = f"[{i}]" if report is None else report if type(report) is str else report[i]
    return args[i] if fixed else args[0], value[i], suffix


def _invalid_in(where: str, path: str, mapping: dict[str, Any], item_wire: Any) -> MessageError:
    """The error in a dict's value, which msgspec does not say the key of: the first that fails."""
    for key, item in mapping.items():
        try:
            msgspec.convert(item, item_wire)
        except msgspec.ValidationError as exc:
            return _invalid(where, f"{path}[{key!r}]", item, item_wire, exc)
    raise LookupError(path)


def _at(where: str, path: str) -> str:
    path = path.lstrip(".")
    return f"{where}: {path}" if where and path else where or path


def _resolve(wire: Any, value: Any) -> tuple[Any, Meta | None]:
    """The type `value` is checked as under `wire` (the member of ``X | None`` it is meant
    for), without Annotated, and its Meta."""
    meta = None
    while True:
        if get_origin(wire) is Annotated:
            wire, *metas = get_args(wire)
            meta = metas[0]
        elif get_origin(wire) in (Union, UnionType):
            members = [t for t in get_args(wire) if t is not NoneType]
            wire = NoneType if value is None else members[0]
        else:
            return wire, meta


@functools.cache
def _field_types(struct: type) -> dict[str, Any]:
    return {f.name: f.type for f in msgspec.structs.fields(struct)}


def _conforms(value: Any, wire: Any) -> bool:
    try:
        msgspec.convert(value, wire)
    except msgspec.ValidationError:
        return False
    return True


def _is_number(wire: Any) -> bool:
    """Whether `wire` is a float type (or ``float | None``)."""
    members = get_args(wire) if get_origin(wire) in (Union, UnionType) else (wire,)
    return any(_resolve(t, 0.0)[0] is float for t in members)


def _finite(value: Any) -> bool:
    return (type(value) is float and value - value == 0.0) or (
        type(value) is int and -_MAX <= value <= _MAX
    )


def _as_read(value: Any, wire: Any) -> Any:
    """`value` as the schema reads it: an int where a float belongs is that float."""
    if type(value) is int and _is_number(wire) and _finite(value):
        return float(value)
    return value


def _rule(wire: Any, value: Any, named: bool) -> str:
    """What `value` at a place of type `wire` must be; `named`: the path ends in its name."""
    if _is_number(wire) and not _finite(value):
        return "must be a finite number"
    meta = get_args(wire)[1] if get_origin(wire) is Annotated else None
    longest = meta.max_length if meta is not None else None
    if longest is not None and isinstance(value, str | list | dict) and len(value) > longest:
        unit = "characters" if isinstance(value, str) else "items"
        return f"holds {len(value):,} {unit}: at most {longest:,} are allowed"
    title = meta.title if meta is not None and not named else None
    return f"{title} must be {_phrase(wire)}" if title else f"must be {_phrase(wire)}"


def _phrase(wire: Any) -> str:
    meta = None
    if get_origin(wire) is Annotated:
        wire, meta = get_args(wire)[:2]
        if meta.description:
            return meta.description
    origin = get_origin(wire)
    if origin in (Union, UnionType):
        return " or ".join(sorted(map(_phrase, get_args(wire)), key=lambda p: p != "null"))
    if wire is NoneType:
        return "null"
    if wire is float:
        bounds = [
            f"{sign} {bound:g}"
            for sign, bound in (
                (">=", meta and meta.ge),
                (">", meta and meta.gt),
                ("<=", meta and meta.le),
                ("<", meta and meta.lt),
            )
            if bound is not None and abs(bound) != _MAX
        ]
        return " and ".join(bounds) or "a finite number"
    if wire is int:
        return "an integer" if meta is None or meta.ge is None else f"an integer >= {meta.ge}"
    if wire is str:
        return "a non-empty string" if meta is not None and meta.min_length else "a string"
    if isinstance(wire, type) and issubclass(wire, enum.Enum):
        return "one of " + ", ".join(repr(e.value) for e in wire)
    if origin in (list, tuple):
        return "an array"
    return "a JSON object"


_QUOTE_MAX = 120
# Bounded even for huge or deeply nested values (a plain repr of those is slow or fails).
_REPR = reprlib.Repr()
_REPR.maxlevel = 4
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = 10
_REPR.maxstring = _REPR.maxother = _REPR.maxlong = _QUOTE_MAX


def _quote(value: Any) -> str:
    if isinstance(value, bytes):
        value = value[:_QUOTE_MAX]
    text = _REPR.repr(value)
    return text if len(text) <= _QUOTE_MAX else text[: _QUOTE_MAX - 3] + "..."


def _fail(where: str, value: Any, rule: str) -> MessageError:
    return MessageError(f"{where} = {_quote(value)}: {rule}")


def _fields_error(d: Any, where: str, allowed: frozenset[str]) -> MessageError:
    """The error of `d`, which is not a JSON object with exactly the fields `allowed`."""
    if type(d) is not dict:
        return _fail(where, d, "must be a JSON object")
    missing = sorted(allowed - d.keys())
    extra = sorted(k for k in d if k not in allowed)
    names = ", ".join(sorted(allowed))
    if missing:
        return MessageError(f"{where}: missing field(s) {', '.join(missing)} (fields: {names})")
    allowed_text = f"only {names} are allowed" if names else "it has no fields"
    return MessageError(f"{where}: unexpected field(s) {_quote(extra)}; {allowed_text}")
