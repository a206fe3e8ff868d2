"""Thin wrappers over pyzmq: address checking and the two socket roles of the bus.

The engine's `Exchange` binds a ROUTER; every `AgentHost` connects a DEALER to it. Three
transports are supported, all with the same classes:

``inproc://<name>``
    Within one process (and one `zmq.Context`); the default, used with synchronous pumping.
``ipc://<path>``
    Between processes on one machine, through a Unix socket file (path at most 107 bytes); an
    absolute path gives three slashes, ``ipc:///tmp/fleet.sock``.
``tcp://<host>:<port>``
    Between machines. The host is a name, an IPv4 address or a bracketed IPv6 address
    (``tcp://[::1]:5555``). When binding, the port may be ``*`` (or 0) to let the system choose;
    the chosen one is reported by `bind_router`.

inproc only works when both ends share one `zmq.Context`: use `default_context()` (the
process-wide ``zmq.Context.instance()``) on both sides. Either end may come first (libzmq
queues a connect until the bind arrives; checked with libzmq 4.3.5).

Every DEALER carries a fixed routing id (the agent's name), so the ROUTER knows an agent again
after ZeroMQ re-establishes a dropped connection; the ROUTER hands the id over to the newest
connection (``ROUTER_HANDOVER``).

Over ipc and tcp the bus can be secured with CurveZMQ (`fleet.bus.security`): `bind_router`
takes the engine's `ServerCurve`, `connect_dealer` an agent's `ClientCurve`. Connections are
then encrypted and only authorised agents get through; the others are refused, logged and
counted by the ROUTER's `CurveGuard` (``socket.curve_guard``). inproc has no security
handshake in libzmq, so keys there are refused rather than silently ignored.
"""

from __future__ import annotations

import itertools
import logging
import os
import re
from dataclasses import dataclass

import zmq

from fleet.bus.schema import MAX_MESSAGE_BYTES
from fleet.bus.security import ClientCurve, CurveGuard, ServerCurve
from fleet.errors import MessageError

__all__ = [
    "AddressError",
    "Address",
    "parse_address",
    "new_inproc_address",
    "default_context",
    "bind_router",
    "connect_dealer",
    "GuardedSocket",
    "LINGER_MS",
    "ROUTING_ID_MAX",
    "ROUTER_RECEIVE_QUEUE",
]

#: How long a closed socket keeps trying to deliver queued messages (e.g. a final BYE).
LINGER_MS = 1000

#: Longest routing id ZeroMQ accepts (bytes); an agent's name, UTF-8 encoded, is its routing id.
ROUTING_ID_MAX = 255

#: Unread messages the exchange's ROUTER queues per connection (ZeroMQ's ``RCVHWM``).
ROUTER_RECEIVE_QUEUE = 100

_ALLOWED = "use 'inproc://<name>', 'ipc://<path>' or 'tcp://<host>:<port>'"
# sockaddr_un.sun_path holds 108 bytes including the terminating NUL.
_IPC_PATH_MAX = 107
_HOST = re.compile(r"^(\*|\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+)$")
_inproc_ids = itertools.count(1)


class AddressError(MessageError, ValueError):
    """A bus address is malformed, unsupported, or cannot be bound or connected.

    Derives from `ValueError` too, so code validating a configuration value may catch either.
    """


@dataclass(frozen=True, slots=True)
class Address:
    """A checked bus address: `transport` is ``inproc``, ``ipc`` or ``tcp``."""

    transport: str
    target: str

    @property
    def ipv6(self) -> bool:
        """Whether this is tcp to a bracketed IPv6 literal (the socket needs ``zmq.IPV6``)."""
        return self.transport == "tcp" and self.target.startswith("[")

    def __str__(self) -> str:
        return f"{self.transport}://{self.target}"


def parse_address(address: str, *, bind: bool = False) -> Address:
    """Check a bus address and split it.

    Parameters
    ----------
    address:
        ``inproc://<name>``, ``ipc://<path>`` or ``tcp://<host>:<port>``.
    bind:
        Whether the address is for binding: only then may a tcp host or port be ``*`` (a tcp
        port may also be 0).

    Raises
    ------
    AddressError
        Quoting the address and saying what is allowed.
    """

    def bad(rule: str) -> AddressError:
        return AddressError(f"bus address {address!r}: {rule}; {_ALLOWED}")

    if not isinstance(address, str):
        raise bad("must be a string")
    transport, sep, target = address.partition("://")
    if not sep or not target:
        raise bad("must look like '<transport>://<target>'")
    if any(c.isspace() for c in address):
        raise bad("must not contain whitespace")
    if transport == "inproc":
        return Address(transport, target)
    if transport == "ipc":
        if target == "*":
            raise bad("ipc needs an explicit socket path")
        if len(os.fsencode(target)) > _IPC_PATH_MAX:
            raise bad(
                f"the ipc path is {len(os.fsencode(target))} bytes long, the system allows at"
                f" most {_IPC_PATH_MAX}; choose a shorter path"
            )
        return Address(transport, target)
    if transport == "tcp":
        host, colon, port = target.rpartition(":")
        if not colon or not host:
            raise bad("tcp needs '<host>:<port>'")
        if not _HOST.match(host):
            raise bad(f"tcp host {host!r} is not a host name, IPv4 address or [IPv6] address")
        if host == "*" and not bind:
            raise bad("tcp host '*' is only allowed when binding; connect to a real host")
        if port == "*" or port == "0":
            if not bind:
                raise bad(f"tcp port {port!r} is only allowed when binding; give the real port")
            return Address(transport, target)
        if not port.isdigit() or not 1 <= int(port) <= 65535:
            raise bad(f"tcp port {port!r} must be an integer in 1..65535")
        return Address(transport, target)
    raise bad(f"transport {transport!r} is not supported")


def new_inproc_address() -> str:
    """A fresh ``inproc://fleet-<n>`` address, unique within this process."""
    return f"inproc://fleet-{next(_inproc_ids)}"


def default_context() -> zmq.Context:
    """The process-wide ZeroMQ context (required to be shared for inproc)."""
    return zmq.Context.instance()


class GuardedSocket(zmq.Socket):
    """A ROUTER bound with CURVE keys: it holds its `CurveGuard` and stops it when closed.

    The guard (the ZAP handler that refuses unauthorised agents) thus lives exactly as long
    as the socket needs it; a CURVE server left without one would admit any client.
    """

    #: The guard enforcing the socket's `ServerCurve`; None once the socket is closed.
    curve_guard: CurveGuard | None = None

    def close(self, linger: int | None = None) -> None:
        """Close the socket, then stop its guard."""
        try:
            super().close(linger=linger)
        finally:
            guard, self.curve_guard = self.curve_guard, None
            if guard is not None:
                guard.stop()


def bind_router(
    context: zmq.Context,
    address: str,
    *,
    curve: ServerCurve | None = None,
    log: logging.Logger | None = None,
    max_message_bytes: int = MAX_MESSAGE_BYTES,
) -> tuple[zmq.Socket, str]:
    """A ROUTER socket bound to `address`, and the address actually bound (port resolved).

    The socket reports unroutable sends (``ROUTER_MANDATORY``: EHOSTUNREACH for an unknown
    peer, EAGAIN for a full queue) instead of dropping them, so the exchange notices agents that
    have gone; a reconnecting agent takes its routing id over (``ROUTER_HANDOVER``).

    Parameters
    ----------
    context:
        The ZeroMQ context.
    address:
        Where to bind (see `parse_address`).
    curve:
        The engine's CURVE keys; None for no security. With keys the socket is a
        `GuardedSocket`: a `CurveGuard` (started on `context` before the bind, so that no
        client slips in unchecked) admits only the authorised agents and stops when the socket
        is closed. Only for ipc and tcp.
    log:
        Where the guard logs refusals; default ``fleet.bus``.
    max_message_bytes:
        ZeroMQ's ``MAXMSGSIZE``: a peer sending a longer message over ipc or tcp is
        disconnected before the message is read into memory (inproc has no such check;
        `fleet.bus.schema.decode` checks the size again).

    Raises
    ------
    AddressError
        If the address is malformed or cannot be bound (in use, missing directory, ...), or
        `curve` is given for inproc.
    SecurityError
        If the guard cannot start (another ZAP handler serves `context`).
    """
    parsed = parse_address(address, bind=True)
    if curve is not None:
        _check_curve(curve, ServerCurve, parsed, address, "bind_router")
    log = log if log is not None else logging.getLogger("fleet.bus")
    sock = context.socket(zmq.ROUTER, socket_class=GuardedSocket if curve else None)
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    sock.setsockopt(zmq.ROUTER_MANDATORY, 1)
    sock.setsockopt(zmq.ROUTER_HANDOVER, 1)
    sock.setsockopt(zmq.MAXMSGSIZE, max_message_bytes)
    # A peer flooding the exchange fills its own send queue, not the engine's memory: past
    # this many unread messages ZeroMQ stops reading its connection (agents in lockstep have
    # one ACT and a few heartbeats outstanding at most).
    sock.setsockopt(zmq.RCVHWM, ROUTER_RECEIVE_QUEUE)
    if parsed.ipv6:
        # Without it libzmq resolves only IPv4 and binding '[::1]' fails with "No such device".
        sock.setsockopt(zmq.IPV6, 1)
    if curve is not None:
        try:
            curve.apply(sock)
            sock.curve_guard = curve.start(context, log)
            sock.curve_guard.watch(sock)
        except BaseException:
            sock.close(linger=0)
            raise
    try:
        sock.bind(str(parsed))
    except zmq.ZMQError as exc:
        sock.close(linger=0)
        raise AddressError(f"cannot bind the bus to {address!r}: {exc.strerror}") from None
    endpoint = sock.getsockopt(zmq.LAST_ENDPOINT)
    bound = endpoint.decode() if isinstance(endpoint, bytes) else str(endpoint)
    if curve is not None:
        log.info(
            "bus: %s requires CURVE; authorised agent keys: %d in %s",
            bound,
            len(curve.authorized_keys),
            curve.authorized,
        )
    return sock, bound


def connect_dealer(
    context: zmq.Context,
    address: str,
    routing_id: bytes | None = None,
    *,
    curve: ClientCurve | None = None,
    max_message_bytes: int = MAX_MESSAGE_BYTES,
) -> zmq.Socket:
    """A DEALER socket connected to `address` (connecting succeeds before the peer is up).

    Parameters
    ----------
    context:
        The ZeroMQ context (for inproc, the ROUTER's).
    address:
        The ROUTER's address.
    routing_id:
        The identity the ROUTER sees, kept across reconnections: 1 to `ROUTING_ID_MAX` bytes,
        not starting with a zero byte (ZeroMQ reserves those for ids it makes up). None lets
        ZeroMQ pick a fresh one per connection.
    curve:
        The agent's CURVE keys, for a ROUTER bound with a `ServerCurve`; only for ipc and tcp.
        If the engine refuses them nothing is delivered and the socket stays silent (the
        engine logs the refusal), as with any peer that never answers.
    max_message_bytes:
        ZeroMQ's ``MAXMSGSIZE``, as for `bind_router`.

    Raises
    ------
    AddressError
        If the address is malformed or cannot be connected to, or `curve` is given for inproc.
    ValueError
        If `routing_id` breaks the rules above.
    """
    parsed = parse_address(address, bind=False)
    if curve is not None:
        _check_curve(curve, ClientCurve, parsed, address, "connect_dealer")
    if routing_id is not None and not (
        isinstance(routing_id, bytes) and 0 < len(routing_id) <= ROUTING_ID_MAX and routing_id[0]
    ):
        raise ValueError(
            f"bus routing id {routing_id!r}: must be 1 to {ROUTING_ID_MAX} bytes,"
            " not starting with a zero byte"
        )
    sock = context.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, LINGER_MS)
    sock.setsockopt(zmq.MAXMSGSIZE, max_message_bytes)
    if routing_id is not None:
        sock.setsockopt(zmq.ROUTING_ID, routing_id)
    if parsed.ipv6:
        sock.setsockopt(zmq.IPV6, 1)
    if curve is not None:
        curve.apply(sock)
    try:
        sock.connect(str(parsed))
    except zmq.ZMQError as exc:
        sock.close(linger=0)
        raise AddressError(f"cannot connect the bus to {address!r}: {exc.strerror}") from None
    return sock


def _check_curve(curve: object, kind: type, parsed: Address, address: str, where: str) -> None:
    if not isinstance(curve, kind):
        raise TypeError(f"{where}: curve must be a {kind.__name__} or None, not {curve!r}")
    if parsed.transport == "inproc":
        # libzmq runs no security handshake on inproc: the keys would be silently ignored.
        raise AddressError(
            f"bus address {address!r}: CURVE security is not supported over inproc (libzmq"
            " runs no handshake there; everything in one process is trusted anyway); use"
            " 'ipc://<path>' or 'tcp://<host>:<port>', or give no keys"
        )
