"""The bus's wire schema: what the engine and the robot agents say to each other, version 3.

Every message is one ZeroMQ frame holding one compact UTF-8 JSON object, the *envelope*::

    {"version": 3, "kind": "observe", "sender": "exchange", "tick": 42, "body": {...}}

`kind` says what the body holds (see `MessageKind`); `tick` is the engine's control tick the
message belongs to (0 for HELLO). Observations and commands travel as JSON objects whose fields
are exactly those of `fleet.plugins.Observation` and `fleet.plugins.Command`; small fixed
tuples travel as arrays: a goal is ``[x, y]``, a neighbour ``[robot, x, y, vx, vy]``, a plan
sample ``[t, x, y]``, a speed-cap piece ``[start_s, end_s, cap]``, a solve report
``[outcome, solver_s, step_s]``. (Version 2 added ``speed_caps`` and ``solve``, version 3
``print_end_s``.) Every field
is always present (``null`` where the dataclass holds None), so a message either matches the
schema exactly or is rejected.

`decode` trusts nothing: it checks the JSON, the version, the kind, every field's presence and
type, that numbers are finite and that no field is extra, and raises `MessageError` saying what
is wrong with the bad value quoted. It returns OBSERVE and ACT bodies already converted to
`Observation` and `Command` objects, so each message is parsed and checked exactly once.
Batching many robots into one message keeps the per-robot cost to a few microseconds.
"""

from __future__ import annotations

import enum
import json
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fleet.errors import MessageError
from fleet.plugins import (
    Command,
    ControlStatus,
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
]

SCHEMA_VERSION = 3
"""The version this build writes and the only one it reads."""


class MessageKind(enum.Enum):
    """What a message is for; the value is what travels in the envelope's ``kind``."""

    HELLO = "hello"
    """Agent to engine, first message: ``{"robots": [robot, ...]}``, the robots it hosts."""
    WELCOME = "welcome"
    """Engine to agent, answer to HELLO: ``{"accepted": [robot, ...], "rejected": {robot: why}}``.
    """
    OBSERVE = "observe"
    """Engine to agent, once per tick: ``{"t": seconds, "observations": [Observation, ...]}``."""
    ACT = "act"
    """Agent to engine, answer to the same tick's OBSERVE: ``{"commands": {robot: Command}}``."""
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
        ``observations`` is a list of `Observation` and ACT's ``commands`` maps robot ids to
        `Command` objects.
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

    OBSERVE observations and ACT commands may be given as `Observation` / `Command` objects
    (converted here) or as the dicts `observation_to_wire` / `command_to_wire` return; so
    ``decode(encode(k, s, t, body)).body == body`` for a body written with the objects.

    Raises
    ------
    MessageError
        If `kind`, `sender` or `tick` is malformed, the body lacks a field of its kind or has
        one too many, ``observations`` is not a list of observations, ``commands`` is not a
        mapping of robot ids to commands, a command is invalid, or the body holds a value JSON
        cannot carry (NaN, infinity, a non-JSON type); the message names where.
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
        body = {**body, "observations": wire}
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
        body = {**body, "commands": commands}
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


def observation_to_wire(o: Observation) -> dict[str, Any]:
    """The JSON form of an observation (numbers coerced to plain float/int, e.g. from numpy)."""
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
            [n.robot, float(n.x), float(n.y), float(n.vx), float(n.vy)] for n in o.neighbours
        ],
        "speed_caps": [[float(a), float(b), float(c)] for a, b, c in o.speed_caps],
        "print_end_s": None if o.print_end_s is None else float(o.print_end_s),
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
    )
)
_COMMAND_FIELDS = frozenset(("ax", "ay", "status", "plan", "solve"))
_HELLO_FIELDS = frozenset(("robots",))
_WELCOME_FIELDS = frozenset(("accepted", "rejected"))
_OBSERVE_FIELDS = frozenset(("t", "observations"))
_ACT_FIELDS = frozenset(("commands",))
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
        The message, with OBSERVE and ACT bodies converted to `Observation` / `Command`.

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
    return {"robots": _robot_list(body["robots"], f"{where}: body.robots")}


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
    return {"t": t, "observations": observations}


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
    return {"commands": commands}


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
    MessageKind.BYE: _BYE_FIELDS,
}

_BODY_READERS = {
    MessageKind.HELLO: _hello_body,
    MessageKind.WELCOME: _welcome_body,
    MessageKind.OBSERVE: _observe_body,
    MessageKind.ACT: _act_body,
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
        tuple([_neighbour(n, prefix, index, j) for j, n in enumerate(neighbours)])
        if neighbours
        else (),
        _cap_pieces(caps, f"{_at(prefix, index)}.speed_caps") if caps else (),
        print_end,
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


def _neighbour(n: Any, prefix: str, index: int | None, j: int) -> Neighbour:
    if type(n) is not list or len(n) != 5 or type(n[0]) is not str or not n[0]:
        raise _fail(f"{_at(prefix, index)}.neighbours[{j}]", n, "must be [robot, x, y, vx, vy]")
    robot, x, y, vx, vy = n
    if (
        type(x) is not float
        or type(y) is not float
        or type(vx) is not float
        or type(vy) is not float
        or x - x + y - y + vx - vx + vy - vy != 0.0
    ):
        name = f"neighbours[{j}]"
        x = _number(x, prefix, name, index)
        y = _number(y, prefix, name, index)
        vx = _number(vx, prefix, name, index)
        vy = _number(vy, prefix, name, index)
    return Neighbour(robot, x, y, vx, vy)


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
