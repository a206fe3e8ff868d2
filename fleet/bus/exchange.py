"""The engine side of the bus: one control round trip per tick with every agent.

The engine owns the clock. At each control tick it hands the observations of the robots due
to `Exchange.round`, which sends each agent one OBSERVE holding its robots' observations and
collects one ACT per agent. Local hosts (same process, `Exchange.add_local`) are pumped
synchronously inside `round`, so a single-process run needs no threads and is deterministic;
remote hosts (other threads, processes or machines over ipc/tcp) answer on their own.

Local hosts are never timed out: `timeout_s` starts once they have answered, so their compute
time does not eat into the remote hosts' allowance. From then on the deadline is fixed and
checked on every pass, however many messages (good or bad) keep arriving.

`round` never raises on what agents send: malformed, unexpected, stale or unknown-sender
messages are logged on ``fleet.bus``, counted in `Exchange.stats` and dropped; robots without a
valid answer in time are simply absent from the result (the engine brakes them).

Contract net: the jobs announced in a round travel in every OBSERVE of that round; each agent
answers with bids for its observed robots and may hand jobs back (`Exchange.bids`,
`Exchange.handbacks`, valid ones only, in an order that does not depend on arrival).

Liveness: every message from an agent (ACT, HEARTBEAT, HELLO) refreshes its last-seen time, and
agents heartbeat while they compute or idle. A round that waits on a remote agent silent for
`lost_after_s` declares it lost at once; lost, departed (BYE) and unreachable agents are
forgotten, so their robots are unhosted (absent from results, braked by the engine) until an
agent says HELLO for them again. What happened is reported as `BusEvent` values
(`Exchange.take_events`).
"""

from __future__ import annotations

import enum
import errno
import logging
import math
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zmq

from fleet.bus.schema import (
    Message,
    MessageKind,
    announcement_to_wire,
    decode,
    encode,
    observation_to_wire,
)
from fleet.bus.transport import bind_router, default_context, new_inproc_address
from fleet.errors import MessageError
from fleet.plugins import Announcement, Bid, Command, Handback, Observation

if TYPE_CHECKING:
    from fleet.bus.agent import AgentHost
    from fleet.bus.security import ServerCurve

__all__ = ["Exchange", "EXCHANGE_STATS", "BusEvent", "BusEventKind"]

#: Counters kept in `Exchange.stats`.
EXCHANGE_STATS = (
    "rounds",
    "messages_sent",
    "messages_received",
    "messages_rejected",  # malformed, unexpected kind, unknown sender, unasked ACT
    "stale",  # ACTs for another tick than the current round's
    "robots_rejected",  # robots refused in a HELLO (unknown or already hosted)
    "commands_rejected",  # commands for robots the agent was not asked about
    "commands_missing",  # observed robots left without a command (absent from a result)
    "timeouts",  # rounds that ended at timeout_s with answers outstanding
    "send_failures",  # messages the socket could not deliver (agent gone, queue full)
    "heartbeats",  # HEARTBEATs received from known agents
    "bids",  # valid bids kept in `Exchange.bids`
    "bids_rejected",  # for jobs not announced this round or robots not asked, or repeated
    "handbacks",  # valid handbacks kept in `Exchange.handbacks`
    "handbacks_rejected",  # for robots the agent does not host, or repeated
    "agents_lost",  # agents declared lost (silent for lost_after_s, or unreachable)
    "agents_refused",  # HELLOs refused as a whole (scenario differs)
)


class BusEventKind(enum.StrEnum):
    """What happened to an agent; the values are plain strings (``kind == "lost"`` works)."""

    JOINED = "joined"
    """A HELLO was accepted for `BusEvent.robots` (also after a rejoin)."""
    LOST = "lost"
    """The agent was silent for ``lost_after_s`` while a round waited on it, or became
    unreachable; its robots are unhosted."""
    LEFT = "left"
    """The agent said BYE; its robots are unhosted."""
    REFUSED = "refused"
    """Robots claimed in a HELLO were refused (already hosted, not in the run, another
    scenario...), or CurveZMQ turned a client away; `BusEvent.reason` says why."""


@dataclass(frozen=True, slots=True)
class BusEvent:
    """Something that happened to an agent, for the engine to count faults and hand jobs back.

    Attributes
    ----------
    kind:
        What happened.
    agent:
        The agent's name (for a CurveZMQ refusal: the client's public key, or its address).
    robots:
        The robots concerned, sorted: accepted (joined), unhosted (lost, left) or refused.
    reason:
        Why, in words (empty for a plain join).
    """

    kind: BusEventKind
    agent: str
    robots: tuple[str, ...]
    reason: str = ""


# Plain ints: pyzmq's enum flags cost microseconds per operation on the hot path.
_EVENTS, _POLLIN, _NOBLOCK = int(zmq.EVENTS), int(zmq.POLLIN), int(zmq.NOBLOCK)
_EXPECT = (MessageKind.HELLO, MessageKind.ACT, MessageKind.HEARTBEAT, MessageKind.BYE)
# Messages taken from the ROUTER per pass, so that a flood cannot keep a pass (and the deadline
# check after it) from ending.
_BATCH = 256


@dataclass(eq=False)
class _Agent:
    identity: bytes
    name: str
    robots: set[str] = field(default_factory=set)
    seen: float = 0.0  # time.monotonic() of its latest valid message
    local: bool = False  # pumped by the exchange itself: never silent, never timed out


class Exchange:
    """Engine-side endpoint: a ROUTER that agents connect to.

    Parameters
    ----------
    address:
        Where to bind; None picks a fresh ``inproc://fleet-<n>``. A tcp port of ``*`` lets the
        system choose; `address` then holds the real one for agents to connect to.
    context:
        ZeroMQ context; default the process-wide one (local hosts must share it).
    timeout_s:
        How long `round` waits for answers before giving up on the missing ones (their agents
        keep their robots: they were heard from during the round, only late).
    lost_after_s:
        How long a remote agent a round waits on may stay silent (no message of any kind)
        before it is declared lost and forgotten; at most `timeout_s` (larger values are
        clamped to it). At the timeout, an agent not heard from since the round began is lost
        too; one that was (a heartbeat, a late answer) is only late and keeps its robots.
    log:
        Logger; default ``fleet.bus``.
    name:
        The exchange's ``sender`` name in messages.
    scenario:
        Fingerprint of the run's scenario; a HELLO naming another (non-empty) one is refused.
        ``""`` checks nothing.
    curve:
        CurveZMQ server keys (`fleet.bus.security.ServerCurve`): the ROUTER then only talks to
        agents whose public key is authorised. None: no encryption or authentication.

    Attributes
    ----------
    address:
        The bound address, for agents to connect to.
    stats:
        Counters named in `EXCHANGE_STATS`.
    bids:
        The valid bids of the latest round, sorted by (job, robot).
    handbacks:
        The valid handbacks of the latest round, sorted by (robot, job).
    """

    def __init__(
        self,
        address: str | None = None,
        *,
        context: zmq.Context | None = None,
        timeout_s: float = 10.0,
        lost_after_s: float = 3.0,
        log: logging.Logger | None = None,
        name: str = "exchange",
        scenario: str = "",
        curve: ServerCurve | None = None,
    ) -> None:
        if not (isinstance(timeout_s, int | float) and math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"exchange timeout_s = {timeout_s!r}: must be a positive number")
        if not (
            isinstance(lost_after_s, int | float)
            and not isinstance(lost_after_s, bool)
            and lost_after_s > 0
        ):
            raise ValueError(f"exchange lost_after_s = {lost_after_s!r}: must be a positive number")
        if not isinstance(scenario, str):
            raise ValueError(f"exchange scenario = {scenario!r}: must be a string ('' unchecked)")
        self.context = context if context is not None else default_context()
        self.timeout_s = float(timeout_s)
        # Beyond timeout_s the check could never fire: the round would have ended first.
        self.lost_after_s = min(float(lost_after_s), self.timeout_s)
        self.log = log if log is not None else logging.getLogger("fleet.bus")
        self.name = name
        self.scenario = scenario
        bind_address = address if address is not None else new_inproc_address()
        self._auth: Any = None
        if curve is None:
            self.socket, self.address = bind_router(self.context, bind_address)
        else:
            # The authenticator must be answering before the first handshake.
            self._auth = curve.start(self.context, self.log)
            try:
                self.socket, self.address = bind_router(
                    self.context, bind_address, curve=curve, log=self.log
                )
            except BaseException:
                self._auth.stop()
                raise
        self.stats: dict[str, int] = dict.fromkeys(EXCHANGE_STATS, 0)
        self.bids: list[Bid] = []
        self.handbacks: list[Handback] = []
        self.closed = False
        self._locals: list[AgentHost] = []
        self._agents: dict[bytes, _Agent] = {}  # by ZeroMQ routing id (the agent's name)
        self._names: dict[str, _Agent] = {}
        self._lost: dict[bytes, str] = {}  # agents dropped as unreachable; told BYE on close
        self._owner: dict[str, _Agent] = {}  # robot -> hosting agent
        self._expected: frozenset[str] | None = None
        self._tick = -1
        self._pending: dict[bytes, set[str]] = {}  # agents yet to answer this round
        self._asked: dict[bytes, frozenset[str]] = {}  # robots each agent was asked this round
        self._announced: frozenset[str] = frozenset()  # jobs announced this round
        self._round_started = 0.0  # time.monotonic() when this round's OBSERVEs went out
        self._results: dict[str, Command] = {}
        self._bids: dict[tuple[str, str], Bid] = {}
        self._handbacks: dict[tuple[str, str], Handback] = {}
        self._events: list[BusEvent] = []
        self._missing = 0

    # -- set-up -------------------------------------------------------------------------------
    def add_local(self, host: AgentHost) -> None:
        """Adopt an in-process host: `round` pumps it synchronously and `close` closes it.

        The host must have been created with this exchange's `address` and context. Its
        heartbeats are turned off: the exchange pumps it itself, so it is never silent.
        """
        if host.address != self.address:
            raise ValueError(
                f"host {host.name!r} is connected to {host.address!r},"
                f" not to this exchange at {self.address!r}"
            )
        if host.context is not self.context:
            raise ValueError(
                f"host {host.name!r} uses another zmq.Context than the exchange;"
                " local hosts must share it (inproc needs one context)"
            )
        if host not in self._locals:
            host.heartbeat_s = None
            self._locals.append(host)
            agent = self._agents.get(host.identity)
            if agent is not None:  # its HELLO was handled before it was adopted
                agent.local = True

    @property
    def agents(self) -> dict[str, frozenset[str]]:
        """Connected agents by name, with the robots each hosts."""
        return {a.name: frozenset(a.robots) for a in self._names.values()}

    def take_events(self) -> list[BusEvent]:
        """The events since the previous call, oldest first (and forget them).

        The engine drains these after every round, to count faults and hand back the jobs of
        robots that lost their agent. With CurveZMQ, clients the gatekeeper turned away
        appear as REFUSED events with no robots, named by their public key (Z85), or by
        their address when the handshake failed before they showed one.
        """
        if self._auth is not None:
            take = getattr(self._auth, "take_refusals", None)
            for refusal in take() if take is not None else ():
                who = refusal.public_key or refusal.address
                why = f"CURVE: {refusal.reason} (from {refusal.address})"
                self._events.append(BusEvent(BusEventKind.REFUSED, who, (), why))
        events, self._events = self._events, []
        return events

    def wait_for_agents(self, robots: Collection[str], timeout_s: float | None = None) -> None:
        """Accept agents until every robot in `robots` is hosted by one of them.

        HELLOs are answered with WELCOME; a robot claimed by a second agent, or not in
        `robots` (nor in an earlier call's), is refused and logged; so is every robot of an
        agent whose name another agent already uses, or that names another scenario.

        Raises
        ------
        MessageError
            If some robots are still without a host after `timeout_s` (default the
            exchange's); the message lists them and the agents connected so far.
        """
        self._expected = frozenset(robots) | (self._expected or frozenset())
        wait = self.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + wait
        if not self._expected - self._owner.keys():
            return
        while True:
            progressed = self._pump()
            uncovered = self._expected - self._owner.keys()
            if not uncovered:
                return
            # Checked on every pass: a stream of messages must not postpone the timeout.
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                shown = sorted(uncovered)
                more = f" and {len(shown) - 10} more" if len(shown) > 10 else ""
                raise MessageError(
                    f"exchange at {self.address}: after {wait:g} s no agent hosts robots"
                    f" {shown[:10]}{more}; connected agents: {sorted(self._names) or 'none'}"
                    " (start their agents, or raise the timeout)"
                )
            if not progressed:
                self._poll(remaining)

    # -- the control round trip -----------------------------------------------------------------
    def round(
        self,
        tick: int,
        t: float,
        observations: Sequence[Observation],
        announcements: Sequence[Announcement] = (),
    ) -> dict[str, Command]:
        """Send this tick's observations to the agents and collect their commands.

        Parameters
        ----------
        tick:
            The control tick; must increase from round to round.
        t:
            Simulation time of the tick (s).
        observations:
            One per robot due this tick (robot ids unique).
        announcements:
            Jobs offered for bids this round (job ids unique); they go in every OBSERVE of
            the round, and each agent bids for its observed robots.

        Returns
        -------
        dict
            Robot id to command, sorted by robot id, for every observed robot whose agent
            answered validly in time (local hosts always are; remote ones within `timeout_s`
            after the local hosts have answered, unless declared lost earlier); the others
            are absent and counted in ``stats["commands_missing"]``. The round's valid bids
            and handbacks are then in `bids` and `handbacks`.

        Raises
        ------
        MessageError
            If the exchange is closed, or an announcement cannot be encoded (not finite,
            negative print time), naming it.
        ValueError
            If `tick` does not increase, or a robot is observed (a job announced) twice.
        """
        if self.closed:
            raise MessageError(f"exchange at {self.address} is closed")
        if type(tick) is not int or tick <= self._tick:
            raise ValueError(f"round tick = {tick!r}: must be an integer > {self._tick}")
        announced = [a.job for a in announcements]
        if len(set(announced)) != len(announced):
            dupes = sorted({j for j in announced if announced.count(j) > 1})
            raise ValueError(f"round tick {tick}: jobs {dupes} announced more than once")
        offers = []
        for i, a in enumerate(announcements):
            if not isinstance(a, Announcement):
                raise MessageError(
                    f"round tick {tick}: announcements[{i}] = {a!r}: must be a"
                    " fleet.plugins.Announcement"
                )
            try:
                offers.append(announcement_to_wire(a))
            except MessageError as exc:
                raise MessageError(f"round tick {tick}: announcements[{i}]: {exc}") from None
        self._tick = tick
        self.stats["rounds"] += 1
        # What queued up since the last round first: a BYE makes its agent "left" rather than
        # unreachable, a HELLO (rejoin) has its robots served in this very round.
        self._pump_router()
        self._results = {}
        self._bids = {}
        self._handbacks = {}
        self._announced = frozenset(announced)
        self._missing = 0
        groups: dict[_Agent, list[dict]] = {}
        robots: dict[_Agent, set[str]] = {}
        owner = self._owner
        seen: set[str] = set()
        for obs in sorted(observations, key=_robot_of):
            robot = obs.robot
            if robot in seen:
                raise ValueError(f"round tick {tick}: two observations of robot {robot!r}")
            seen.add(robot)
            agent = owner.get(robot)
            if agent is None:
                self._missing += 1
                continue
            if agent in groups:
                groups[agent].append(observation_to_wire(obs))
                robots[agent].add(robot)
            else:
                groups[agent] = [observation_to_wire(obs)]
                robots[agent] = {robot}
        self._pending = {}
        self._asked = {}
        self._round_started = time.monotonic()
        # Asking for EVENTS makes the ROUTER take in connections made since its last call (a
        # send may skip that when calls come quickly), so a reconnected agent is routable.
        self.socket.getsockopt(_EVENTS)
        for agent, wire in groups.items():
            body = {"t": float(t), "observations": wire, "announcements": offers}
            if self._send(agent, MessageKind.OBSERVE, body):
                self._pending[agent.identity] = robots[agent]
                self._asked[agent.identity] = frozenset(robots[agent])
            else:
                self._missing += len(robots[agent])
        self._pump_locals(tick)
        self._collect(time.monotonic() + self.timeout_s)
        self.stats["commands_missing"] += self._missing
        results = self._results
        self._results = {}
        self.bids = [self._bids[k] for k in sorted(self._bids)]
        self.handbacks = [self._handbacks[k] for k in sorted(self._handbacks)]
        self.stats["bids"] += len(self.bids)
        self.stats["handbacks"] += len(self.handbacks)
        return {r: results[r] for r in sorted(results)}

    def _pump_locals(self, tick: int) -> None:
        """Pump until every local host that was sent an OBSERVE has answered it.

        Over ipc/tcp the OBSERVE reaches a local host only after a short trip through the
        sockets, so this waits for it; the wait gives up only if no local host handles
        anything for `timeout_s` (the message was lost), never because a controller is slow.
        """
        pending = self._pending
        hosts = [h for h in self._locals if h.identity in pending]
        if not hosts:
            return
        idle_until = time.monotonic() + self.timeout_s
        while True:
            if self._pump_hosts():
                idle_until = time.monotonic() + self.timeout_s
            self._pump_router()
            hosts = [
                h
                for h in hosts
                if h.last_tick < tick and not h.closed and h.identity in self._pending
            ]
            if not hosts:
                return
            remaining = idle_until - time.monotonic()
            if remaining <= 0:
                self.log.warning(
                    "exchange: tick %d: local hosts %s got no OBSERVE within %g s",
                    tick,
                    [h.name for h in hosts],
                    self.timeout_s,
                )
                return
            self._poll(remaining)

    def _collect(self, deadline: float) -> None:
        """Handle answers until none is outstanding or `deadline` (time.monotonic) passes.

        Remote agents silent for `lost_after_s` are declared lost on the way; the check is
        made only once the ROUTER's queue is drained, so that messages the exchange has not
        read yet (say, heartbeats sent while the engine was busy between rounds) count.
        """
        while self._pending:
            progressed = self._pump_hosts()
            handled = self._pump_router_count()
            if not self._pending:
                return
            now = time.monotonic()
            drained = handled < _BATCH  # silence is then real, not messages yet unread
            # Checked on every pass: a stream of messages must not postpone the timeout.
            if now >= deadline:
                if drained:
                    # Silent for the whole round, which lasted at least lost_after_s: lost.
                    # Those heard from since the OBSERVE went out are alive, merely late.
                    self._check_silent(now, since=self._round_started)
                if self._pending:
                    self._time_out()
                return
            wake = deadline - now
            if drained:
                wake = min(wake, self._check_silent(now))
                if not self._pending:
                    return
            if not progressed and not handled:
                self._poll(wake)

    def _time_out(self) -> None:
        late = sorted(r for robots in self._pending.values() for r in robots)
        agents = sorted(self._agents[i].name for i in self._pending if i in self._agents)
        self.stats["timeouts"] += 1
        self._missing += len(late)
        self.log.warning(
            "exchange: tick %d: no answer within %g s from %s for robots %s",
            self._tick,
            self.timeout_s,
            agents,
            late[:20],
        )
        self._pending = {}

    def _check_silent(self, now: float, since: float | None = None) -> float:
        """Declare pending remote agents lost that were silent for `lost_after_s` (or, given
        `since`, not heard from since then); seconds until the next one would be (inf if no
        other is pending)."""
        soonest = math.inf
        for identity in list(self._pending):
            agent = self._agents.get(identity)
            if agent is None or agent.local:
                continue
            silent = now - agent.seen
            if silent >= self.lost_after_s if since is None else agent.seen < since:
                why = f"silent for {silent:.3g} s (lost_after_s = {self.lost_after_s:g})"
                self._declare_lost(agent, why)
                # If it is only stuck, it learns it was dropped (its serve() returns) instead
                # of talking on to an exchange that no longer listens; it may say HELLO again.
                bye = encode(MessageKind.BYE, self.name, max(self._tick, 0), {"reason": why})
                try:
                    self.socket.send_multipart((identity, bye), _NOBLOCK)
                except zmq.ZMQError as exc:
                    self.log.debug("exchange: no BYE for lost agent %s: %s", agent.name, exc)
            else:
                soonest = min(soonest, self.lost_after_s - silent)
        return soonest

    def _declare_lost(self, agent: _Agent, why: str) -> None:
        self.stats["agents_lost"] += 1
        robots = tuple(sorted(agent.robots))
        self.log.warning(
            "exchange: tick %d: agent %s lost (%s); its robots %s are unhosted",
            self._tick,
            agent.name,
            why,
            list(robots[:20]),
        )
        self._forget(agent)
        self._events.append(BusEvent(BusEventKind.LOST, agent.name, robots, why))

    # -- receiving ----------------------------------------------------------------------------
    def _pump(self) -> bool:
        """Let local hosts handle what is waiting, then handle what reached the ROUTER."""
        progressed = self._pump_hosts()
        return self._pump_router() or progressed

    def _pump_hosts(self) -> bool:
        """Let local hosts handle what is waiting; True if any handled something."""
        progressed = False
        for host in self._locals:
            while host.pump(0):
                progressed = True
        return progressed

    def _pump_router(self) -> bool:
        """Handle up to `_BATCH` messages waiting at the ROUTER; True if there were any."""
        return self._pump_router_count() > 0

    def _pump_router_count(self) -> int:
        """Handle up to `_BATCH` messages waiting at the ROUTER; how many there were."""
        sock = self.socket
        handled = 0
        # Asking for EVENTS is much cheaper than a recv that fails with zmq.Again.
        while handled < _BATCH and sock.getsockopt(_EVENTS) & _POLLIN:
            try:
                frames = sock.recv_multipart(_NOBLOCK)
            except zmq.Again:
                break
            handled += 1
            self._handle(frames)
        return handled

    def _poll(self, remaining_s: float) -> None:
        """Sleep until the ROUTER or a local host has something, at most `remaining_s`."""
        poller = zmq.Poller()
        poller.register(self.socket, zmq.POLLIN)
        for host in self._locals:
            if not host.closed:
                poller.register(host.socket, zmq.POLLIN)
        poller.poll(max(1, math.ceil(remaining_s * 1000)))

    def _handle(self, frames: list[bytes]) -> None:
        self.stats["messages_received"] += 1
        identity = frames[0]
        if len(frames) != 2:
            self._reject(identity, f"{len(frames) - 1} frames after the routing id, expected 1")
            return
        try:
            msg = decode(frames[1], _EXPECT)
        except MessageError as exc:
            self._reject(identity, str(exc))
            return
        if msg.kind is MessageKind.HELLO:
            self._hello(identity, msg)
            return
        agent = self._agents.get(identity)
        if agent is None:
            self._reject(identity, f"{msg.kind.name} from unknown sender {msg.sender!r} (no HELLO)")
            return
        if msg.sender != agent.name:
            self._reject(
                identity,
                f"{msg.kind.name} from {msg.sender!r} on the connection of agent {agent.name!r}",
            )
            return
        agent.seen = time.monotonic()
        kind = msg.kind
        if kind is MessageKind.ACT:
            self._act(agent, msg)
        elif kind is MessageKind.HEARTBEAT:
            self.stats["heartbeats"] += 1
        else:
            self._bye(agent, msg)

    def _hello(self, identity: bytes, msg: Message) -> None:
        name = msg.sender
        claimed = msg.body["robots"]
        scenario = msg.body["scenario"]
        agent = self._agents.get(identity)
        by_name = self._names.get(name)
        reason = None
        refuse_all = False
        if scenario and self.scenario and scenario != self.scenario:
            reason = f"scenario differs (agent {scenario}, run {self.scenario})"
            refuse_all = True
        elif agent is not None and agent.name != name:
            reason = f"this connection already introduced itself as {agent.name!r}"
        elif by_name is not None and by_name is not agent:
            reason = f"another agent is already called {name!r}"
        accepted: list[str] = []  # in the order claimed, including robots it hosts already
        joined: list[str] = []  # robots it did not host before
        rejected: dict[str, str] = {}
        if reason is not None:
            rejected = dict.fromkeys(claimed, reason)
        else:
            if agent is None:
                agent = _Agent(identity, name, local=self._is_local(identity))
                self._agents[identity] = agent
                self._names[name] = agent
                self._lost.pop(identity, None)
            agent.seen = time.monotonic()
            for robot in claimed:
                owner = self._owner.get(robot)
                if self._expected is not None and robot not in self._expected:
                    rejected[robot] = "unknown robot: not part of this run"
                elif owner is not None and owner is not agent:
                    rejected[robot] = f"already hosted by agent {owner.name!r}"
                else:
                    if owner is None:
                        joined.append(robot)
                    accepted.append(robot)
                    agent.robots.add(robot)
                    self._owner[robot] = agent
        self.stats["robots_rejected"] += len(rejected)
        if refuse_all:
            self.stats["agents_refused"] += 1
            self.log.warning("exchange: refused agent %s: %s", name, reason)
        else:
            for robot, why in rejected.items():
                self.log.warning("exchange: agent %s may not host robot %s: %s", name, robot, why)
        self.log.debug("exchange: agent %s hosts %d robots", name, len(accepted))
        if joined:
            self._events.append(BusEvent(BusEventKind.JOINED, name, tuple(sorted(joined))))
        by_reason: dict[str, list[str]] = {}
        for robot, why in rejected.items():
            by_reason.setdefault(why, []).append(robot)
        for why, robots in by_reason.items():
            self._events.append(BusEvent(BusEventKind.REFUSED, name, tuple(sorted(robots)), why))
        body = {"accepted": accepted, "rejected": rejected}
        raw = encode(MessageKind.WELCOME, self.name, max(self._tick, 0), body)
        self._send_raw(identity, raw, name)
        if refuse_all:
            # An agent set up for another scenario can do no good here: tell it to stop.
            raw = encode(MessageKind.BYE, self.name, max(self._tick, 0), {"reason": reason})
            self._send_raw(identity, raw, name)

    def _is_local(self, identity: bytes) -> bool:
        return any(h.identity == identity for h in self._locals)

    def _act(self, agent: _Agent, msg: Message) -> None:
        if msg.tick != self._tick:
            self.stats["stale"] += 1
            self.log.warning(
                "exchange: dropped ACT of agent %s for tick %d during tick %d",
                agent.name,
                msg.tick,
                self._tick,
            )
            return
        asked = self._pending.pop(agent.identity, None)
        if asked is None:
            self._reject(agent.identity, f"ACT from {agent.name!r} for tick {msg.tick}, not asked")
            return
        results = self._results
        for robot, command in msg.body["commands"].items():
            if robot in asked:
                results[robot] = command
                asked.discard(robot)
            else:
                self.stats["commands_rejected"] += 1
                self.log.warning(
                    "exchange: tick %d: agent %s sent a command for robot %s, not asked of it",
                    self._tick,
                    agent.name,
                    robot,
                )
        if asked:
            self._missing += len(asked)
            self.log.warning(
                "exchange: tick %d: agent %s sent no command for robots %s",
                self._tick,
                agent.name,
                sorted(asked)[:20],
            )
        self._take_bids(agent, msg.body["bids"])
        self._take_handbacks(agent, msg.body["handbacks"])

    def _take_bids(self, agent: _Agent, bids: list[Bid]) -> None:
        if not bids:
            return
        asked = self._asked.get(agent.identity, frozenset())
        announced = self._announced
        kept = self._bids
        refused = []
        for bid in bids:
            key = (bid.job, bid.robot)
            if bid.job not in announced:
                refused.append((bid, "job not announced this round"))
            elif bid.robot not in asked:
                refused.append((bid, "robot not asked of this agent this round"))
            elif key in kept:
                refused.append((bid, "second bid for the same job and robot"))
            else:
                kept[key] = bid
        if refused:
            self.stats["bids_rejected"] += len(refused)
            # One line per ACT, not per bid: a confused agent may send hundreds.
            self.log.warning(
                "exchange: tick %d: dropped %d bids of agent %s, e.g. job %s robot %s: %s",
                self._tick,
                len(refused),
                agent.name,
                refused[0][0].job,
                refused[0][0].robot,
                refused[0][1],
            )

    def _take_handbacks(self, agent: _Agent, handbacks: list[Handback]) -> None:
        kept = self._handbacks
        for h in handbacks:
            key = (h.robot, h.job)
            if h.robot not in agent.robots:
                why = "robot not hosted by this agent"
            elif key in kept:
                why = "handed back twice"
            else:
                kept[key] = h
                continue
            self.stats["handbacks_rejected"] += 1
            self.log.warning(
                "exchange: tick %d: dropped handback of job %s by robot %s from agent %s: %s",
                self._tick,
                h.job,
                h.robot,
                agent.name,
                why,
            )

    def _bye(self, agent: _Agent, msg: Message) -> None:
        reason = msg.body["reason"]
        self.log.info("exchange: agent %s left: %s", agent.name, reason)
        robots = tuple(sorted(agent.robots))
        self._forget(agent)
        self._events.append(BusEvent(BusEventKind.LEFT, agent.name, robots, reason))

    def _forget(self, agent: _Agent) -> None:
        self._agents.pop(agent.identity, None)
        if self._names.get(agent.name) is agent:
            del self._names[agent.name]
        for robot in agent.robots:
            if self._owner.get(robot) is agent:
                del self._owner[robot]
        asked = self._pending.pop(agent.identity, None)
        if asked:
            self._missing += len(asked)

    def _reject(self, identity: bytes, why: str) -> None:
        self.stats["messages_rejected"] += 1
        agent = self._agents.get(identity)
        peer = repr(agent.name) if agent is not None else f"peer {identity.hex()}"
        self.log.warning("exchange: dropped message from %s: %s", peer, why)

    # -- sending ------------------------------------------------------------------------------
    def _send(self, agent: _Agent, kind: MessageKind, body: dict) -> bool:
        raw = encode(kind, self.name, max(self._tick, 0), body)
        error = self._send_raw(agent.identity, raw, agent.name)
        if not error:
            return True
        if error == errno.EHOSTUNREACH:
            # No connection carries its routing id any more: stop routing its robots to it.
            self._declare_lost(agent, "unreachable: no connection carries its routing id")
            self._lost[agent.identity] = agent.name
        # Otherwise (EAGAIN: its queue is full) it is behind but there: it keeps its robots and
        # only misses this round.
        return False

    def _send_raw(self, identity: bytes, raw: bytes, name: str) -> int:
        """Send one message; 0 on success, else the ZeroMQ errno (counted and logged)."""
        try:
            self.socket.send_multipart((identity, raw), _NOBLOCK)
        except zmq.ZMQError as exc:
            self.stats["send_failures"] += 1
            self.log.warning("exchange: could not send to agent %s: %s", name, exc)
            return exc.errno
        self.stats["messages_sent"] += 1
        return 0

    # -- shutting down ------------------------------------------------------------------------
    def close(self) -> None:
        """Say BYE to every agent, close the local hosts, the socket and the CurveZMQ
        authenticator. Idempotent.

        Agents dropped as unreachable are told too, in case they have reconnected since, so
        that their `AgentHost.serve` returns.
        """
        if self.closed:
            return
        raw = encode(MessageKind.BYE, self.name, max(self._tick, 0), {"reason": "run finished"})
        for agent in list(self._agents.values()):
            self._send_raw(agent.identity, raw, agent.name)
        for identity, name in self._lost.items():
            try:
                self.socket.send_multipart((identity, raw), _NOBLOCK)
            except zmq.ZMQError as exc:  # most likely still gone: nothing more to do
                self.log.debug("exchange: no BYE for lost agent %s: %s", name, exc)
        for host in self._locals:
            while host.pump(0):
                pass
            host.close()
        self.socket.close()
        if self._auth is not None:
            self._auth.stop()
            self._auth = None
        self.closed = True

    def __enter__(self) -> Exchange:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<Exchange {self.address}: {len(self._agents)} agents, {len(self._owner)} robots>"


def _robot_of(obs: Observation) -> str:
    return obs.robot
