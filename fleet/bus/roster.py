"""Who is on the bus: the agents the exchange knows, the robots each hosts, and who was lost.

The `Roster` answers a HELLO (which of the claimed robots the agent may host), forgets agents
that left or were lost, and keeps what happened to them as `BusEvent` values until the engine
takes them (`Exchange.take_events`).
"""

from __future__ import annotations

import enum
import logging
import time
from collections.abc import Collection
from dataclasses import dataclass, field

__all__ = ["BusEvent", "BusEventKind", "Member", "Roster"]


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


@dataclass(eq=False)
class Member:
    """An agent the exchange talks to; compared by identity, as each is one connection."""

    identity: bytes  # its ZeroMQ routing id
    name: str
    robots: set[str] = field(default_factory=set)
    seen: float = 0.0  # time.monotonic() of its latest valid message
    local: bool = False  # pumped by the exchange itself: never silent, never timed out


@dataclass(frozen=True, slots=True)
class Admission:
    """The roster's answer to a HELLO, for the WELCOME (and the BYE of a refused agent)."""

    accepted: list[str]  # in the order claimed, including robots it hosted already
    rejected: dict[str, str]  # robot -> why
    refusal: str | None  # why the agent as a whole is turned away, or None
    refused: str = ""  # the rejected robots grouped by reason, for the log ("" if none)


class Roster:
    """The agents connected to one exchange and the robots each hosts.

    Parameters
    ----------
    scenario:
        Fingerprint of the run's scenario; a HELLO naming another (non-empty) one is refused.
        ``""`` checks nothing.
    stats:
        The exchange's counters (`EXCHANGE_STATS`); the roster counts into them.
    log:
        Where refusals, departures and losses are logged.

    Attributes
    ----------
    members:
        Connected agents by ZeroMQ routing id.
    by_name:
        Connected agents by name.
    owner:
        Robot -> the agent hosting it.
    expected:
        The robots of the run (`expect`); None accepts any robot.
    unreachable:
        Routing id -> name of the agents dropped as unreachable, told BYE when the exchange
        closes in case they have reconnected since.
    """

    def __init__(self, scenario: str, stats: dict[str, int], log: logging.Logger) -> None:
        self.scenario = scenario
        self.stats = stats
        self.log = log
        self.members: dict[bytes, Member] = {}
        self.by_name: dict[str, Member] = {}
        self.owner: dict[str, Member] = {}
        self.expected: frozenset[str] | None = None
        self.unreachable: dict[bytes, str] = {}
        self._local: set[bytes] = set()  # routing ids of the hosts the exchange pumps itself
        self._events: list[BusEvent] = []

    @property
    def agents(self) -> dict[str, frozenset[str]]:
        """Connected agents by name, with the robots each hosts."""
        return {a.name: frozenset(a.robots) for a in self.by_name.values()}

    def expect(self, robots: Collection[str]) -> None:
        """Add `robots` to the robots of the run; others are refused from now on."""
        self.expected = frozenset(robots) | (self.expected or frozenset())

    def uncovered(self) -> set[str]:
        """The expected robots no agent hosts."""
        return (self.expected or frozenset()) - self.owner.keys()

    def mark_local(self, identity: bytes) -> None:
        """The agent of routing id `identity` is pumped by the exchange: never silent."""
        self._local.add(identity)
        member = self.members.get(identity)
        if member is not None:  # its HELLO was handled before it was adopted
            member.local = True

    # -- comings and goings -------------------------------------------------------------------
    def admit(self, identity: bytes, name: str, claimed: list[str], scenario: str) -> Admission:
        """Take in a HELLO: which of the `claimed` robots the agent `name` may host.

        `scenario` is the fingerprint the HELLO names. Refusals are counted, logged and
        recorded as events; so is a join. An agent that hosts no robot after its HELLO is not
        kept as a member.
        """
        member = self.members.get(identity)
        namesake = self.by_name.get(name)
        reason = None
        refuse_all = False
        if scenario and self.scenario and scenario != self.scenario:
            reason = f"scenario differs (agent {scenario}, run {self.scenario})"
            refuse_all = True
        elif member is not None and member.name != name:
            reason = f"this connection already introduced itself as {member.name!r}"
        elif namesake is not None and namesake is not member:
            reason = f"another agent is already called {name!r}"
        accepted: list[str] = []
        joined: list[str] = []  # robots it did not host before
        rejected: dict[str, str] = {}
        if reason is not None:
            rejected = dict.fromkeys(claimed, reason)
        else:
            if member is None:
                member = Member(identity, name, local=identity in self._local)
            member.seen = time.monotonic()
            for robot in claimed:
                owner = self.owner.get(robot)
                if self.expected is not None and robot not in self.expected:
                    rejected[robot] = "unknown robot: not part of this run"
                elif owner is not None and owner is not member:
                    rejected[robot] = f"already hosted by agent {owner.name!r}"
                else:
                    if owner is None:
                        joined.append(robot)
                    accepted.append(robot)
                    member.robots.add(robot)
                    self.owner[robot] = member
            # Only an agent hosting something is kept: a stream of HELLOs naming no robot of
            # the run, each from a new name, must not fill the roster.
            if member.robots and self.members.get(identity) is not member:
                self.members[identity] = member
                self.by_name[name] = member
                self.unreachable.pop(identity, None)
        self.stats["robots_rejected"] += len(rejected)
        if refuse_all:
            self.stats["agents_refused"] += 1
        if joined:
            self.log.info(
                "exchange: agent %s joined, hosting %d robots: %s",
                name,
                len(member.robots),
                _some(sorted(joined)),
            )
            self._events.append(BusEvent(BusEventKind.JOINED, name, tuple(sorted(joined))))
        by_reason: dict[str, list[str]] = {}
        for robot, why in rejected.items():
            by_reason.setdefault(why, []).append(robot)
        for why, robots in by_reason.items():
            self._events.append(BusEvent(BusEventKind.REFUSED, name, tuple(sorted(robots)), why))
        # Logged by the exchange: it knows whether the peer keeps sending such HELLOs.
        refused = "; ".join(f"{_some(sorted(r))}: {why}" for why, r in by_reason.items())
        return Admission(accepted, rejected, reason if refuse_all else None, refused)

    def leave(self, member: Member, reason: str) -> None:
        """Forget an agent that said BYE; its robots are unhosted."""
        self.log.info("exchange: agent %s left: %s", member.name, reason)
        robots = tuple(sorted(member.robots))
        self._forget(member)
        self._events.append(BusEvent(BusEventKind.LEFT, member.name, robots, reason))

    def lose(self, member: Member, why: str, tick: int) -> None:
        """Forget an agent declared lost at `tick`; its robots are unhosted."""
        self.stats["agents_lost"] += 1
        robots = tuple(sorted(member.robots))
        self.log.warning(
            "exchange: tick %d: agent %s lost (%s); its robots %s are unhosted",
            tick,
            member.name,
            why,
            list(robots[:20]),
        )
        self._forget(member)
        self._events.append(BusEvent(BusEventKind.LOST, member.name, robots, why))

    def _forget(self, member: Member) -> None:
        self.members.pop(member.identity, None)
        if self.by_name.get(member.name) is member:
            del self.by_name[member.name]
        for robot in member.robots:
            if self.owner.get(robot) is member:
                del self.owner[robot]

    # -- events -------------------------------------------------------------------------------
    def record(self, event: BusEvent) -> None:
        """Keep an event that happened outside the roster (a CurveZMQ refusal)."""
        self._events.append(event)

    def take_events(self) -> list[BusEvent]:
        """The events since the previous call, oldest first (and forget them)."""
        events, self._events = self._events, []
        return events


def _some(robots: list[str], shown: int = 10) -> str:
    """Up to `shown` robot ids, and how many more: a log line stays short."""
    more = f" and {len(robots) - shown} more" if len(robots) > shown else ""
    return f"{', '.join(robots[:shown])}{more}"
