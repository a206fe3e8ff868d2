"""The agent side of the bus: one host serving the controllers of several robots.

An `AgentHost` connects to the engine's `Exchange`, introduces itself with HELLO (the robots it
hosts), and then answers every OBSERVE with one ACT holding a command per observed robot. It
never raises on what it receives: malformed, unexpected or stale messages are logged on the
``fleet.bus`` logger, counted in `AgentHost.stats` and dropped. A controller that raises, or
returns something that is not a valid `Command`, gets its robot a braking command with
`ControlStatus.ERROR`, and the host keeps going.

Contract net: an OBSERVE may announce jobs; the host asks each observed robot's controller for
a bid (`Controller.bid`) on every announced job and sends the bids with the commands. A
controller that answers `ControlStatus.BLOCKED` while its robot has a job hands that job back
(`Handback`, once per robot and job), so the engine announces it again.

Liveness: a host run by `serve` sends a HEARTBEAT whenever it has sent nothing for
`heartbeat_s`, while idle and between robots while computing a long OBSERVE, so the exchange
can tell a slow agent from a dead one. Hosts the engine pumps itself send none.

Only the newest OBSERVE matters: the exchange has given up on older ticks by the time a newer
one is queued, so after a stall the host answers the newest and skips the rest (counted as
``skipped``) instead of computing every abandoned tick in turn.

In one process the engine pumps local hosts itself (`Exchange.add_local`); in another process
(or thread) call `AgentHost.serve`, which returns when the exchange says BYE. The host's name is
its ZeroMQ routing id, so the exchange knows it again after a dropped connection comes back.

The host keeps the conversation with the exchange (HELLO, WELCOME, OBSERVE, BYE, heartbeats);
its `link` carries the messages and its `responder` calls the controllers.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING

import zmq

from fleet.bus.link import Link
from fleet.bus.responder import Responder
from fleet.bus.schema import MAX_MESSAGE_BYTES, Message, MessageKind
from fleet.bus.transport import ROUTING_ID_MAX, default_context
from fleet.errors import PluginError
from fleet.plugins import Controller

if TYPE_CHECKING:
    from fleet.bus.security import ClientCurve

__all__ = ["AgentHost", "AGENT_STATS"]

#: Counters kept in `AgentHost.stats`.
AGENT_STATS = (
    "messages_received",
    "messages_sent",
    "messages_rejected",
    "stale",
    "skipped",  # queued OBSERVEs passed over because a newer one was waiting behind them
    "observations",
    "unknown_robots",
    "controller_errors",
    "bids",  # bids sent
    "bids_declined",  # announcements a controller declined (bid returned None)
    "bids_dropped",  # bids that were not a finite number >= 0
    "bid_errors",  # bid() raised
    "handbacks",  # jobs handed back (BLOCKED)
    "heartbeats",  # HEARTBEATs sent
)

_names = itertools.count(1)


class AgentHost:
    """Hosts the controllers of some robots and answers the exchange on their behalf.

    Parameters
    ----------
    address:
        The exchange's address (`Exchange.address`).
    controllers:
        Robot id to its controller, already `reset` with its context.
    name:
        Name used as ``sender``, in logs and (UTF-8 encoded, at most 255 bytes) as the socket's
        routing id; default ``agent-<pid>-<n>``. Must be unique among the agents of one
        exchange: a second host of the same name takes the first one's connection over.
    context:
        ZeroMQ context; default the process-wide one (inproc needs the exchange's).
    log:
        Logger; default ``fleet.bus``.
    heartbeat_s:
        Send a HEARTBEAT whenever nothing was sent for this long (s), in `serve` and between
        robots while computing; None sends none (`Exchange.add_local` sets that: the engine
        pumps local hosts itself). Keep it well below the exchange's ``lost_after_s``.
    scenario:
        Fingerprint of the scenario the controllers were set up for, sent in HELLO; an
        exchange running another scenario refuses every robot and says BYE. ``""``: unchecked.
    curve:
        CurveZMQ client keys (`fleet.bus.security.ClientCurve`) for an exchange that requires
        them; None connects in the clear.
    max_message_bytes:
        Longest message taken in or sent; the exchange's must be the same (both read it from
        the scenario's ``[bus] max_message_bytes``).
    threads:
        Robots' steps computed at once, in threads (`fleet.bus.responder`; the scenario's
        ``[bus] threads``); 1 computes them in turn. The commands are the same either way.

    Attributes
    ----------
    identity:
        The socket's ZeroMQ routing id: `name`, UTF-8 encoded.
    accepted:
        Robots the exchange accepted (from WELCOME); None until WELCOME arrives.
    rejected:
        Robots the exchange refused, with its reason.
    finished:
        True once the exchange said BYE.
    last_tick:
        The newest tick whose OBSERVE this host answered; -1 before the first.
    heartbeat_s:
        As the parameter; may be changed between calls.
    stats:
        Counters named in `AGENT_STATS`.
    """

    def __init__(
        self,
        address: str,
        controllers: Mapping[str, Controller],
        *,
        name: str | None = None,
        context: zmq.Context | None = None,
        log: logging.Logger | None = None,
        heartbeat_s: float | None = 0.5,
        scenario: str = "",
        curve: ClientCurve | None = None,
        max_message_bytes: int = MAX_MESSAGE_BYTES,
        threads: int = 1,
    ) -> None:
        if not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
            raise ValueError(f"agent host threads = {threads!r}: must be an integer >= 1")
        if heartbeat_s is not None and not (
            isinstance(heartbeat_s, int | float)
            and not isinstance(heartbeat_s, bool)
            and math.isfinite(heartbeat_s)
            and heartbeat_s > 0
        ):
            raise ValueError(
                f"agent host heartbeat_s = {heartbeat_s!r}: must be a positive number or None"
            )
        if not isinstance(scenario, str):
            raise ValueError(f"agent host scenario = {scenario!r}: must be a string ('' unchecked)")
        for robot, controller in controllers.items():
            if not isinstance(robot, str) or not robot:
                raise PluginError(f"agent host: robot id {robot!r} must be a non-empty string")
            if not isinstance(controller, Controller):
                raise PluginError(
                    f"agent host: controller for robot {robot!r} is a"
                    f" {type(controller).__name__}, not a fleet.plugins.Controller"
                )
        if name is None:
            name = f"agent-{os.getpid()}-{next(_names)}"
        elif (
            not isinstance(name, str)
            or not name
            or name[0] == "\0"
            or len(name.encode()) > ROUTING_ID_MAX
        ):
            raise ValueError(
                f"agent host name {name!r}: must be a non-empty string of at most"
                f" {ROUTING_ID_MAX} UTF-8 bytes, not starting with NUL (it is the routing id)"
            )
        self.name = name
        self.identity = name.encode()
        self.address = address
        self.context = context if context is not None else default_context()
        self.log = log if log is not None else logging.getLogger("fleet.bus")
        self.controllers: dict[str, Controller] = dict(sorted(controllers.items()))
        self.stats: dict[str, int] = dict.fromkeys(AGENT_STATS, 0)
        self.accepted: frozenset[str] | None = None
        self.rejected: dict[str, str] = {}
        self.exchange: str | None = None
        self.finished = False
        self.closed = False
        self.last_tick = -1
        self.heartbeat_s: float | None = None if heartbeat_s is None else float(heartbeat_s)
        self.scenario = scenario
        self._responder = Responder(name, self.controllers, self.stats, self.log, threads)
        self._link = Link(
            self.context,
            address,
            self.identity,
            curve,
            name=name,
            stats=self.stats,
            log=self.log,
            max_message_bytes=max_message_bytes,
        )
        self.socket = self._link.socket
        hello = {"robots": list(self.controllers), "scenario": scenario}
        self._link.send(MessageKind.HELLO, 0, hello)

    # -- running ----------------------------------------------------------------------------
    def pump(self, timeout_ms: int | None = 0) -> bool:
        """Handle one incoming message, waiting up to `timeout_ms` (None: forever).

        If it is an OBSERVE, first take in everything queued behind it: only the newest OBSERVE
        is answered (the older ones are counted as ``skipped``), other messages are handled in
        their order. Returns True if a message was received (whether handled or dropped),
        False if none came in time or the host is closed.
        """
        if self.closed:
            return False
        return self._link.receive(timeout_ms, self._handle)

    def serve(self, idle_timeout_s: float | None = None) -> None:
        """Answer the exchange until it says BYE (or nothing arrives for `idle_timeout_s`).

        Sends a HEARTBEAT whenever nothing was sent for `heartbeat_s` (once the exchange has
        accepted a robot). Does not close the host; call `close` (or use ``with``) afterwards.
        """
        last = time.monotonic()
        while not self.finished and not self.closed:
            now = time.monotonic()
            wait: float | None = None
            if idle_timeout_s is not None:
                wait = idle_timeout_s - (now - last)
                if wait <= 0:
                    self.log.warning(
                        "agent %s: nothing from the exchange for %g s; stopping",
                        self.name,
                        idle_timeout_s,
                    )
                    return
            if self.heartbeat_s is not None and self.accepted:
                due = self._link.last_sent + self.heartbeat_s - now
                if due <= 0:
                    self._heartbeat()
                    due = self.heartbeat_s
                wait = due if wait is None else min(wait, due)
            if self.pump(None if wait is None else max(1, math.ceil(wait * 1000))):
                last = time.monotonic()

    def close(self) -> None:
        """Say BYE (unless the exchange already did) and close the socket. Idempotent."""
        if self.closed:
            return
        if not self.finished:
            self._link.send(MessageKind.BYE, max(self.last_tick, 0), {"reason": "agent closing"})
        self.socket.close()
        self._responder.close()
        self.closed = True

    def heartbeat(self) -> None:
        """Send a HEARTBEAT now, whatever `heartbeat_s` says.

        For code that keeps the host's thread busy outside `serve` (a loop of its own around
        `pump`, a long controller step) and must not be taken for dead by the exchange. Call
        it from the thread that uses the host, like every other method.
        """
        if not self.closed:
            self._heartbeat()

    def __enter__(self) -> AgentHost:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<AgentHost {self.name!r} -> {self.address}: {len(self.controllers)} robots>"

    # -- handlers ---------------------------------------------------------------------------
    def _handle(self, msg: Message) -> None:
        if msg.kind is MessageKind.OBSERVE:
            self._observe(msg)
        elif msg.kind is MessageKind.WELCOME:
            self._welcome(msg)
        else:
            self._bye(msg)

    def _welcome(self, msg: Message) -> None:
        accepted = msg.body["accepted"]
        strangers = [r for r in accepted if r not in self.controllers]
        if strangers:
            self._link.reject(
                f"WELCOME from {msg.sender!r} accepts robots we do not host: {strangers}"
            )
            return
        self.exchange = msg.sender
        self.accepted = frozenset(accepted)
        self.rejected = dict(msg.body["rejected"])
        for robot, reason in sorted(self.rejected.items()):
            self.log.warning("agent %s: exchange refused robot %s: %s", self.name, robot, reason)

    def _observe(self, msg: Message) -> None:
        if self.accepted is None:
            self._link.reject(f"OBSERVE from {msg.sender!r} before WELCOME")
            return
        if msg.sender != self.exchange:
            self._link.reject(
                f"OBSERVE from unknown sender {msg.sender!r} (exchange is {self.exchange!r})"
            )
            return
        if msg.tick <= self.last_tick:
            self.stats["stale"] += 1
            self.log.warning(
                "agent %s: dropped stale OBSERVE for tick %d (already at tick %d)",
                self.name,
                msg.tick,
                self.last_tick,
            )
            return
        self.last_tick = msg.tick
        tick = msg.tick
        beat = self.heartbeat_s

        def keep_alive() -> None:
            # A cheap clock check per robot keeps a long OBSERVE from looking like silence.
            if beat is not None and time.monotonic() - self._link.last_sent >= beat:
                self._heartbeat(tick)

        commands, bids, handbacks = self._responder.answer(
            tick, msg.body["observations"], msg.body["announcements"], self.accepted, keep_alive
        )
        self.stats["observations"] += len(commands)
        self.stats["bids"] += len(bids)
        self.stats["handbacks"] += len(handbacks)
        body = {"commands": commands, "bids": bids, "handbacks": handbacks}
        self._link.send(MessageKind.ACT, tick, body)

    def _heartbeat(self, tick: int | None = None) -> None:
        self.stats["heartbeats"] += 1
        self._link.send(MessageKind.HEARTBEAT, max(self.last_tick if tick is None else tick, 0), {})

    def _bye(self, msg: Message) -> None:
        if self.exchange is not None and msg.sender != self.exchange:
            self._link.reject(f"BYE from unknown sender {msg.sender!r}")
            return
        self.finished = True
        self.log.info(
            "agent %s: exchange %s said bye: %s", self.name, msg.sender, msg.body["reason"]
        )
