"""What each peer of the exchange sent that was refused, and which peers are cut off.

Anything that can reach a tcp port can send anything, as often as it likes. The `PeerLedger`
keeps the exchange's answer to that bounded: each refusal is counted against the connection
(ZeroMQ routing id) it came on, logged at warning level the first time per kind and peer and at
debug level after that, and a peer with `cut_off_after` refusals is cut off: its frames are
dropped unread from then on. The ledger itself holds at most `max_peers` peers (the oldest
are forgotten first), so a stream of new connections cannot grow it without bound either.

Only junk counts against a peer: frames that do not decode, messages from a connection that
never said HELLO or that speak for another agent, and HELLOs refused outright. A late or
unasked ACT from a known agent is rejected but not counted, since a slow agent sends those.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field

__all__ = ["Junk", "PeerLedger", "CUT_OFF_AFTER", "MAX_PEERS"]

#: Default number of refused messages after which a peer is cut off.
CUT_OFF_AFTER = 100
#: Default number of peers the ledger remembers.
MAX_PEERS = 4096


class Junk(enum.StrEnum):
    """Why a message counts against its peer."""

    OVERSIZED = "oversized"  # longer than the bus's max_message_bytes
    MALFORMED = "malformed"  # not a valid message of an expected kind
    FRAMES = "frames"  # not exactly one frame after the routing id
    STRANGER = "stranger"  # not a HELLO, from a connection that never said one
    IMPOSTOR = "impostor"  # sent in another agent's name
    REFUSED = "refused"  # a HELLO none of whose robots could be accepted


@dataclass
class _Account:
    counts: dict[Junk, int] = field(default_factory=dict)
    total: int = 0
    cut_off: bool = False


class PeerLedger:
    """Refusals per peer, and the peers cut off.

    Parameters
    ----------
    stats:
        The exchange's counters; ``peers_cut_off`` and ``messages_ignored`` are counted here.
    log:
        Where refusals and cut-offs are logged.
    cut_off_after:
        Refusals after which a peer is cut off (>= 1).
    max_peers:
        Peers remembered at most (>= 1).
    """

    def __init__(
        self,
        stats: dict[str, int],
        log: logging.Logger,
        *,
        cut_off_after: int = CUT_OFF_AFTER,
        max_peers: int = MAX_PEERS,
    ) -> None:
        for name, value in (("cut_off_after", cut_off_after), ("max_peers", max_peers)):
            if type(value) is not int or value < 1:
                raise ValueError(f"peer ledger {name} = {value!r}: must be an integer >= 1")
        self.stats = stats
        self.log = log
        self.cut_off_after = cut_off_after
        self.max_peers = max_peers
        self._accounts: dict[bytes, _Account] = {}

    def ignores(self, identity: bytes) -> bool:
        """Whether the peer is cut off; if so its message is counted as ignored."""
        account = self._accounts.get(identity)
        if account is None or not account.cut_off:
            return False
        self.stats["messages_ignored"] += 1
        return True

    def charge(self, identity: bytes, peer: str, junk: Junk, why: str) -> bool:
        """Count one refused message of `peer` (its name for the log) on connection
        `identity`; True if that cut the peer off."""
        account = self._accounts.get(identity)
        if account is None:
            if len(self._accounts) >= self.max_peers:
                # The oldest first: dicts keep insertion order.
                del self._accounts[next(iter(self._accounts))]
            account = self._accounts[identity] = _Account()
        seen = account.counts.get(junk, 0)
        account.counts[junk] = seen + 1
        account.total += 1
        level = logging.WARNING if seen == 0 else logging.DEBUG
        more = "" if seen else " (more of this kind from it are logged at debug level)"
        self.log.log(level, "exchange: dropped message from %s (%s): %s%s", peer, junk, why, more)
        if account.cut_off or account.total < self.cut_off_after:
            return False
        account.cut_off = True
        self.stats["peers_cut_off"] += 1
        counts = ", ".join(f"{n} {kind}" for kind, n in sorted(account.counts.items()))
        self.log.warning(
            "exchange: cut off %s after %d refused messages (%s): its messages are dropped"
            " unread from now on",
            peer,
            account.total,
            counts,
        )
        return True

    def refusals(self, identity: bytes) -> dict[str, int]:
        """The refusals counted against a peer, by kind."""
        account = self._accounts.get(identity)
        return {str(k): n for k, n in account.counts.items()} if account else {}

    def __len__(self) -> int:
        return len(self._accounts)
