"""CurveZMQ security for the bus: key files, the engine's and the agents' keys, the gatekeeper.

Without keys the bus trusts whoever can reach its port. With them every connection is
encrypted and the engine admits only agents whose public key it holds:

1. Make one key pair for the engine and one per agent (`make_keypair`): ``<name>.key`` is the
   public key, ``<name>.key_secret`` the secret one (mode 0600; it never leaves its machine).
2. Copy each authorised agent's ``<name>.key`` into one directory on the engine's machine, and
   the engine's ``.key`` to every agent's machine.
3. The engine binds with ``ServerCurve(engine.key_secret, authorized_dir)``, each agent
   connects with ``ClientCurve(agent.key_secret, engine.key)``
   (`fleet.bus.transport.bind_router` / `connect_dealer` take them as ``curve=``).

The files are ZeroMQ's certificate format (ZPL, as written by czmq and by
``zmq.auth.create_certificates``), so keys made by other ZeroMQ tools work too. Keys are read
and checked once, when a `ServerCurve` or `ClientCurve` is built: a missing, unreadable or
malformed file raises `KeyFileError` naming the file and the field. The authorised directory is
not watched: build a new `ServerCurve` (and bind again) to change who is admitted.

The gatekeeper is a ZAP handler (ZeroMQ's authentication protocol, RFC 27) running in a thread
per `zmq.Context`; `ServerCurve.start` returns a `CurveGuard` holding it. It refuses every key
not authorised, and also sees the handshakes that fail before ZAP is asked (a client without
CURVE, a client holding the wrong engine key). Each refusal is counted on the guard and logged
at WARNING on the given logger (``fleet.bus``) with the client's public key (Z85) and address;
a client that keeps retrying is logged again at most once a minute, with the count. We run our
own thread rather than pyzmq's ``ThreadAuthenticator`` because that one only logs refusals at
DEBUG without the address, offers no hook to count them, never sees failed handshakes, swallows
errors in the key directory (and then refuses everyone), and allows one configuration per
context; here sockets with different authorised sets share a context, told apart by their ZAP
domain (derived from the authorised keys).

An authorised client's messages carry its key file's name (``<name>`` of ``<name>.key``) as
ZeroMQ's ``User-Id`` message property, so the engine can check that an agent speaks under its
own name (``frame.get("User-Id")`` on a frame received with ``copy=False``).
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import hashlib
import itertools
import logging
import os
import queue
import re
import string
import threading
import time
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import zmq
from zmq.utils import z85
from zmq.utils.monitor import parse_monitor_message

from fleet.errors import InputError, MessageError

__all__ = [
    "SecurityError",
    "KeyFileError",
    "PUBLIC_SUFFIX",
    "SECRET_SUFFIX",
    "make_keypair",
    "ServerCurve",
    "ClientCurve",
    "Refusal",
    "CurveGuard",
]

#: File name suffix of a public key file (ZeroMQ certificate), ``<name>.key``.
PUBLIC_SUFFIX = ".key"
#: File name suffix of a secret key file, ``<name>.key_secret``.
SECRET_SUFFIX = ".key_secret"

_Z85_CHARS = frozenset(string.digits + string.ascii_letters + ".-:+=^!/*?&<>()[]{}@%$#")
_KEY_LEN = 40  # a 32-byte Curve25519 key in Z85
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,99}$")
_ZAP_ENDPOINT = "inproc://zeromq.zap.01"  # fixed by RFC 27
_ZAP_VERSION = b"1.0"
# Handshake failures the ROUTER's monitor reports; ZAP refusals (HANDSHAKE_FAILED_AUTH) are not
# among them, the ZAP handler has already recorded those with the client's key.
_MONITOR_EVENTS = (
    zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
    | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
    | zmq.EVENT_MONITOR_STOPPED
)
_PROTOCOL_ERRORS = {
    zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH: "the client does not use CURVE",
    zmq.PROTOCOL_ERROR_ZMTP_CRYPTOGRAPHIC: (
        "cryptographic handshake failed (the client probably holds a wrong engine public key)"
    ),
}
#: A client that keeps being refused is logged again at most this often (s), with the count.
_RELOG_S = 60.0
_REPLY_TIMEOUT_MS = 10_000
# How long a stopping ZAP thread waits for its ROUTERs' monitors to report MONITOR_STOPPED.
_MONITOR_DRAIN_S = 2.0
_monitor_ids = itertools.count(1)


class SecurityError(MessageError):
    """The bus cannot be secured as asked (e.g. another ZAP handler owns the context)."""


class KeyFileError(InputError, SecurityError):
    """A key file or the authorised-keys directory is missing, unreadable or malformed.

    `source` is the file or directory, `field` the certificate field (``curve.public-key``,
    ``curve.secret-key``), ``(file)`` or ``(directory)``. Secret keys are never quoted.
    """


class _Hidden:
    """Stands in for a secret key in error messages."""

    def __init__(self, text: str) -> None:
        self.length = len(text)

    def __repr__(self) -> str:
        return f"<hidden, {self.length} characters>"


# -- key files ------------------------------------------------------------------------------------
def make_keypair(directory: str | os.PathLike[str], name: str) -> tuple[Path, Path]:
    """Make a CURVE key pair: ``<name>.key`` (public) and ``<name>.key_secret`` (secret, 0600).

    Parameters
    ----------
    directory:
        Where to write; created (mode 0700) if missing.
    name:
        The key's name: letters, digits, ``_``, ``.``, ``-``; not starting with ``.`` or
        ``-``. For an agent, its name: the engine reports it as the connection's ``User-Id``.

    Returns
    -------
    tuple of Path
        The public and the secret key file.

    Raises
    ------
    KeyFileError
        If `name` is not allowed, or either file already exists (a key is never overwritten).
    """
    directory = Path(directory)
    if not (isinstance(name, str) and _NAME.match(name)):
        raise KeyFileError(
            directory,
            "name",
            name,
            "a key name is 1 to 100 letters, digits, '_', '.' or '-', not starting with '.' or '-'",
        )
    public = directory / f"{name}{PUBLIC_SUFFIX}"
    secret = directory / f"{name}{SECRET_SUFFIX}"
    for path in (public, secret):
        if os.path.lexists(path):
            raise _exists(path)
    try:
        directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as exc:
        raise KeyFileError(
            directory, "(directory)", str(directory), f"cannot be created: {exc.strerror}"
        ) from None
    public_z85, secret_z85 = (k.decode("ascii") for k in zmq.curve_keypair())
    stamp = datetime.datetime.now().isoformat(timespec="seconds")
    # Secret first: if the public file then fails, no public key without its secret is left.
    _write_new(
        secret,
        _certificate(
            f"#   ****  Generated on {stamp} by mambot-fleet  ****\n"
            "#   ZeroMQ CURVE **Secret** Certificate\n"
            "#   DO NOT PROVIDE THIS FILE TO OTHER USERS nor change its permissions.\n",
            public_z85,
            secret_z85,
        ),
        0o600,
    )
    try:
        _write_new(
            public,
            _certificate(
                f"#   ****  Generated on {stamp} by mambot-fleet  ****\n"
                "#   ZeroMQ CURVE Public Certificate\n"
                "#   Exchange securely, or use a secure mechanism to verify the contents\n"
                "#   of this file after exchange.\n",
                public_z85,
                None,
            ),
            0o644,
        )
    except BaseException:
        secret.unlink(missing_ok=True)
        raise
    return public, secret


def _certificate(banner: str, public: str, secret: str | None) -> str:
    text = f'{banner}\nmetadata\ncurve\n    public-key = "{public}"\n'
    return text + (f'    secret-key = "{secret}"\n' if secret is not None else "")


def _write_new(path: Path, text: str, mode: int) -> None:
    """Create `path` with `mode` and write `text`; never replaces an existing file."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    except FileExistsError:
        raise _exists(path) from None
    except OSError as exc:
        raise KeyFileError(
            path, "(file)", str(path), f"cannot be created: {exc.strerror}"
        ) from None
    try:
        os.fchmod(fd, mode)  # the umask may have taken bits away; set exactly what we mean
        with os.fdopen(fd, "w", encoding="ascii") as f:
            fd = -1
            f.write(text)
    except BaseException:
        if fd >= 0:
            os.close(fd)
        path.unlink(missing_ok=True)
        raise


def _exists(path: Path) -> KeyFileError:
    return KeyFileError(
        path,
        "(file)",
        str(path),
        "already exists; a key is never overwritten (delete it first, or choose another name)",
    )


def _read_key_file(path: Path, *, secret: bool) -> tuple[str, str | None]:
    """The Z85 public key of a certificate file, and its secret key (None in a public file).

    With `secret` the file must hold a secret key matching its public key; without, it must
    hold none (a public key file that carries a secret is a leak waiting to happen).
    """
    want = SECRET_SUFFIX if secret else PUBLIC_SUFFIX
    what = "secret key file" if secret else "public key file"
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise KeyFileError(path, "(file)", str(path), f"no such {what}") from None
    except IsADirectoryError:
        raise KeyFileError(
            path, "(file)", str(path), f"is a directory; give the {what} '<name>{want}'"
        ) from None
    except OSError as exc:
        raise KeyFileError(path, "(file)", str(path), f"cannot be read: {exc.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise KeyFileError(
            path, "(file)", str(path), "is not a ZeroMQ certificate (not UTF-8 text)"
        ) from None
    values: dict[str, str] = {}
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("#"):
            continue
        for key in ("public-key", "secret-key"):
            if line.startswith(key) and key not in values:
                _, eq, value = line.partition("=")
                if eq:
                    values[key] = value.strip().strip("\"'")
    public = values.get("public-key")
    if public is None:
        raise KeyFileError(
            path,
            "curve.public-key",
            "(missing)",
            "a ZeroMQ certificate needs a line 'public-key = \"<40 Z85 characters>\"' under"
            " 'curve' (make_keypair writes such files)",
        )
    if not _is_z85_key(public):
        raise KeyFileError(
            path,
            "curve.public-key",
            public,
            f"must be a CURVE key: {_KEY_LEN} characters of the Z85 alphabet",
        )
    found = values.get("secret-key")
    if not secret:
        if found is not None:
            raise KeyFileError(
                path,
                "curve.secret-key",
                _Hidden(found),
                f"a {what} must not hold a secret key; give '<name>{PUBLIC_SUFFIX}', and"
                " keep the secret one on its own machine",
            )
        return public, None
    if found is None:
        raise KeyFileError(
            path,
            "curve.secret-key",
            "(missing)",
            f"this holds only a public key; give the secret key file '<name>{SECRET_SUFFIX}'",
        )
    if not _is_z85_key(found):
        raise KeyFileError(
            path,
            "curve.secret-key",
            _Hidden(found),
            f"must be a CURVE key: {_KEY_LEN} characters of the Z85 alphabet",
        )
    if zmq.curve_public(found.encode("ascii")).decode("ascii") != public:
        raise KeyFileError(
            path,
            "curve.public-key",
            public,
            "does not belong to the secret-key in the same file (edited, or mixed from two"
            " key pairs); make a new pair with make_keypair",
        )
    return public, found


def _is_z85_key(text: str) -> bool:
    return len(text) == _KEY_LEN and _Z85_CHARS.issuperset(text)


def _read_authorized(directory: Path) -> dict[str, str]:
    """Public key (Z85) to name for every ``*.key`` file in `directory`."""
    rule = (
        "must be a directory holding the authorised agents' public key files"
        f" '<name>{PUBLIC_SUFFIX}'"
    )
    try:
        entries = sorted(directory.iterdir())
    except FileNotFoundError:
        raise KeyFileError(
            directory, "(directory)", str(directory), f"no such directory; {rule}"
        ) from None
    except NotADirectoryError:
        raise KeyFileError(directory, "(directory)", str(directory), f"is a file; {rule}") from None
    except OSError as exc:
        raise KeyFileError(
            directory, "(directory)", str(directory), f"cannot be read: {exc.strerror}"
        ) from None
    keys: dict[str, str] = {}
    files: dict[str, Path] = {}
    for path in entries:
        if path.suffix != PUBLIC_SUFFIX:
            continue  # secret files, notes, editor backups: none is an authorisation
        public, _ = _read_key_file(path, secret=False)
        if public in keys:
            raise KeyFileError(
                path,
                "curve.public-key",
                public,
                f"the same key as {files[public]}; each agent needs its own key pair",
            )
        keys[public] = path.stem
        files[public] = path
    if not keys:
        raise KeyFileError(
            directory,
            "(directory)",
            str(directory),
            f"holds no '*{PUBLIC_SUFFIX}' files, so no agent could connect; copy each"
            f" authorised agent's public key file '<name>{PUBLIC_SUFFIX}' there",
        )
    return keys


# -- the two ends -----------------------------------------------------------------------------
@dataclass(frozen=True)
class ServerCurve:
    """The engine's side of CURVE: its secret key and the agents it admits.

    Both files are read and checked when the object is built.

    Parameters
    ----------
    secret_key:
        The engine's secret key file, ``<name>.key_secret``.
    authorized:
        A directory of authorised agents' public key files ``<name>.key`` (other files are
        ignored); at least one.

    Attributes
    ----------
    public_key:
        The engine's public key (Z85): what agents must hold as the engine's key.
    authorized_keys:
        Authorised public key (Z85) to name (the file name without ``.key``).

    Raises
    ------
    KeyFileError
        Naming the file and field that is missing, unreadable or malformed.
    """

    secret_key: Path
    authorized: Path
    public_key: str = field(init=False, compare=False)
    authorized_keys: Mapping[str, str] = field(init=False, compare=False, repr=False)
    _secret: str = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        secret_key, authorized = Path(self.secret_key), Path(self.authorized)
        public, secret = _read_key_file(secret_key, secret=True)
        keys = _read_authorized(authorized)
        for name, value in (
            ("secret_key", secret_key),
            ("authorized", authorized),
            ("public_key", public),
            ("authorized_keys", MappingProxyType(keys)),
            ("_secret", secret),
        ):
            object.__setattr__(self, name, value)

    def __reduce__(self) -> tuple[Any, ...]:
        # Pickled as its two paths: unpickling reads and checks the files again.
        return (ServerCurve, (self.secret_key, self.authorized))

    @property
    def zap_domain(self) -> str:
        """The ZAP domain of sockets using these keys: the same authorised set, the same domain."""
        digest = hashlib.sha256("\n".join(sorted(self.authorized_keys)).encode("ascii"))
        return f"mambot-fleet-{digest.hexdigest()[:16]}"

    def apply(self, socket: zmq.Socket) -> None:
        """Make `socket` a CURVE server with these keys (before it binds).

        It then admits only clients a running `CurveGuard` for these keys approves: without
        one, libzmq would admit any client that knows the engine's public key, so bind with
        `fleet.bus.transport.bind_router`, which starts one, or call `start` first.
        """
        socket.setsockopt(zmq.CURVE_SERVER, 1)
        socket.setsockopt(zmq.CURVE_SECRETKEY, self._secret.encode("ascii"))
        socket.setsockopt(zmq.CURVE_PUBLICKEY, self.public_key.encode("ascii"))
        socket.setsockopt(zmq.ZAP_DOMAIN, self.zap_domain.encode("ascii"))

    def start(self, context: zmq.Context, log: logging.Logger | None = None) -> CurveGuard:
        """Start admitting clients on `context`: a guard that lasts until its `stop`.

        Guards on one context share one ZAP thread, which ends when the last guard stops.

        Parameters
        ----------
        context:
            The context of the sockets to guard.
        log:
            Where refusals are logged (WARNING); default ``fleet.bus``.

        Raises
        ------
        SecurityError
            If another ZAP handler (not ours) already serves `context`, or the context is
            closed.
        """
        return _Warden.acquire(context, self, log or logging.getLogger("fleet.bus"))


@dataclass(frozen=True)
class ClientCurve:
    """An agent's side of CURVE: its own key pair and the engine's public key.

    Parameters
    ----------
    secret_key:
        The agent's secret key file, ``<name>.key_secret``.
    server_key:
        The engine's public key file, ``<name>.key`` (never its secret one).

    Attributes
    ----------
    public_key:
        The agent's public key (Z85): the engine must hold it among its authorised keys.
    server_public_key:
        The engine's public key (Z85).

    Raises
    ------
    KeyFileError
        Naming the file and field that is missing, unreadable or malformed.
    """

    secret_key: Path
    server_key: Path
    public_key: str = field(init=False, compare=False)
    server_public_key: str = field(init=False, compare=False)
    _secret: str = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        secret_key, server_key = Path(self.secret_key), Path(self.server_key)
        public, secret = _read_key_file(secret_key, secret=True)
        server, _ = _read_key_file(server_key, secret=False)
        for name, value in (
            ("secret_key", secret_key),
            ("server_key", server_key),
            ("public_key", public),
            ("server_public_key", server),
            ("_secret", secret),
        ):
            object.__setattr__(self, name, value)

    def apply(self, socket: zmq.Socket) -> None:
        """Make `socket` a CURVE client with these keys (before it connects)."""
        socket.setsockopt(zmq.CURVE_SERVERKEY, self.server_public_key.encode("ascii"))
        socket.setsockopt(zmq.CURVE_PUBLICKEY, self.public_key.encode("ascii"))
        socket.setsockopt(zmq.CURVE_SECRETKEY, self._secret.encode("ascii"))


# -- refusals and guards ----------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Refusal:
    """One kind of client the guard turned away.

    Attributes
    ----------
    public_key:
        The client's public key (Z85); None when the handshake failed before the client showed
        one (no CURVE, wrong engine key).
    address:
        Where it came from: the client's IP for tcp, ``localhost:<uid>:<gid>:<pid>`` for ipc;
        the listening endpoint when the handshake failed before ZAP (libzmq names no peer then).
    reason:
        Why, in words.
    """

    public_key: str | None
    address: str
    reason: str


class CurveGuard:
    """A running gatekeeper for sockets using one `ServerCurve` on one context.

    Made by `ServerCurve.start`; keeps the context's ZAP thread alive until `stop`. Counts
    and collects the refusals of clients of those sockets from its start on.

    Attributes
    ----------
    curve:
        The keys it enforces.
    context:
        The guarded context.
    log:
        Where refusals are logged.
    """

    def __init__(
        self, warden: _Warden, curve: ServerCurve, context: zmq.Context, log: logging.Logger
    ) -> None:
        self.curve = curve
        self.context = context
        self.log = log
        self._warden = warden
        self._domain = curve.zap_domain
        self._lock = threading.Lock()
        self._refused = 0
        self._new: dict[Refusal, None] = {}  # ordered set: distinct, in order of first sight
        self._watched: list[weakref.ref[zmq.Socket]] = []  # weak: the socket holds the guard
        self._stopped = False

    @property
    def refused(self) -> int:
        """How many connection attempts were refused (each retry counts)."""
        with self._lock:
            return self._refused

    @property
    def stopped(self) -> bool:
        """Whether `stop` was called."""
        return self._stopped

    def take_refusals(self) -> list[Refusal]:
        """The distinct refusals since the last call, in order of first occurrence."""
        with self._lock:
            new, self._new = list(self._new), {}
        return new

    def watch(self, socket: zmq.Socket) -> None:
        """Also report `socket`'s failed handshakes (no CURVE, wrong engine key) as refusals.

        Call before the socket binds, so that no failure goes unseen; `bind_router` does.

        Raises
        ------
        SecurityError
            If the guard has been stopped.
        """
        if self._stopped:
            raise SecurityError("this CurveGuard is stopped; start a new one to watch a socket")
        endpoint = f"inproc://mambot-fleet-curve-monitor-{next(_monitor_ids)}"
        socket.monitor(endpoint, _MONITOR_EVENTS)
        self._warden.command("watch", endpoint, self._domain)
        self._watched.append(weakref.ref(socket))

    def stop(self) -> None:
        """Stop this guard; the ZAP thread ends with the context's last guard. Idempotent.

        Stop only after closing the sockets it guards: a CURVE server socket with no ZAP
        handler admits any client that knows the engine's public key.
        """
        if self._stopped:
            return
        self._stopped = True
        self._warden.release(self)

    def _record(self, refusal: Refusal) -> None:
        with self._lock:
            self._refused += 1
            self._new[refusal] = None

    def __enter__(self) -> CurveGuard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def __repr__(self) -> str:
        state = "stopped" if self._stopped else "running"
        return f"<CurveGuard {self.curve.authorized} ({state}, {self.refused} refused)>"


class _Warden:
    """The ZAP handler thread of one context, shared by its guards (reference counted).

    Its sockets are made with ``zmq.Socket(context, ...)`` rather than ``context.socket``, so
    that ``Context.destroy`` in another thread does not close them under it; when the context
    is terminated the thread closes them itself. Commands reach it through a queue and an OS
    pipe (not a ZeroMQ socket), so no socket of it lives outside the thread.
    """

    _registry: dict[int, _Warden] = {}  # by id(context); a warden holds its context alive
    # Reentrant: a socket closed by the garbage collector may stop its guard from anywhere.
    _registry_lock = threading.RLock()

    def __init__(self, context: zmq.Context) -> None:
        self.context = context
        self.guards: list[CurveGuard] = []
        self.lock = threading.Lock()  # guards, _logged
        self._logged: dict[tuple[str, str | None, str, str], list[float]] = {}
        self._commands: queue.SimpleQueue[tuple[str, str, str, threading.Event]] = (
            queue.SimpleQueue()
        )
        try:
            self.zap = zmq.Socket(context, zmq.REP)
        except zmq.ZMQError as exc:
            raise SecurityError(
                f"cannot guard the bus: the zmq.Context is unusable ({exc})"
            ) from None
        self.zap.setsockopt(zmq.LINGER, 0)
        try:
            self.zap.bind(_ZAP_ENDPOINT)
        except zmq.ZMQError as exc:
            self.zap.close()
            if exc.errno == errno.EADDRINUSE:
                raise SecurityError(
                    "cannot guard the bus: another ZAP handler (not mambot-fleet's) already"
                    " serves this zmq.Context; give the exchange a context of its own"
                ) from None
            raise SecurityError(f"cannot guard the bus: {exc}") from None
        self._wake_r, self._wake_w = os.pipe()
        # The ZAP socket was made here and moves to the thread; starting it is the memory
        # barrier ZeroMQ asks for when a socket changes threads.
        self.thread = threading.Thread(target=self._run, name="mambot-fleet-zap", daemon=True)
        self.thread.start()

    # -- guards (any thread) ----------------------------------------------------------------
    @classmethod
    def acquire(cls, context: zmq.Context, curve: ServerCurve, log: logging.Logger) -> CurveGuard:
        with cls._registry_lock:
            warden = cls._registry.get(id(context))
            if warden is None or not warden.thread.is_alive():
                if warden is not None:
                    warden._close_wake()
                warden = cls(context)
                cls._registry[id(context)] = warden
            guard = CurveGuard(warden, curve, context, log)
            with warden.lock:
                warden.guards.append(guard)
            return guard

    def release(self, guard: CurveGuard) -> None:
        with self._registry_lock:
            for ref in guard._watched:
                sock = ref()
                if sock is not None and not sock.closed:
                    # Stopping early (misuse, or the socket's owner stops it): the monitor
                    # must say MONITOR_STOPPED for the thread to let go of it cleanly.
                    sock.disable_monitor()
            with self.lock:
                if guard in self.guards:
                    self.guards.remove(guard)
                last = not self.guards
            if last:
                self.command("stop")
                self.thread.join()
                self._close_wake()
                if self._registry.get(id(self.context)) is self:
                    del self._registry[id(self.context)]

    def command(self, op: str, endpoint: str = "", domain: str = "") -> None:
        """Have the thread carry out `op` and wait until it has (or has ended)."""
        done = threading.Event()
        self._commands.put((op, endpoint, domain, done))
        try:
            os.write(self._wake_w, b"!")
        except OSError:
            return  # closed: the warden has stopped for good
        waited = 0.0
        while not done.wait(0.05):
            if not self.thread.is_alive():
                return  # the context was terminated under it: nothing left to do
            waited += 0.05
            if waited * 1000 >= _REPLY_TIMEOUT_MS:
                raise SecurityError(f"the bus's ZAP thread did not carry out {op!r}")

    def _close_wake(self) -> None:
        if self._wake_w >= 0:
            os.close(self._wake_w)
            self._wake_w = -1

    # -- the thread -------------------------------------------------------------------------
    def _run(self) -> None:
        monitors: dict[zmq.Socket, str] = {}  # monitor socket -> ZAP domain of its ROUTER
        poller = zmq.Poller()
        poller.register(self._wake_r, zmq.POLLIN)
        poller.register(self.zap, zmq.POLLIN)
        stop: threading.Event | None = None
        stop_by = 0.0
        try:
            while stop is None or (monitors and time.monotonic() < stop_by):
                ready = dict(poller.poll(None if stop is None else 50))
                if self.zap in ready:
                    self.zap.send_multipart(self._verdict(self.zap.recv_multipart()))
                for mon in [m for m in monitors if m in ready]:
                    event = parse_monitor_message(mon.recv_multipart())
                    if event["event"] == zmq.EVENT_MONITOR_STOPPED:
                        # Its ROUTER closed (or stopped monitoring). Only now may this end close:
                        # closed earlier, libzmq never frees the ROUTER's monitor socket.
                        poller.unregister(mon)
                        del monitors[mon]
                        mon.close()
                    else:
                        address = _text(event["endpoint"])
                        self._refuse(monitors[mon], None, address, _failure(event))
                if self._wake_r in ready:
                    os.read(self._wake_r, 4096)
                    while not self._commands.empty():
                        op, endpoint, domain, done = self._commands.get()
                        if op == "watch":
                            mon = zmq.Socket(self.context, zmq.PAIR)
                            mon.setsockopt(zmq.LINGER, 0)
                            mon.connect(endpoint)
                            monitors[mon] = domain
                            poller.register(mon, zmq.POLLIN)
                            done.set()
                        else:  # stop, once the last ROUTERs' monitors have said goodbye
                            stop, stop_by = done, time.monotonic() + _MONITOR_DRAIN_S
        except zmq.ContextTerminated:
            pass  # the context is going away; nothing is left to guard
        finally:
            for mon in monitors:
                mon.close()
            # Unbinding frees the ZAP endpoint at once; closing alone frees it only when
            # libzmq's reaper gets to it, and a guard started right after would find it taken.
            with contextlib.suppress(zmq.ZMQError):
                self.zap.unbind(_ZAP_ENDPOINT)
            self.zap.close()
            os.close(self._wake_r)
            if stop is not None:
                stop.set()
            while not self._commands.empty():  # nobody must wait for a thread that is gone
                self._commands.get()[3].set()

    def _verdict(self, frames: list[bytes]) -> list[bytes]:
        """The ZAP reply to one request (RFC 27)."""
        if len(frames) < 6 or frames[0] != _ZAP_VERSION:
            request_id = frames[1] if len(frames) > 1 else b""
            return [_ZAP_VERSION, request_id, b"400", b"malformed ZAP request", b"", b""]
        _, request_id, domain_b, address_b, _, mechanism, *credentials = frames
        domain, address = _text(domain_b), _text(address_b)
        with self.lock:
            curve = next((g.curve for g in self.guards if g._domain == domain), None)
        if curve is None:
            if mechanism == b"NULL":
                # Someone else's unencrypted socket with a ZAP domain: admit it, as libzmq
                # does when no handler runs; it was never ours to police.
                return [_ZAP_VERSION, request_id, b"200", b"OK", b"", b""]
            reason = f"its socket's ZAP domain {domain!r} is not guarded by mambot-fleet"
            self._refuse(domain, None, address, reason, anyone=True)
            return [_ZAP_VERSION, request_id, b"400", b"unknown domain", b"", b""]
        if mechanism != b"CURVE" or len(credentials) != 1 or len(credentials[0]) != 32:
            reason = f"mechanism {_text(mechanism)!r} instead of CURVE"
            self._refuse(domain, None, address, reason)
            return [_ZAP_VERSION, request_id, b"400", b"CURVE required", b"", b""]
        key = z85.encode(credentials[0]).decode("ascii")
        name = curve.authorized_keys.get(key)
        if name is None:
            reason = f"key not among the authorised keys in {curve.authorized}"
            self._refuse(domain, key, address, reason)
            return [_ZAP_VERSION, request_id, b"400", b"key not authorised", b"", b""]
        return [_ZAP_VERSION, request_id, b"200", b"OK", name.encode("utf-8"), b""]

    def _refuse(
        self, domain: str, key: str | None, address: str, reason: str, *, anyone: bool = False
    ) -> None:
        """Count a refusal on the guards of `domain` and log it, once a minute at most.

        With `anyone` (a domain no guard knows) every guard hears of it.
        """
        refusal = Refusal(key, address, reason)
        now = time.monotonic()
        with self.lock:
            guards = (
                list(self.guards) if anyone else [g for g in self.guards if g._domain == domain]
            )
            seen = self._logged.get((domain, key, address, reason))
            if seen is None:
                if len(self._logged) > 4096:  # a scan from many addresses: start afresh
                    self._logged.clear()
                self._logged[(domain, key, address, reason)] = [now, 0]
                repeats = 0
            elif now - seen[0] >= _RELOG_S:
                repeats, seen[0], seen[1] = seen[1], now, 0
            else:
                seen[1] += 1
                repeats = -1  # counted, not logged
        for guard in guards:
            guard._record(refusal)
        if repeats < 0:
            return
        # Before ZAP, libzmq names only our listening endpoint, not the client's address.
        who = f"CURVE client with public key {key} from" if key else "a client at"
        again = f" ({repeats} more times since last logged)" if repeats else ""
        for log in {id(g.log): g.log for g in guards}.values():
            log.warning("bus: refused %s %s: %s%s", who, address, reason, again)


def _failure(event: dict[str, Any]) -> str:
    if event["event"] == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
        code = int(event["value"])
        return _PROTOCOL_ERRORS.get(code, f"ZMTP protocol error 0x{code:08x} in the handshake")
    return "the handshake failed (libzmq gives no detail)"


def _text(raw: bytes | str) -> str:
    return raw.decode("utf-8", "replace") if isinstance(raw, bytes) else str(raw)
