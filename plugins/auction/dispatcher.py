"""`AuctionDispatcher`: a contract net over the bus.

The engine announces every open job in a bus round (`fleet.plugins.Announcement`); each robot's
agent bids the time it would need to deliver it after the work it already has
(`fleet.plugins.Controller.bid`, by default `fleet.plugins.bidding.estimate_completion`). This
dispatcher awards each job to the lowest bid. Jobs nobody bid for are announced again.
"""

from __future__ import annotations

from collections.abc import Sequence

from fleet.plugins import Assignment, Bid, DispatchContext, Dispatcher, Job, RobotStatus

__all__ = ["AuctionDispatcher"]


class AuctionDispatcher(Dispatcher):
    """Award each announced job to the robot that bids the earliest delivery.

    Jobs are awarded oldest first (``released_s``, then id); each robot wins at most one job
    per round, so a robot's bid (made before it won anything) still holds when it wins. Equal
    bids go to the smaller robot id. A busy robot may win a job: it queues behind its current
    one (robots with a job queued do not bid).

    Parameters
    ----------
    busy:
        Whether robots with a job may win more (queued); False awards idle robots only.
    """

    name = "auction"
    announces = True

    def __init__(self, busy: bool = True) -> None:
        super().__init__()
        if not isinstance(busy, bool):
            raise ValueError(f"AuctionDispatcher option busy = {busy!r}: must be true or false")
        self.busy = busy

    def award(
        self,
        bids: Sequence[Bid],
        jobs: Sequence[Job],
        robots: Sequence[RobotStatus],
        context: DispatchContext,
    ) -> list[Assignment]:
        """The lowest bid wins each job; see the class docstring for the order and ties."""
        eligible = {r.robot for r in robots if r.queued == 0 and (self.busy or r.idle)}
        offers: dict[str, list[tuple[float, str]]] = {}
        for b in bids:
            if b.robot in eligible:
                offers.setdefault(b.job, []).append((b.estimate_s, b.robot))
        taken: set[str] = set()
        out: list[Assignment] = []
        for job in sorted(jobs, key=lambda j: (j.released_s, j.id)):
            ranked = sorted(o for o in offers.get(job.id, ()) if o[1] not in taken)
            if ranked:
                robot = ranked[0][1]
                taken.add(robot)
                out.append(Assignment(job.id, robot))
        return out

    def assign(
        self, jobs: Sequence[Job], robots: Sequence[RobotStatus], context: DispatchContext
    ) -> list[Assignment]:
        """Nothing without bids: jobs wait for the next announcement."""
        return []

    def __repr__(self) -> str:
        return f"AuctionDispatcher(busy={self.busy!r})"
