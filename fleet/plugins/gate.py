"""Controller steps in threads: the one gate a host's threads hold while plugin code runs.

An agent host with ``[bus] threads`` > 1 (`fleet.bus.AgentHost`) computes its robots' steps and
bids in a pool of threads, each call made through `in_gate`: it holds one process-wide lock
while it runs, so plugin code, Pyomo and whatever robots share (path caches, the floor) never
run in two threads at once, and a plugin needs no locks of its own. A plugin lets go of the gate
(`gate_released`) around work that runs no Python and touches nothing it shares: C code that
releases the GIL on the plugin's own data, such as a HiGHS run of its own object (the MPC's step
solve, `fleet_plugins.mpc.model.run_outcome`). Those parts of several robots' steps run at once,
on as many cores as there are threads; the rest waits its turn.

Each step still computes from its own observation and its own controller's state, so which
thread ran it, and in what order, does not change a command: a run's digest is the same with
any number of threads (`tests/test_threads.py`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

__all__ = ["in_gate", "gate_released"]

_T = TypeVar("_T")

_GATE = threading.Lock()
#: Whether the current thread holds the gate (it is taken only through `in_gate`).
_holder = threading.local()


def in_gate(fn: Callable[..., _T], /, *args: object) -> _T:
    """``fn(*args)`` holding the gate: called from several threads, only the parts of the
    calls inside `gate_released` run at once."""
    with _GATE:
        _holder.held = True
        try:
            return fn(*args)
        finally:
            _holder.held = False


@contextmanager
def gate_released() -> Iterator[None]:
    """Let go of the gate for the block, if this thread holds it (else nothing happens: a step
    computed without threads, or outside a host). The block must leave nothing shared
    half-changed and run no plugin Python; it gets the gate back before it ends."""
    if not getattr(_holder, "held", False):
        yield
        return
    _holder.held = False
    _GATE.release()
    try:
        yield
    finally:
        _GATE.acquire()
        _holder.held = True
