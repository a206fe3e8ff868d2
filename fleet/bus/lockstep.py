"""One lockstep round of the exchange: OBSERVEs out, ACTs in, the late and the silent noted.

`Exchange.round` opens a `Round` per control tick. The round sends each agent one OBSERVE with
its robots' observations and the jobs on offer, pumps the local hosts until they have answered,
and waits up to the exchange's ``timeout_s`` for the remote ones, declaring lost on the way an
agent silent for ``lost_after_s``. The valid parts of the answers go to its `Answers`.
"""

from __future__ import annotations

import errno
import math
import time
from collections import Counter
from collections.abc import Sequence

from fleet.bus.answers import Answers
from fleet.bus.roster import Member, Roster
from fleet.bus.router import BATCH, Router
from fleet.bus.schema import (
    Message,
    MessageKind,
    announcement_to_wire,
    encode,
    observation_to_wire,
)
from fleet.errors import MessageError
from fleet.plugins import Announcement, Observation

__all__ = ["Round", "announcement_offers"]


def announcement_offers(
    tick: int, announcements: Sequence[Announcement]
) -> tuple[list[str], list[dict]]:
    """The announced job ids and their wire forms, for the OBSERVEs of round `tick`.

    Raises
    ------
    ValueError
        If a job is announced twice.
    MessageError
        If an announcement is no `Announcement` or cannot be encoded, naming it.
    """
    offers = []
    for i, a in enumerate(announcements):
        if not isinstance(a, Announcement):
            raise MessageError(
                f"round tick {tick}: announcements[{i}] = {a!r}: must be a"
                " fleet.plugins.Announcement"
            )
        try:
            offers.append(announcement_to_wire(a))
        except MessageError as exc:
            raise MessageError(f"round tick {tick}: announcements[{i}]: {exc}") from None
    announced = [a.job for a in announcements]
    if len(set(announced)) != len(announced):
        dupes = sorted(j for j, n in Counter(announced).items() if n > 1)
        raise ValueError(f"round tick {tick}: jobs {dupes} announced more than once")
    return announced, offers


class Round:
    """One control round: OBSERVEs out to the agents hosting the observed robots, their ACTs
    awaited until all are in or the time is up.

    Local hosts are pumped until they have answered, never timed out; the remote agents then
    have `timeout_s`, and one silent for `lost_after_s` meanwhile is declared lost at once.

    Parameters
    ----------
    tick:
        The round's control tick (-1 stands for "no round yet").
    announced:
        The jobs announced this round.
    roster:
        Who hosts which robot; agents found lost are forgotten there.
    router:
        The exchange's socket and local hosts.
    sender:
        The exchange's name in messages.

    Attributes
    ----------
    pending:
        Routing id -> the robots still without a command, for the agents yet to answer.
    missing:
        Observed robots left without a command so far.
    answers:
        The valid commands, bids and handbacks so far.
    """

    def __init__(
        self,
        tick: int,
        announced: frozenset[str],
        *,
        roster: Roster,
        router: Router,
        sender: str,
    ) -> None:
        self.tick = tick
        self.roster = roster
        self.router = router
        self.sender = sender
        self.stats = router.stats
        self.log = router.log
        self.answers = Answers(tick, announced, self.stats, self.log)
        self.pending: dict[bytes, set[str]] = {}
        self.missing = 0
        self._started = 0.0  # time.monotonic() when the OBSERVEs went out

    def message(self, kind: MessageKind, body: dict) -> bytes:
        """A message from the exchange, stamped with this round's tick (0 before the first)."""
        return encode(kind, self.sender, max(self.tick, 0), body)

    # -- asking -------------------------------------------------------------------------------
    def ask(self, t: float, observations: Sequence[Observation], offers: list[dict]) -> None:
        """Send each agent one OBSERVE with its robots' observations and the job offers.

        Robots no agent hosts, or whose agent cannot be reached, count as missing.

        Raises
        ------
        ValueError
            If a robot is observed twice.
        """
        groups: dict[Member, list[dict]] = {}
        robots: dict[Member, set[str]] = {}
        owner = self.roster.owner
        seen: set[str] = set()
        for obs in sorted(observations, key=_robot_of):
            robot = obs.robot
            if robot in seen:
                raise ValueError(f"round tick {self.tick}: two observations of robot {robot!r}")
            seen.add(robot)
            member = owner.get(robot)
            if member is None:
                self.missing += 1
                continue
            if member in groups:
                groups[member].append(observation_to_wire(obs))
                robots[member].add(robot)
            else:
                groups[member] = [observation_to_wire(obs)]
                robots[member] = {robot}
        self._started = time.monotonic()
        self.router.wake()
        for member, wire in groups.items():
            body = {"t": float(t), "observations": wire, "announcements": offers}
            if self._send(member, self.message(MessageKind.OBSERVE, body)):
                self.pending[member.identity] = robots[member]
                self.answers.ask(member.identity, frozenset(robots[member]))
            else:
                self.missing += len(robots[member])

    def _send(self, member: Member, raw: bytes) -> bool:
        error = self.router.send(member.identity, raw, member.name)
        if not error:
            return True
        if error == errno.EHOSTUNREACH:
            # No connection carries its routing id any more: stop routing its robots to it.
            self.declare_lost(member, "unreachable: no connection carries its routing id")
            self.roster.unreachable[member.identity] = member.name
        # Otherwise (EAGAIN: its queue is full) it is behind but there: it keeps its robots and
        # only misses this round.
        return False

    # -- waiting ------------------------------------------------------------------------------
    def wait(self, timeout_s: float, lost_after_s: float) -> None:
        """Wait for the local hosts' answers, then up to `timeout_s` for the remote ones."""
        self._pump_locals(timeout_s)
        self._collect(time.monotonic() + timeout_s, timeout_s, lost_after_s)

    def _pump_locals(self, timeout_s: float) -> None:
        """Pump until every local host that was sent an OBSERVE has answered it.

        Over ipc/tcp the OBSERVE reaches a local host only after a short trip through the
        sockets, so this waits for it; the wait gives up only if no local host handles
        anything for `timeout_s` (the message was lost), never because a controller is slow.
        """
        router, tick = self.router, self.tick
        pending = self.pending
        hosts = [h for h in router.hosts if h.identity in pending]
        if not hosts:
            return
        idle_until = time.monotonic() + timeout_s
        while True:
            if router.pump_hosts():
                idle_until = time.monotonic() + timeout_s
            router.take_in()
            hosts = [
                h
                for h in hosts
                if h.last_tick < tick and not h.closed and h.identity in self.pending
            ]
            if not hosts:
                return
            remaining = idle_until - time.monotonic()
            if remaining <= 0:
                self.log.warning(
                    "exchange: tick %d: local hosts %s got no OBSERVE within %g s",
                    tick,
                    [h.name for h in hosts],
                    timeout_s,
                )
                return
            router.poll(remaining)

    def _collect(self, deadline: float, timeout_s: float, lost_after_s: float) -> None:
        """Handle answers until none is outstanding or `deadline` (time.monotonic) passes.

        Remote agents silent for `lost_after_s` are declared lost on the way; the check is
        made only once the ROUTER's queue is drained, so that messages the exchange has not
        read yet (say, heartbeats sent while the engine was busy between rounds) count.
        """
        router = self.router
        while self.pending:
            progressed = router.pump_hosts()
            handled = router.take_in()
            if not self.pending:
                return
            now = time.monotonic()
            drained = handled < BATCH  # silence is then real, not messages yet unread
            # Checked on every pass: a stream of messages must not postpone the timeout.
            if now >= deadline:
                if drained:
                    # Silent for the whole round, which lasted at least lost_after_s: lost.
                    # Those heard from since the OBSERVE went out are alive, merely late.
                    self._check_silent(now, lost_after_s, since=self._started)
                if self.pending:
                    self._time_out(timeout_s)
                return
            wake = deadline - now
            if drained:
                wake = min(wake, self._check_silent(now, lost_after_s))
                if not self.pending:
                    return
            if not progressed and not handled:
                router.poll(wake)

    def _time_out(self, timeout_s: float) -> None:
        members = self.roster.members
        late = sorted(r for robots in self.pending.values() for r in robots)
        agents = sorted(members[i].name for i in self.pending if i in members)
        self.stats["timeouts"] += 1
        self.missing += len(late)
        self.log.warning(
            "exchange: tick %d: no answer within %g s from %s for robots %s",
            self.tick,
            timeout_s,
            agents,
            late[:20],
        )
        self.pending = {}

    def _check_silent(self, now: float, lost_after_s: float, since: float | None = None) -> float:
        """Declare pending remote agents lost that were silent for `lost_after_s` (or, given
        `since`, not heard from since then); seconds until the next one would be (inf if no
        other is pending)."""
        soonest = math.inf
        for identity in list(self.pending):
            member = self.roster.members.get(identity)
            if member is None or member.local:
                continue
            silent = now - member.seen
            if silent >= lost_after_s if since is None else member.seen < since:
                why = f"silent for {silent:.3g} s (lost_after_s = {lost_after_s:g})"
                self.declare_lost(member, why)
                # If it is only stuck, it learns it was dropped (its serve() returns) instead
                # of talking on to an exchange that no longer listens; it may say HELLO again.
                bye = self.message(MessageKind.BYE, {"reason": why})
                self.router.send_to_lost(identity, bye, member.name)
            else:
                soonest = min(soonest, lost_after_s - silent)
        return soonest

    # -- answers and departures ---------------------------------------------------------------
    def take_act(self, member: Member, msg: Message) -> str | None:
        """Take in an ACT of `member`: the valid parts go to `answers`.

        Returns why the message is rejected as a whole (this agent was not asked this round),
        or None; an ACT for another tick is counted and dropped as stale.
        """
        if msg.tick != self.tick:
            self.stats["stale"] += 1
            self.log.warning(
                "exchange: dropped ACT of agent %s for tick %d during tick %d",
                member.name,
                msg.tick,
                self.tick,
            )
            return None
        asked = self.pending.pop(member.identity, None)
        if asked is None:
            return f"ACT from {member.name!r} for tick {msg.tick}, not asked"
        self.answers.take_commands(member, asked, msg.body["commands"])
        if asked:
            self.missing += len(asked)
            self.log.warning(
                "exchange: tick %d: agent %s sent no command for robots %s",
                self.tick,
                member.name,
                sorted(asked)[:20],
            )
        self.answers.take_bids(member, msg.body["bids"])
        self.answers.take_handbacks(member, msg.body["handbacks"])
        return None

    def declare_lost(self, member: Member, why: str) -> None:
        """Forget an agent found lost; its robots are unhosted and missing from this round."""
        self.roster.lose(member, why, self.tick)
        self.drop(member.identity)

    def drop(self, identity: bytes) -> None:
        """Stop waiting for an agent that is gone; its outstanding robots are missing."""
        asked = self.pending.pop(identity, None)
        if asked:
            self.missing += len(asked)


def _robot_of(obs: Observation) -> str:
    return obs.robot
