"""The engine side of the bus: one control round trip per tick with every agent.

The engine owns the clock. At each control tick it hands the observations of the robots due
to `Exchange.round`, which sends each agent one OBSERVE holding its robots' observations and
collects one ACT per agent. Local hosts (same process, `Exchange.add_local`) are pumped
synchronously inside `round`, so a single-process run needs no threads and is deterministic;
remote hosts (other threads, processes or machines over ipc/tcp) answer on their own.
`round` is `send` then `collect`: a pipelined engine calls them apart and steps the world while
the agents compute (`[bus] lockstep = "pipelined"`, `fleet.engine.pipeline`).

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

The `Exchange` wires the parts together and holds the counters: the `roster` knows who is
connected and hosts which robot, a `lockstep` round asks the agents and waits for them, its
`answers` keep what is valid of their ACTs, and the `router` reads and sends the frames.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Collection, Sequence
from typing import TYPE_CHECKING

import zmq

from fleet.bus.ledger import CUT_OFF_AFTER, Junk
from fleet.bus.lockstep import Round, announcement_offers
from fleet.bus.roster import BusEvent, BusEventKind, Member, Roster
from fleet.bus.router import Router
from fleet.bus.schema import MAX_MESSAGE_BYTES, Message, MessageKind
from fleet.bus.transport import default_context, new_inproc_address
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
    "peers_cut_off",  # connections cut off for sending junk (fleet.bus.ledger)
    "messages_ignored",  # frames from cut-off connections, dropped unread
)


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
    max_message_bytes:
        Longest message taken in or sent (`fleet.bus.schema.MAX_MESSAGE_BYTES` by default).
        A peer sending a longer one over ipc or tcp is disconnected by ZeroMQ before the
        message is read; one the exchange would send is not sent (logged as an error).
    cut_off_after:
        Refused messages (malformed, oversized, from a stranger or an impostor, refused
        HELLOs) after which a connection is cut off: its messages are dropped unread, and
        an agent on it is lost (`fleet.bus.ledger`).

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
        max_message_bytes: int = MAX_MESSAGE_BYTES,
        cut_off_after: int = CUT_OFF_AFTER,
    ) -> None:
        if type(max_message_bytes) is not int or max_message_bytes < 1024:
            raise ValueError(
                f"exchange max_message_bytes = {max_message_bytes!r}: must be an integer >= 1024"
            )
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
        bind_address = address if address is not None else new_inproc_address()
        self.stats: dict[str, int] = dict.fromkeys(EXCHANGE_STATS, 0)
        self._roster = Roster(scenario, self.stats, self.log)
        self._router = Router(
            self.context,
            bind_address,
            curve,
            roster=self._roster,
            on_hello=self._hello,
            on_message=self._receive,
            on_cut_off=self._cut_off,
            stats=self.stats,
            log=self.log,
            max_message_bytes=max_message_bytes,
            cut_off_after=cut_off_after,
        )
        self.socket = self._router.socket
        self.address = self._router.address
        self.bids: list[Bid] = []
        self.handbacks: list[Handback] = []
        self.closed = False
        self._open = False  # a round was sent and not yet collected
        self._round = self._open_round(-1, frozenset())  # none yet: HELLOs are stamped tick 0

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
        if host not in self._router.hosts:
            host.heartbeat_s = None
            self._router.hosts.append(host)
            self._roster.mark_local(host.identity)

    @property
    def scenario(self) -> str:
        """The fingerprint agents must have been set up for ('': not checked)."""
        return self._roster.scenario

    @property
    def agents(self) -> dict[str, frozenset[str]]:
        """Connected agents by name, with the robots each hosts."""
        return self._roster.agents

    def take_events(self) -> list[BusEvent]:
        """The events since the previous call, oldest first (and forget them).

        The engine drains these after every round, to count faults and hand back the jobs of
        robots that lost their agent. With CurveZMQ, clients the gatekeeper turned away
        appear as REFUSED events with no robots, named by their public key (Z85), or by
        their address when the handshake failed before they showed one.
        """
        for refusal in self._router.take_refusals():
            who = refusal.public_key or refusal.address
            why = f"CURVE: {refusal.reason} (from {refusal.address})"
            self._roster.record(BusEvent(BusEventKind.REFUSED, who, (), why))
        return self._roster.take_events()

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
        roster = self._roster
        roster.expect(robots)
        wait = self.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + wait
        if not roster.uncovered():
            return
        while True:
            progressed = self._pump()
            uncovered = roster.uncovered()
            if not uncovered:
                return
            # Checked on every pass: a stream of messages must not postpone the timeout.
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                shown = sorted(uncovered)
                more = f" and {len(shown) - 10} more" if len(shown) > 10 else ""
                raise MessageError(
                    f"exchange at {self.address}: after {wait:g} s no agent hosts robots"
                    f" {shown[:10]}{more}; connected agents: {sorted(roster.by_name) or 'none'}"
                    " (start their agents, or raise the timeout)"
                )
            if not progressed:
                self._router.poll(remaining)

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
        self.send(tick, t, observations, announcements)
        return self.collect()

    def send(
        self,
        tick: int,
        t: float,
        observations: Sequence[Observation],
        announcements: Sequence[Announcement] = (),
    ) -> None:
        """The first half of `round`: send the OBSERVEs and return at once, the round left
        open; `collect` ends it. The remote agents compute meanwhile (a pipelined lockstep);
        local hosts compute when `collect` pumps them.

        Raises
        ------
        MessageError, ValueError
            As `round`; ValueError also if the previous round was sent and not collected.
        """
        if self.closed:
            raise MessageError(f"exchange at {self.address} is closed")
        if self._open:
            raise ValueError(f"round tick {self._round.tick} was sent and not collected")
        if type(tick) is not int or tick <= self._round.tick:
            raise ValueError(f"round tick = {tick!r}: must be an integer > {self._round.tick}")
        announced, offers = announcement_offers(tick, announcements)
        self._round = this = self._open_round(tick, frozenset(announced))
        self.stats["rounds"] += 1
        # What queued up since the last round first: a BYE makes its agent "left" rather than
        # unreachable, a HELLO (rejoin) has its robots served in this very round.
        self._router.take_in()
        this.ask(t, observations, offers)
        self._open = True

    @property
    def outstanding(self) -> bool:
        """Whether a round was sent (`send`) and not yet collected."""
        return self._open

    def collect(self) -> dict[str, Command]:
        """The second half of `round`: wait for the answers to the round `send` opened and
        return its commands (see `round`); bids and handbacks are then in `bids` and
        `handbacks`. The remote agents' `timeout_s` counts from this call.

        Raises
        ------
        MessageError
            If the exchange is closed.
        ValueError
            If no round is open.
        """
        if self.closed:
            raise MessageError(f"exchange at {self.address} is closed")
        if not self._open:
            raise ValueError("no round to collect: send one first")
        this = self._round
        self._open = False
        this.wait(self.timeout_s, self.lost_after_s)
        self.stats["commands_missing"] += this.missing
        self.bids = this.answers.bids()
        self.handbacks = this.answers.handbacks()
        self.stats["bids"] += len(self.bids)
        self.stats["handbacks"] += len(self.handbacks)
        return this.answers.commands()

    def _open_round(self, tick: int, announced: frozenset[str]) -> Round:
        return Round(tick, announced, roster=self._roster, router=self._router, sender=self.name)

    # -- receiving ----------------------------------------------------------------------------
    def _pump(self) -> bool:
        """Let local hosts handle what is waiting, then handle what reached the ROUTER."""
        progressed = self._router.pump_hosts()
        return self._router.take_in() > 0 or progressed

    def _hello(self, identity: bytes, msg: Message) -> None:
        name = msg.sender
        admission = self._roster.admit(identity, name, msg.body["robots"], msg.body["scenario"])
        body = {"accepted": admission.accepted, "rejected": admission.rejected}
        self._router.send(identity, self._round.message(MessageKind.WELCOME, body), name)
        if identity in self._roster.members:
            if admission.rejected:
                self.log.warning("exchange: agent %s may not host %s", name, admission.refused)
            return
        # An agent that hosts nothing here (set up for another scenario, or its robots hosted
        # already) can do no good: told to stop rather than wait for ever. The ledger logs it
        # (once per peer at warning level) and cuts off a peer that keeps saying such HELLOs.
        reason = admission.refusal or "none of its robots can be hosted here"
        self._router.send(identity, self._round.message(MessageKind.BYE, {"reason": reason}), name)
        claimed = len(msg.body["robots"])
        why = f"HELLO refused ({claimed} robots claimed): {admission.refused or 'none'}"
        self._router.ledger.charge(identity, f"peer {name!r}", Junk.REFUSED, why)

    def _cut_off(self, member: Member) -> None:
        """A known agent sent junk until cut off: it is lost, its robots unhosted."""
        why = f"cut off after {self._router.ledger.cut_off_after} refused messages"
        self._round.declare_lost(member, why)
        self._router.send_to_lost(
            member.identity, self._round.message(MessageKind.BYE, {"reason": why}), member.name
        )

    def _receive(self, member: Member, msg: Message) -> None:
        kind = msg.kind
        if kind is MessageKind.ACT:
            why = self._round.take_act(member, msg)
            if why is not None:
                self._router.reject(member.identity, why)
        elif kind is MessageKind.HEARTBEAT:
            self.stats["heartbeats"] += 1
        else:
            self._roster.leave(member, msg.body["reason"])
            self._round.drop(member.identity)

    # -- shutting down ------------------------------------------------------------------------
    def close(self) -> None:
        """Say BYE to every agent, close the local hosts, the socket and the CurveZMQ
        authenticator. Idempotent.

        Agents dropped as unreachable are told too, in case they have reconnected since, so
        that their `AgentHost.serve` returns.
        """
        if self.closed:
            return
        bye = self._round.message(MessageKind.BYE, {"reason": "run finished"})
        for member in list(self._roster.members.values()):
            self._router.send(member.identity, bye, member.name)
        for identity, name in self._roster.unreachable.items():
            self._router.send_to_lost(identity, bye, name)
        self._router.close()
        self.closed = True

    def __enter__(self) -> Exchange:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        roster = self._roster
        return (
            f"<Exchange {self.address}: {len(roster.members)} agents, {len(roster.owner)} robots>"
        )
