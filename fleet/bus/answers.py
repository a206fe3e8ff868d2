"""The answers of one lockstep round, judged: what of each agent's ACT the engine may use.

Commands count only for robots asked of the agent, bids only for jobs announced this round and
robots asked of the agent, handbacks only for robots the agent hosts, each at most once. What
is wrong is counted, logged and dropped, never raised. What is kept comes out in an order that
does not depend on which agent answered first.
"""

from __future__ import annotations

import logging

from fleet.bus.roster import Member
from fleet.plugins import Bid, Command, Handback

__all__ = ["Answers"]


class Answers:
    """The valid commands, bids and handbacks of one round.

    Parameters
    ----------
    tick:
        The round's control tick, for the logs.
    announced:
        The jobs announced this round.
    stats:
        The exchange's counters (`EXCHANGE_STATS`); dropped answers are counted into them.
    log:
        Where dropped answers are logged.
    """

    def __init__(
        self, tick: int, announced: frozenset[str], stats: dict[str, int], log: logging.Logger
    ) -> None:
        self.tick = tick
        self.announced = announced
        self.stats = stats
        self.log = log
        self._asked: dict[bytes, frozenset[str]] = {}  # robots each agent was asked about
        self._commands: dict[str, Command] = {}
        self._bids: dict[tuple[str, str], Bid] = {}
        self._handbacks: dict[tuple[str, str], Handback] = {}

    def ask(self, identity: bytes, robots: frozenset[str]) -> None:
        """The agent `identity` was asked about `robots`: it may bid for them."""
        self._asked[identity] = robots

    def take_commands(self, member: Member, asked: set[str], commands: dict[str, Command]) -> None:
        """Keep the commands for robots in `asked`, and take those robots out of it."""
        kept = self._commands
        for robot, command in commands.items():
            if robot in asked:
                kept[robot] = command
                asked.discard(robot)
            else:
                self.stats["commands_rejected"] += 1
                self.log.warning(
                    "exchange: tick %d: agent %s sent a command for robot %s, not asked of it",
                    self.tick,
                    member.name,
                    robot,
                )

    def take_bids(self, member: Member, bids: list[Bid]) -> None:
        """Keep the bids for announced jobs and robots asked of `member`, once each."""
        if not bids:
            return
        asked = self._asked.get(member.identity, frozenset())
        announced = self.announced
        kept = self._bids
        refused = []
        for bid in bids:
            key = (bid.job, bid.robot)
            if bid.job not in announced:
                refused.append((bid, "job not announced this round"))
            elif bid.robot not in asked:
                refused.append((bid, "robot not asked of this agent this round"))
            elif key in kept:
                refused.append((bid, "second bid for the same job and robot"))
            else:
                kept[key] = bid
        if refused:
            self.stats["bids_rejected"] += len(refused)
            # One line per ACT, not per bid: a confused agent may send hundreds.
            self.log.warning(
                "exchange: tick %d: dropped %d bids of agent %s, e.g. job %s robot %s: %s",
                self.tick,
                len(refused),
                member.name,
                refused[0][0].job,
                refused[0][0].robot,
                refused[0][1],
            )

    def take_handbacks(self, member: Member, handbacks: list[Handback]) -> None:
        """Keep the handbacks of robots `member` hosts, once each."""
        kept = self._handbacks
        for h in handbacks:
            key = (h.robot, h.job)
            if h.robot not in member.robots:
                why = "robot not hosted by this agent"
            elif key in kept:
                why = "handed back twice"
            else:
                kept[key] = h
                continue
            self.stats["handbacks_rejected"] += 1
            self.log.warning(
                "exchange: tick %d: dropped handback of job %s by robot %s from agent %s: %s",
                self.tick,
                h.job,
                h.robot,
                member.name,
                why,
            )

    def commands(self) -> dict[str, Command]:
        """The commands kept, sorted by robot id."""
        commands = self._commands
        return {r: commands[r] for r in sorted(commands)}

    def bids(self) -> list[Bid]:
        """The bids kept, sorted by (job, robot)."""
        return [self._bids[k] for k in sorted(self._bids)]

    def handbacks(self) -> list[Handback]:
        """The handbacks kept, sorted by (robot, job)."""
        return [self._handbacks[k] for k in sorted(self._handbacks)]
