"""An agent's connection to the exchange: its DEALER socket, messages in and out.

Messages go out without blocking; one that cannot go is logged (a heartbeat only at debug
level: it is retried soon anyway) and dropped. Coming in, malformed or unexpected messages are
counted, logged and dropped. Only the newest OBSERVE matters: the exchange has given up on
older ticks by the time a newer one is queued, so after a stall the link passes on the newest
and skips the rest (counted as ``skipped``) instead of having every abandoned tick computed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import zmq

from fleet.bus.schema import MAX_MESSAGE_BYTES, Message, MessageKind, decode, encode
from fleet.bus.transport import connect_dealer
from fleet.errors import MessageError

if TYPE_CHECKING:
    from fleet.bus.security import ClientCurve

__all__ = ["Link"]

# Plain ints: pyzmq's enum flags cost microseconds per operation on the hot path.
_EVENTS, _POLLIN, _NOBLOCK = int(zmq.EVENTS), int(zmq.POLLIN), int(zmq.NOBLOCK)
_EXPECT = (MessageKind.WELCOME, MessageKind.OBSERVE, MessageKind.BYE)


class Link:
    """The DEALER socket of agent `name`, connected to the exchange at `address`.

    Parameters
    ----------
    context, address, identity, curve:
        As for `fleet.bus.transport.connect_dealer`.
    name:
        The agent's name: the ``sender`` of its messages, and in the logs.
    stats:
        The host's counters (`AGENT_STATS`); messages received, rejected, skipped and sent
        are counted into them.
    log:
        Where dropped messages and failed sends are logged.
    max_message_bytes:
        Longest message taken in (the socket's ``MAXMSGSIZE`` and `decode`'s limit) or sent.

    Attributes
    ----------
    socket:
        The DEALER.
    last_sent:
        time.monotonic() of the latest message sent (of the link's creation before the first).
    """

    def __init__(
        self,
        context: zmq.Context,
        address: str,
        identity: bytes,
        curve: ClientCurve | None,
        *,
        name: str,
        stats: dict[str, int],
        log: logging.Logger,
        max_message_bytes: int = MAX_MESSAGE_BYTES,
    ) -> None:
        self.name = name
        self.stats = stats
        self.log = log
        self.max_message_bytes = max_message_bytes
        self.last_sent = time.monotonic()
        self.socket = connect_dealer(
            context, address, identity, curve=curve, max_message_bytes=max_message_bytes
        )

    def receive(self, timeout_ms: int | None, handle: Callable[[Message], None]) -> bool:
        """Pass one incoming message to `handle`, waiting up to `timeout_ms` (None: forever).

        If it is an OBSERVE, first take in everything queued behind it: only the newest OBSERVE
        is passed on (the older ones are counted as ``skipped``), other messages in their
        order. Returns True if a message was received (whether passed on or dropped), False
        if none came in time.
        """
        sock = self.socket
        if timeout_ms == 0:
            # Asking for EVENTS is much cheaper than a recv that fails with zmq.Again.
            if not sock.getsockopt(_EVENTS) & _POLLIN:
                return False
        elif not sock.poll(timeout_ms, zmq.POLLIN):
            return False
        try:
            frames = sock.recv_multipart(_NOBLOCK)
        except zmq.Again:
            return False
        msg = self._read(frames)
        if msg is None:
            return True
        if msg.kind is not MessageKind.OBSERVE:
            handle(msg)
            return True
        # The exchange has given up on an OBSERVE once a newer one is queued: after a stall,
        # answering each in turn would only keep the host behind.
        batch = [msg]
        while sock.getsockopt(_EVENTS) & _POLLIN:
            try:
                frames = sock.recv_multipart(_NOBLOCK)
            except zmq.Again:
                break
            queued = self._read(frames)
            if queued is not None:
                batch.append(queued)
        if len(batch) == 1:
            handle(msg)
            return True
        newest: dict[str, Message] = {}  # by sender: a stranger must not displace the exchange
        for queued in batch:
            if queued.kind is MessageKind.OBSERVE:
                newest[queued.sender] = queued
        for queued in batch:
            if queued.kind is MessageKind.OBSERVE and newest[queued.sender] is not queued:
                self.stats["skipped"] += 1
                self.log.debug(
                    "agent %s: skipped OBSERVE for tick %d: a newer one is queued",
                    self.name,
                    queued.tick,
                )
            else:
                handle(queued)
        return True

    def _read(self, frames: list[bytes]) -> Message | None:
        """The message in `frames`, or None if it was rejected (counted and logged)."""
        self.stats["messages_received"] += 1
        if len(frames) != 1:
            self.reject(f"{len(frames)} frames, expected 1")
            return None
        try:
            return decode(frames[0], _EXPECT, max_bytes=self.max_message_bytes)
        except MessageError as exc:
            self.reject(str(exc))
            return None

    def reject(self, why: str) -> None:
        """Drop a message (counted and logged) for the reason `why`."""
        self.stats["messages_rejected"] += 1
        self.log.warning("agent %s: dropped message: %s", self.name, why)

    def send(self, kind: MessageKind, tick: int, body: dict) -> None:
        """Send one message, or log why it could not go."""
        raw = encode(kind, self.name, tick, body)
        if len(raw) > self.max_message_bytes:
            # The exchange's socket would drop the connection rather than read it.
            self.log.error(
                "agent %s: %s not sent: %d bytes, over the bus's limit of %d (raise the"
                " scenario's [bus] max_message_bytes, or spread the robots over more agents)",
                self.name,
                kind.name,
                len(raw),
                self.max_message_bytes,
            )
            return
        try:
            self.socket.send(raw, _NOBLOCK)
        except zmq.ZMQError as exc:
            # A heartbeat that cannot go out (the exchange gone or far behind) is retried soon
            # anyway: not worth a warning every heartbeat_s.
            level = logging.DEBUG if kind is MessageKind.HEARTBEAT else logging.WARNING
            self.log.log(level, "agent %s: could not send %s: %s", self.name, kind.name, exc)
            return
        self.last_sent = time.monotonic()
        self.stats["messages_sent"] += 1
