"""The exchange's I/O: its ROUTER socket and the in-process hosts it pumps itself.

Frames are taken in a batch at a time (`Router.take_in`), so that a flood cannot keep a pass,
and the deadline check after it, from ending. Each message is checked before it is passed on:
a well-formed HELLO from anyone, any other kind only from a known agent on its own connection
(which refreshes its last-seen time); the rest is counted, logged and dropped, and counted
against the connection it came on (`fleet.bus.ledger`): a peer that keeps sending junk is cut
off, and a known agent cut off is lost. Messages go out without blocking, and a failure, or a
message longer than the bus's limit, is counted and logged, never raised (`Router.send`).
"""

from __future__ import annotations

import errno
import logging
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import zmq

from fleet.bus.ledger import CUT_OFF_AFTER, Junk, PeerLedger
from fleet.bus.roster import Member, Roster
from fleet.bus.schema import MAX_MESSAGE_BYTES, Message, MessageKind, decode
from fleet.bus.transport import bind_router
from fleet.errors import MessageError

if TYPE_CHECKING:
    from fleet.bus.agent import AgentHost
    from fleet.bus.security import CurveGuard, Refusal, ServerCurve

__all__ = ["Router", "BATCH"]

# Plain ints: pyzmq's enum flags cost microseconds per operation on the hot path.
_EVENTS, _POLLIN, _NOBLOCK = int(zmq.EVENTS), int(zmq.POLLIN), int(zmq.NOBLOCK)
_EXPECT = (MessageKind.HELLO, MessageKind.ACT, MessageKind.HEARTBEAT, MessageKind.BYE)

#: Messages taken from the ROUTER per pass (`Router.take_in`).
BATCH = 256


class Router:
    """A bound ROUTER socket (with its CurveZMQ gatekeeper) and the local hosts it pumps.

    Parameters
    ----------
    context:
        The ZeroMQ context.
    address:
        Where to bind (see `fleet.bus.transport.bind_router`).
    curve:
        CurveZMQ server keys, or None.
    roster:
        The agents the exchange knows: who may send what.
    on_hello:
        Called with the routing id and the message of each valid HELLO.
    on_message:
        Called with the sending agent and the message of each other valid message.
    on_cut_off:
        Called with a known agent that the ledger has just cut off (the exchange loses it).
    stats:
        The exchange's counters (`EXCHANGE_STATS`); messages received, rejected, ignored,
        sent and not sent, and peers cut off, are counted into them.
    log:
        Where dropped messages and failed sends are logged.
    max_message_bytes:
        Longest message taken in (the socket's ``MAXMSGSIZE`` and `decode`'s limit) or sent.
    cut_off_after:
        Refused messages after which a peer is cut off (`fleet.bus.ledger`).

    Attributes
    ----------
    socket:
        The ROUTER.
    address:
        The bound address.
    hosts:
        The in-process hosts (`Exchange.add_local`), pumped and closed with the router.
    ledger:
        The refusals per peer, and who is cut off.
    """

    def __init__(
        self,
        context: zmq.Context,
        address: str,
        curve: ServerCurve | None,
        *,
        roster: Roster,
        on_hello: Callable[[bytes, Message], None],
        on_message: Callable[[Member, Message], None],
        on_cut_off: Callable[[Member], None],
        stats: dict[str, int],
        log: logging.Logger,
        max_message_bytes: int = MAX_MESSAGE_BYTES,
        cut_off_after: int = CUT_OFF_AFTER,
    ) -> None:
        self.stats = stats
        self.log = log
        self.hosts: list[AgentHost] = []
        self.max_message_bytes = max_message_bytes
        self.ledger = PeerLedger(stats, log, cut_off_after=cut_off_after)
        self._roster = roster
        self._on_hello = on_hello
        self._on_message = on_message
        self._on_cut_off = on_cut_off
        self._guard: CurveGuard | None = None
        limit = max_message_bytes
        if curve is None:
            self.socket, self.address = bind_router(context, address, max_message_bytes=limit)
        else:
            # The authenticator must be answering before the first handshake.
            self._guard = curve.start(context, log)
            try:
                self.socket, self.address = bind_router(
                    context, address, curve=curve, log=log, max_message_bytes=limit
                )
            except BaseException:
                self._guard.stop()
                raise

    # -- receiving ----------------------------------------------------------------------------
    def take_in(self) -> int:
        """Handle up to `BATCH` messages waiting at the ROUTER; how many there were."""
        sock = self.socket
        handled = 0
        # Asking for EVENTS is much cheaper than a recv that fails with zmq.Again.
        while handled < BATCH and sock.getsockopt(_EVENTS) & _POLLIN:
            try:
                frames = sock.recv_multipart(_NOBLOCK)
            except zmq.Again:
                break
            handled += 1
            self._handle(frames)
        return handled

    def _handle(self, frames: list[bytes]) -> None:
        self.stats["messages_received"] += 1
        identity = frames[0]
        if self.ledger.ignores(identity):
            return
        if len(frames) != 2:
            why = f"{len(frames) - 1} frames after the routing id, expected 1"
            self.reject(identity, why, Junk.FRAMES)
            return
        try:
            msg = decode(frames[1], _EXPECT, max_bytes=self.max_message_bytes)
        except MessageError as exc:
            junk = Junk.OVERSIZED if len(frames[1]) > self.max_message_bytes else Junk.MALFORMED
            self.reject(identity, str(exc), junk)
            return
        if msg.kind is MessageKind.HELLO:
            self._on_hello(identity, msg)
            return
        member = self._roster.members.get(identity)
        if member is None:
            why = f"{msg.kind.name} from unknown sender {msg.sender!r} (no HELLO)"
            self.reject(identity, why, Junk.STRANGER)
            return
        if msg.sender != member.name:
            why = f"{msg.kind.name} from {msg.sender!r} on the connection of agent {member.name!r}"
            self.reject(identity, why, Junk.IMPOSTOR)
            return
        member.seen = time.monotonic()
        self._on_message(member, msg)

    def reject(self, identity: bytes, why: str, junk: Junk | None = None) -> None:
        """Drop a message from `identity` (counted and logged) for the reason `why`.

        `junk` says how it counts against the peer (None: not at all, as for a late ACT; it
        is then logged at warning level every time).
        """
        self.stats["messages_rejected"] += 1
        member = self._roster.members.get(identity)
        peer = f"agent {member.name!r}" if member is not None else f"peer {identity.hex()[:64]}"
        if junk is None:
            self.log.warning("exchange: dropped message from %s: %s", peer, why)
        elif self.ledger.charge(identity, peer, junk, why) and member is not None:
            self._on_cut_off(member)

    def pump_hosts(self) -> bool:
        """Let local hosts handle what is waiting; True if any handled something."""
        progressed = False
        for host in self.hosts:
            while host.pump(0):
                progressed = True
        return progressed

    def poll(self, remaining_s: float) -> None:
        """Sleep until the ROUTER or a local host has something, at most `remaining_s`."""
        poller = zmq.Poller()
        poller.register(self.socket, zmq.POLLIN)
        for host in self.hosts:
            if not host.closed:
                poller.register(host.socket, zmq.POLLIN)
        poller.poll(max(1, math.ceil(remaining_s * 1000)))

    def take_refusals(self) -> list[Refusal]:
        """The clients the CurveZMQ gatekeeper turned away since the last call."""
        return self._guard.take_refusals() if self._guard is not None else []

    # -- sending ------------------------------------------------------------------------------
    def send(self, identity: bytes, raw: bytes, name: str) -> int:
        """Send one message to agent `name`; 0 on success, else the ZeroMQ errno (counted
        and logged). A message longer than `max_message_bytes` is not sent (EMSGSIZE): the
        agent's socket would drop the connection rather than take it in."""
        if len(raw) > self.max_message_bytes:
            self.stats["send_failures"] += 1
            self.log.error(
                "exchange: not sent to agent %s: a message of %d bytes, over the bus's limit of"
                " %d (raise the scenario's [bus] max_message_bytes, or spread the robots over"
                " more agents)",
                name,
                len(raw),
                self.max_message_bytes,
            )
            return errno.EMSGSIZE
        try:
            self.socket.send_multipart((identity, raw), _NOBLOCK)
        except zmq.ZMQError as exc:
            self.stats["send_failures"] += 1
            self.log.warning("exchange: could not send to agent %s: %s", name, exc)
            return exc.errno
        self.stats["messages_sent"] += 1
        return 0

    def send_to_lost(self, identity: bytes, raw: bytes, name: str) -> None:
        """Send a BYE to an agent already dropped: not counted, a failure only debug-logged
        (it is most likely still gone: nothing more to do)."""
        try:
            self.socket.send_multipart((identity, raw), _NOBLOCK)
        except zmq.ZMQError as exc:
            self.log.debug("exchange: no BYE for lost agent %s: %s", name, exc)

    def wake(self) -> None:
        """Make the ROUTER take in the connections made since its last call, so that a
        reconnected agent is routable (a send may skip that when calls come quickly)."""
        self.socket.getsockopt(_EVENTS)

    # -- shutting down ------------------------------------------------------------------------
    def close(self) -> None:
        """Close the local hosts (after they handled what is waiting), the socket and the
        gatekeeper."""
        for host in self.hosts:
            while host.pump(0):
                pass
            host.close()
        self.socket.close()
        if self._guard is not None:
            self._guard.stop()
            self._guard = None
