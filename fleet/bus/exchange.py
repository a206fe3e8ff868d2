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
"""

from __future__ import annotations

import errno
import logging
import math
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import zmq

from fleet.bus.schema import Message, MessageKind, decode, encode, observation_to_wire
from fleet.bus.transport import bind_router, default_context, new_inproc_address
from fleet.errors import MessageError
from fleet.plugins import Command, Observation

if TYPE_CHECKING:
    from fleet.bus.agent import AgentHost

__all__ = ["Exchange", "EXCHANGE_STATS"]

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
)

# Plain ints: pyzmq's enum flags cost microseconds per operation on the hot path.
_EVENTS, _POLLIN, _NOBLOCK = int(zmq.EVENTS), int(zmq.POLLIN), int(zmq.NOBLOCK)
_EXPECT = (MessageKind.HELLO, MessageKind.ACT, MessageKind.BYE)
# Messages taken from the ROUTER per pass, so that a flood cannot keep a pass (and the deadline
# check after it) from ending.
_BATCH = 256


@dataclass(eq=False)
class _Agent:
    identity: bytes
    name: str
    robots: set[str] = field(default_factory=set)


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
        How long `round` waits for answers before giving up on the missing ones.
    log:
        Logger; default ``fleet.bus``.
    name:
        The exchange's ``sender`` name in messages.

    Attributes
    ----------
    address:
        The bound address, for agents to connect to.
    stats:
        Counters named in `EXCHANGE_STATS`.
    """

    def __init__(
        self,
        address: str | None = None,
        *,
        context: zmq.Context | None = None,
        timeout_s: float = 10.0,
        log: logging.Logger | None = None,
        name: str = "exchange",
    ) -> None:
        if not (isinstance(timeout_s, int | float) and math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"exchange timeout_s = {timeout_s!r}: must be a positive number")
        self.context = context if context is not None else default_context()
        self.timeout_s = float(timeout_s)
        self.log = log if log is not None else logging.getLogger("fleet.bus")
        self.name = name
        self.socket, self.address = bind_router(
            self.context, address if address is not None else new_inproc_address()
        )
        self.stats: dict[str, int] = dict.fromkeys(EXCHANGE_STATS, 0)
        self.closed = False
        self._locals: list[AgentHost] = []
        self._agents: dict[bytes, _Agent] = {}  # by ZeroMQ routing id (the agent's name)
        self._names: dict[str, _Agent] = {}
        self._lost: dict[bytes, str] = {}  # agents dropped as unreachable; told BYE on close
        self._owner: dict[str, _Agent] = {}  # robot -> hosting agent
        self._expected: frozenset[str] | None = None
        self._tick = -1
        self._pending: dict[bytes, set[str]] = {}  # agents yet to answer this round
        self._results: dict[str, Command] = {}
        self._missing = 0

    # -- set-up -------------------------------------------------------------------------------
    def add_local(self, host: AgentHost) -> None:
        """Adopt an in-process host: `round` pumps it synchronously and `close` closes it.

        The host must have been created with this exchange's `address` and context.
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
            self._locals.append(host)

    @property
    def agents(self) -> dict[str, frozenset[str]]:
        """Connected agents by name, with the robots each hosts."""
        return {a.name: frozenset(a.robots) for a in self._names.values()}

    def wait_for_agents(self, robots: Collection[str], timeout_s: float | None = None) -> None:
        """Accept agents until every robot in `robots` is hosted by one of them.

        HELLOs are answered with WELCOME; a robot claimed by a second agent, or not in
        `robots` (nor in an earlier call's), is refused and logged; so is every robot of an
        agent whose name another agent already uses.

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
    def round(self, tick: int, t: float, observations: Sequence[Observation]) -> dict[str, Command]:
        """Send this tick's observations to the agents and collect their commands.

        Parameters
        ----------
        tick:
            The control tick; must increase from round to round.
        t:
            Simulation time of the tick (s).
        observations:
            One per robot due this tick (robot ids unique).

        Returns
        -------
        dict
            Robot id to command, sorted by robot id, for every observed robot whose agent
            answered validly in time (local hosts always are; remote ones within `timeout_s`
            after the local hosts have answered); the others are absent and counted in
            ``stats["commands_missing"]``.
        """
        if self.closed:
            raise MessageError(f"exchange at {self.address} is closed")
        if type(tick) is not int or tick <= self._tick:
            raise ValueError(f"round tick = {tick!r}: must be an integer > {self._tick}")
        self._tick = tick
        self.stats["rounds"] += 1
        self._results = {}
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
        # Asking for EVENTS makes the ROUTER take in connections made since its last call (a
        # send may skip that when calls come quickly), so a reconnected agent is routable.
        self.socket.getsockopt(_EVENTS)
        for agent, wire in groups.items():
            body = {"t": float(t), "observations": wire}
            if self._send(agent, MessageKind.OBSERVE, body):
                self._pending[agent.identity] = robots[agent]
            else:
                self._missing += len(robots[agent])
        self._pump_locals(tick)
        self._collect(time.monotonic() + self.timeout_s)
        self.stats["commands_missing"] += self._missing
        results = self._results
        self._results = {}
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
        """Handle answers until none is outstanding or `deadline` (time.monotonic) passes."""
        while self._pending:
            progressed = self._pump()
            if not self._pending:
                return
            # Checked on every pass: a stream of messages must not postpone the timeout.
            remaining = deadline - time.monotonic()
            if remaining <= 0:
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
                return
            if not progressed:
                self._poll(remaining)

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
        return handled > 0

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
        if msg.kind is MessageKind.ACT:
            self._act(agent, msg)
        else:
            self._bye(agent, msg)

    def _hello(self, identity: bytes, msg: Message) -> None:
        name = msg.sender
        claimed = msg.body["robots"]
        agent = self._agents.get(identity)
        by_name = self._names.get(name)
        reason = None
        if agent is not None and agent.name != name:
            reason = f"this connection already introduced itself as {agent.name!r}"
        elif by_name is not None and by_name is not agent:
            reason = f"another agent is already called {name!r}"
        accepted: list[str] = []
        rejected: dict[str, str] = {}
        if reason is not None:
            rejected = dict.fromkeys(claimed, reason)
        else:
            if agent is None:
                agent = _Agent(identity, name)
                self._agents[identity] = agent
                self._names[name] = agent
                self._lost.pop(identity, None)
            for robot in claimed:
                owner = self._owner.get(robot)
                if self._expected is not None and robot not in self._expected:
                    rejected[robot] = "unknown robot: not part of this run"
                elif owner is not None and owner is not agent:
                    rejected[robot] = f"already hosted by agent {owner.name!r}"
                else:
                    accepted.append(robot)
                    agent.robots.add(robot)
                    self._owner[robot] = agent
        self.stats["robots_rejected"] += len(rejected)
        for robot, why in rejected.items():
            self.log.warning("exchange: agent %s may not host robot %s: %s", name, robot, why)
        self.log.debug("exchange: agent %s hosts %d robots", name, len(accepted))
        body = {"accepted": accepted, "rejected": rejected}
        raw = encode(MessageKind.WELCOME, self.name, max(self._tick, 0), body)
        self._send_raw(identity, raw, name)

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

    def _bye(self, agent: _Agent, msg: Message) -> None:
        self.log.info("exchange: agent %s left: %s", agent.name, msg.body["reason"])
        self._forget(agent)

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
            self._forget(agent)
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
        """Say BYE to every agent, close the local hosts and the socket. Idempotent.

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
        self.closed = True

    def __enter__(self) -> Exchange:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<Exchange {self.address}: {len(self._agents)} agents, {len(self._owner)} robots>"


def _robot_of(obs: Observation) -> str:
    return obs.robot
