"""CurveZMQ on the bus: key files, and who gets through a guarded ROUTER over real sockets."""

from __future__ import annotations

import inspect
import logging
import pickle
import stat
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zmq
from zmq.auth import load_certificate

from fleet.bus import AgentHost, Exchange
from fleet.bus.security import (
    ClientCurve,
    KeyFileError,
    Refusal,
    SecurityError,
    ServerCurve,
    make_keypair,
)
from fleet.bus.transport import AddressError, GuardedSocket, bind_router, connect_dealer
from fleet.errors import InputError, MessageError
from fleet.plugins import Command, Controller, ControlStatus, Observation

# Generous: these waits end as soon as the awaited thing happens; only a broken bus waits this.
WAIT_S = 10.0
# How long a refused client gets to (wrongly) deliver once its refusal has been seen.
QUIET_MS = 300


# --- fixtures and helpers ------------------------------------------------------------------------


@pytest.fixture
def context() -> Iterator[zmq.Context]:
    """A context of the test's own; it must terminate, i.e. no guard thread may be left over."""
    ctx = zmq.Context()
    yield ctx
    ctx.destroy(linger=0)
    assert not zap_threads()


@pytest.fixture
def keys(tmp_path: Path) -> Path:
    """engine, alice (authorised) and mallory (not) key pairs; authorised keys in ``allowed/``."""
    make_keypair(tmp_path, "engine")
    make_keypair(tmp_path, "alice")
    make_keypair(tmp_path, "mallory")
    allowed = tmp_path / "allowed"
    allowed.mkdir()
    (allowed / "alice.key").write_bytes((tmp_path / "alice.key").read_bytes())
    return tmp_path


def server(keys: Path, allowed: str = "allowed") -> ServerCurve:
    return ServerCurve(keys / "engine.key_secret", keys / allowed)


def client(keys: Path, name: str, server_key: str = "engine.key") -> ClientCurve:
    return ClientCurve(keys / f"{name}.key_secret", keys / server_key)


def zap_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name == "mambot-fleet-zap"]


def wait_until(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"gave up waiting for {what}"
        time.sleep(0.01)


def receive(router: zmq.Socket, timeout_ms: int) -> list[tuple[bytes, bytes, str | None]]:
    """What reaches `router` until it is quiet for `timeout_ms`: (id, body, User-Id) each."""
    got = []
    while router.poll(timeout_ms):
        identity, body = router.recv_multipart(copy=False)
        got.append((identity.bytes, body.bytes, body.get("User-Id")))
    return got


def refusal_records(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.name == "fleet.bus" and r.levelno == logging.WARNING and "refused" in r.getMessage()
    ]


# --- make_keypair --------------------------------------------------------------------------------


def test_make_keypair_writes_a_zeromq_certificate_pair_with_a_private_secret(tmp_path):
    public, secret = make_keypair(tmp_path / "new" / "dir", "agent-7")
    assert (public.name, secret.name) == ("agent-7.key", "agent-7.key_secret")
    assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    # pyzmq's own reader understands both files, and the secret belongs to the public key.
    public_key, none = load_certificate(public)
    again, secret_key = load_certificate(secret)
    assert none is None and again == public_key
    assert zmq.curve_public(secret_key) == public_key
    assert ClientCurve(secret, public).public_key == public_key.decode()


def test_make_keypair_gives_a_fresh_pair_each_time(tmp_path):
    a, _ = make_keypair(tmp_path, "a")
    b, _ = make_keypair(tmp_path, "b")
    assert load_certificate(a)[0] != load_certificate(b)[0]


@pytest.mark.parametrize("existing", ["x.key", "x.key_secret"])
def test_make_keypair_never_overwrites_either_file(tmp_path, existing):
    (tmp_path / existing).write_text("precious")
    with pytest.raises(KeyFileError, match="already exists") as info:
        make_keypair(tmp_path, "x")
    assert existing in str(info.value)
    assert (tmp_path / existing).read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == [existing]


@pytest.mark.parametrize("name", ["", ".hidden", "-x", "a/b", "../up", "sp ace", "x" * 101])
def test_make_keypair_refuses_names_that_are_not_plain_file_names(tmp_path, name):
    with pytest.raises(KeyFileError, match="key name") as info:
        make_keypair(tmp_path, name)
    assert info.value.field == "name" and info.value.value == name
    assert not list(tmp_path.iterdir())


# --- key files that are wrong ---------------------------------------------------------------------


def test_errors_are_input_errors_and_bus_errors(keys):
    with pytest.raises(KeyFileError) as info:
        server(keys, allowed="nowhere")
    assert isinstance(info.value, InputError) and isinstance(info.value, MessageError)
    assert issubclass(KeyFileError, SecurityError)


def test_missing_secret_key_file_is_named(keys):
    with pytest.raises(KeyFileError, match="no such secret key file") as info:
        ServerCurve(keys / "gone.key_secret", keys / "allowed")
    assert str(keys / "gone.key_secret") in str(info.value)


def test_a_public_file_given_as_the_secret_one_says_which_file_to_give(keys):
    with pytest.raises(KeyFileError, match=r"give the secret key file '<name>.key_secret'") as info:
        ClientCurve(keys / "alice.key", keys / "engine.key")
    assert info.value.source == str(keys / "alice.key")
    assert info.value.field == "curve.secret-key"


def test_a_secret_file_given_as_the_engine_key_is_refused_without_quoting_the_secret(keys):
    secret = load_certificate(keys / "engine.key_secret")[1].decode()
    with pytest.raises(KeyFileError, match="must not hold a secret key") as info:
        client(keys, "alice", server_key="engine.key_secret")
    assert info.value.source == str(keys / "engine.key_secret")
    assert secret not in str(info.value)
    assert "<hidden, 40 characters>" in str(info.value)


@pytest.mark.parametrize(
    ("text", "field", "message"),
    [
        ("metadata\ncurve\n", "curve.public-key", "needs a line 'public-key"),
        ('curve\n    public-key = "short"\n', "curve.public-key", "40 characters of the Z85"),
        ('curve\n    public-key = "' + "~" * 40 + '"\n', "curve.public-key", "Z85 alphabet"),
    ],
)
def test_malformed_public_keys_name_file_and_field(keys, text, field, message):
    bad = keys / "allowed" / "broken.key"
    bad.write_text(text)
    with pytest.raises(KeyFileError, match=message) as info:
        server(keys)
    assert (info.value.source, info.value.field) == (str(bad), field)


def test_a_secret_key_that_does_not_match_its_public_key_is_refused(keys):
    alice = load_certificate(keys / "alice.key_secret")
    mallory = load_certificate(keys / "mallory.key_secret")
    mixed = keys / "mixed.key_secret"
    mixed.write_text(
        f'curve\n    public-key = "{alice[0].decode()}"\n    secret-key = "{mallory[1].decode()}"\n'
    )
    with pytest.raises(KeyFileError, match="does not belong to the secret-key") as info:
        ClientCurve(mixed, keys / "engine.key")
    assert info.value.source == str(mixed)
    assert mallory[1].decode() not in str(info.value)


def test_a_malformed_secret_key_is_refused_without_being_quoted(keys):
    public = load_certificate(keys / "alice.key")[0].decode()
    bad = keys / "bad.key_secret"
    bad.write_text(f'curve\n    public-key = "{public}"\n    secret-key = "not-a-key"\n')
    with pytest.raises(KeyFileError, match="CURVE key") as info:
        ClientCurve(bad, keys / "engine.key")
    assert info.value.field == "curve.secret-key"
    assert "not-a-key" not in str(info.value)


def test_binary_and_directory_key_files_are_refused(keys):
    junk = keys / "junk.key_secret"
    junk.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(KeyFileError, match="not UTF-8 text"):
        ClientCurve(junk, keys / "engine.key")
    with pytest.raises(KeyFileError, match="is a directory") as info:
        ClientCurve(keys / "allowed", keys / "engine.key")
    assert info.value.source == str(keys / "allowed")


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        (lambda d: None, "no such directory"),
        (lambda d: d.write_text("a file"), "is a file"),
        (lambda d: d.mkdir(), r"holds no '\*.key' files"),
        (lambda d: (d.mkdir(), (d / "notes.txt").write_text("hi")), r"holds no '\*.key' files"),
    ],
)
def test_the_authorised_directory_must_exist_and_hold_public_keys(keys, setup, message):
    where = keys / "empty"
    setup(where)
    with pytest.raises(KeyFileError, match=message) as info:
        server(keys, allowed="empty")
    assert info.value.source == str(where)


def test_an_authorised_directory_holding_a_secret_key_is_refused(keys):
    leaked = keys / "allowed" / "leak.key"
    leaked.write_bytes((keys / "mallory.key_secret").read_bytes())
    with pytest.raises(KeyFileError, match="must not hold a secret key") as info:
        server(keys)
    assert info.value.source == str(leaked)


def test_the_same_key_under_two_names_is_refused(keys):
    (keys / "allowed" / "alias.key").write_bytes((keys / "alice.key").read_bytes())
    with pytest.raises(KeyFileError, match="the same key as") as info:
        server(keys)
    assert "alias.key" in str(info.value) and "alice.key" in str(info.value)


def test_keys_are_read_once_and_secrets_stay_out_of_repr(keys):
    curve = server(keys)
    secret = load_certificate(keys / "engine.key_secret")[1].decode()
    assert curve.public_key == load_certificate(keys / "engine.key")[0].decode()
    assert dict(curve.authorized_keys) == {
        load_certificate(keys / "alice.key")[0].decode(): "alice"
    }
    assert secret not in repr(curve)
    assert load_certificate(keys / "alice.key_secret")[1].decode() not in repr(
        client(keys, "alice")
    )
    assert pickle.loads(pickle.dumps(curve)).authorized_keys == curve.authorized_keys
    # The same authorised set means the same ZAP domain, another set another one.
    assert server(keys).zap_domain == curve.zap_domain
    (keys / "more").mkdir()
    (keys / "more" / "mallory.key").write_bytes((keys / "mallory.key").read_bytes())
    assert server(keys, allowed="more").zap_domain != curve.zap_domain


# --- who gets through (real tcp sockets) ---------------------------------------------------------


def test_an_authorised_agent_reaches_the_router_under_its_key_name(context, keys):
    router, address = bind_router(context, "tcp://127.0.0.1:*", curve=server(keys))
    assert isinstance(router, GuardedSocket) and router.curve_guard is not None
    assert address.startswith("tcp://127.0.0.1:") and not address.endswith(":0")
    dealer = connect_dealer(context, address, b"agent-a", curve=client(keys, "alice"))
    dealer.send(b"hello")
    assert router.poll(int(WAIT_S * 1000))
    assert receive(router, QUIET_MS) == [(b"agent-a", b"hello", "alice")]
    # ... and the reply travels back encrypted over the same connection.
    router.send_multipart([b"agent-a", b"welcome"])
    assert dealer.poll(int(WAIT_S * 1000)) and dealer.recv() == b"welcome"
    assert router.curve_guard.refused == 0
    dealer.close(linger=0)
    router.close(linger=0)


def test_an_unauthorised_key_never_delivers_and_is_logged_and_counted(context, keys, caplog):
    caplog.set_level(logging.WARNING, logger="fleet.bus")
    router, address = bind_router(context, "tcp://127.0.0.1:*", curve=server(keys))
    guard = router.curve_guard
    mallory = client(keys, "mallory")
    intruder = connect_dealer(context, address, b"agent-m", curve=mallory)
    intruder.send(b"let me in")
    wait_until(lambda: guard.refused >= 1, "the refusal")
    assert receive(router, QUIET_MS) == []
    assert guard.take_refusals() == [
        Refusal(
            mallory.public_key,
            "127.0.0.1",
            f"key not among the authorised keys in {keys / 'allowed'}",
        )
    ]
    (message,) = refusal_records(caplog)
    assert mallory.public_key in message and "from 127.0.0.1" in message
    # Refused for good: an authorised agent's message arrives, the intruder's never does.
    friend = connect_dealer(context, address, b"agent-a", curve=client(keys, "alice"))
    friend.send(b"hello")
    assert router.poll(int(WAIT_S * 1000))
    assert receive(router, QUIET_MS) == [(b"agent-a", b"hello", "alice")]
    for sock in (intruder, friend, router):
        sock.close(linger=0)


def test_a_client_without_curve_never_delivers_and_is_logged_and_counted(context, keys, caplog):
    caplog.set_level(logging.WARNING, logger="fleet.bus")
    router, address = bind_router(context, "tcp://127.0.0.1:*", curve=server(keys))
    guard = router.curve_guard
    plain = connect_dealer(context, address, b"agent-p")
    plain.send(b"plain text")
    wait_until(lambda: guard.refused >= 1, "the refusal")
    assert receive(router, QUIET_MS) == []
    (refusal,) = guard.take_refusals()
    assert refusal == Refusal(None, address, "the client does not use CURVE")
    (message,) = refusal_records(caplog)
    assert f"at {address}" in message and "does not use CURVE" in message
    plain.close(linger=0)
    router.close(linger=0)


def test_a_client_with_a_wrong_engine_key_retries_but_is_logged_once(context, keys, caplog):
    caplog.set_level(logging.WARNING, logger="fleet.bus")
    router, address = bind_router(context, "tcp://127.0.0.1:*", curve=server(keys))
    guard = router.curve_guard
    # alice is authorised but holds mallory's public key for the engine's.
    confused = connect_dealer(
        context, address, b"agent-a", curve=client(keys, "alice", server_key="mallory.key")
    )
    confused.send(b"hello")
    # libzmq reconnects after each failed handshake: every try counts, one is logged.
    wait_until(lambda: guard.refused >= 3, "three refusals")
    assert receive(router, QUIET_MS) == []
    assert [r.reason for r in guard.take_refusals()] == [
        "cryptographic handshake failed (the client probably holds a wrong engine public key)"
    ]
    assert len(refusal_records(caplog)) == 1
    confused.close(linger=0)
    router.close(linger=0)


def test_an_unauthorised_client_cannot_take_over_an_agents_routing_id(context, keys):
    router, address = bind_router(context, "tcp://127.0.0.1:*", curve=server(keys))
    alice = connect_dealer(context, address, b"agent-a", curve=client(keys, "alice"))
    alice.send(b"hello")
    assert router.poll(int(WAIT_S * 1000)) and receive(router, QUIET_MS)
    # Same routing id: with ROUTER_HANDOVER a plain impostor would take alice's messages.
    impostor = connect_dealer(context, address, b"agent-a", curve=client(keys, "mallory"))
    impostor.send(b"hello")
    wait_until(lambda: router.curve_guard.refused >= 1, "the refusal")
    router.send_multipart([b"agent-a", b"for alice"])
    assert alice.poll(int(WAIT_S * 1000)) and alice.recv() == b"for alice"
    assert not impostor.poll(QUIET_MS)
    for sock in (alice, impostor, router):
        sock.close(linger=0)


def test_curve_works_over_ipc_too(context, keys, tmp_path):
    router, address = bind_router(context, f"ipc://{tmp_path}/bus", curve=server(keys))
    friend = connect_dealer(context, address, b"agent-a", curve=client(keys, "alice"))
    intruder = connect_dealer(context, address, b"agent-m", curve=client(keys, "mallory"))
    friend.send(b"hello")
    intruder.send(b"let me in")
    wait_until(lambda: router.curve_guard.refused >= 1, "the refusal")
    assert router.poll(int(WAIT_S * 1000))
    assert receive(router, QUIET_MS) == [(b"agent-a", b"hello", "alice")]
    (refusal,) = router.curve_guard.take_refusals()
    # Over ipc libzmq names the peer by its credentials: localhost:<uid>:<gid>:<pid>.
    assert refusal.public_key == client(keys, "mallory").public_key
    assert refusal.address.startswith("localhost:")
    for sock in (friend, intruder, router):
        sock.close(linger=0)


def test_curve_is_refused_over_inproc_rather_than_silently_ignored(context, keys):
    with pytest.raises(AddressError, match="not supported over inproc"):
        bind_router(context, "inproc://secure", curve=server(keys))
    with pytest.raises(AddressError, match="not supported over inproc"):
        connect_dealer(context, "inproc://secure", curve=client(keys, "alice"))
    assert not zap_threads()


def test_keys_of_the_wrong_side_are_a_type_error(context, keys):
    with pytest.raises(TypeError, match="ServerCurve"):
        bind_router(context, "tcp://127.0.0.1:*", curve=client(keys, "alice"))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="ClientCurve"):
        connect_dealer(context, "tcp://127.0.0.1:5555", curve=server(keys))  # type: ignore[arg-type]


# --- guard lifetime ------------------------------------------------------------------------------


def test_the_guard_lives_as_long_as_the_router_or_an_explicit_guard(context, keys):
    curve = server(keys)
    guard = curve.start(context)  # as Exchange does: a guard of its own, before binding
    router, address = bind_router(context, "tcp://127.0.0.1:*", curve=curve)
    router.close(linger=0)
    assert zap_threads() and not guard.stopped
    # Still guarded: a second router on the same context refuses mallory.
    again, address = bind_router(context, "tcp://127.0.0.1:*", curve=curve)
    intruder = connect_dealer(context, address, b"m", curve=client(keys, "mallory"))
    intruder.send(b"x")
    wait_until(lambda: guard.refused >= 1 and again.curve_guard.refused >= 1, "the refusal")
    intruder.close(linger=0)
    again.close(linger=0)
    guard.stop()
    guard.stop()  # idempotent
    assert guard.stopped and not zap_threads()


def test_routers_with_different_authorised_sets_share_a_context(context, keys):
    (keys / "only-mallory").mkdir()
    (keys / "only-mallory" / "mallory.key").write_bytes((keys / "mallory.key").read_bytes())
    for_alice, a_address = bind_router(context, "tcp://127.0.0.1:*", curve=server(keys))
    for_mallory, m_address = bind_router(
        context, "tcp://127.0.0.1:*", curve=server(keys, allowed="only-mallory")
    )
    assert len(zap_threads()) == 1
    senders = [
        connect_dealer(context, address, name.encode(), curve=client(keys, name))
        for address in (a_address, m_address)
        for name in ("alice", "mallory")
    ]
    for sock in senders:
        sock.send(b"hi")
    wait_until(
        lambda: for_alice.curve_guard.refused >= 1 and for_mallory.curve_guard.refused >= 1,
        "both refusals",
    )
    assert router_poll(for_alice) and receive(for_alice, QUIET_MS) == [(b"alice", b"hi", "alice")]
    assert router_poll(for_mallory)
    assert receive(for_mallory, QUIET_MS) == [(b"mallory", b"hi", "mallory")]
    assert [r.public_key for r in for_alice.curve_guard.take_refusals()] == [
        client(keys, "mallory").public_key
    ]
    assert [r.public_key for r in for_mallory.curve_guard.take_refusals()] == [
        client(keys, "alice").public_key
    ]
    for sock in (*senders, for_alice, for_mallory):
        sock.close(linger=0)


def router_poll(router: zmq.Socket) -> bool:
    return bool(router.poll(int(WAIT_S * 1000)))


def test_binding_and_closing_guarded_routers_again_and_again_leaks_no_sockets(keys):
    # libzmq frees a closed socket's monitor only if the monitor's last event is read; a leak
    # of a few sockets per bind would hit this context's limit long before the loop ends.
    ctx = zmq.Context()
    ctx.set(zmq.MAX_SOCKETS, 200)
    curve = server(keys)
    for _ in range(300):
        router, _address = bind_router(ctx, "tcp://127.0.0.1:*", curve=curve)
        router.close(linger=0)
    # A guard stopped while its router is still open lets go of the router's monitor too.
    router, _address = bind_router(ctx, "tcp://127.0.0.1:*", curve=curve)
    router.curve_guard.stop()
    assert not zap_threads()
    router.close(linger=0)
    ctx.term()


def test_a_foreign_zap_handler_on_the_context_is_reported(context, keys):
    foreign = context.socket(zmq.REP)
    foreign.bind("inproc://zeromq.zap.01")
    with pytest.raises(SecurityError, match="another ZAP handler"):
        bind_router(context, "tcp://127.0.0.1:*", curve=server(keys))
    foreign.close(linger=0)


def test_a_failed_bind_stops_the_guard_it_started(context, keys):
    router, address = bind_router(context, "tcp://127.0.0.1:*")
    with pytest.raises(AddressError, match="cannot bind"):
        bind_router(context, address, curve=server(keys))
    assert not zap_threads()
    router.close(linger=0)


def test_terminating_the_context_ends_a_forgotten_guard(keys):
    ctx = zmq.Context()
    guard = server(keys).start(ctx)
    assert zap_threads()
    ctx.term()  # would hang if the guard's sockets stayed open
    wait_until(lambda: not zap_threads(), "the guard's thread to end")  # it ends after term
    guard.stop()  # nothing left to stop, and no error


# --- through the exchange ------------------------------------------------------------------------


def test_the_exchange_never_hears_an_unauthorised_agent_and_logs_it_once(context, keys, caplog):
    caplog.set_level(logging.WARNING, logger="fleet.bus")
    exchange = Exchange("tcp://127.0.0.1:*", context=context, timeout_s=5.0, curve=server(keys))
    intruder = connect_dealer(context, exchange.address, b"mallory", curve=client(keys, "mallory"))
    intruder.send(b"{}")
    wait_until(lambda: exchange.socket.curve_guard.refused >= 1, "the refusal")
    with pytest.raises(MessageError, match="no agent hosts robots"):
        exchange.wait_for_agents(["r1"], timeout_s=QUIET_MS / 1000)
    assert exchange.stats["messages_received"] == 0
    # The exchange's guard and its socket's both saw it; the log says it once.
    (message,) = refusal_records(caplog)
    assert client(keys, "mallory").public_key in message
    intruder.close(linger=0)
    exchange.close()


class Echo(Controller):
    def compute(self, obs: Observation) -> Command:
        return Command(-obs.vx, float(obs.tick), ControlStatus.OK)


@pytest.mark.skipif(
    "curve" not in inspect.signature(AgentHost).parameters,
    reason="AgentHost does not take curve= yet",
)
def test_a_round_trip_through_exchange_and_agent_host_over_curve(context, keys):
    exchange = Exchange("tcp://127.0.0.1:*", context=context, timeout_s=5.0, curve=server(keys))
    host = AgentHost(
        exchange.address,
        {"r1": Echo()},
        name="alice",
        context=context,
        curve=client(keys, "alice"),  # type: ignore[call-arg]
    )
    serving = threading.Thread(target=host.serve, daemon=True)
    serving.start()
    exchange.wait_for_agents(["r1"])
    result = exchange.round(0, 0.0, [Observation("r1", 0, 0.0, 1.0, -2.0, 0.25, -0.5)])
    assert result == {"r1": Command(-0.25, 0.0, ControlStatus.OK)}
    exchange.close()
    serving.join(WAIT_S)
    assert not serving.is_alive()
    host.close()
