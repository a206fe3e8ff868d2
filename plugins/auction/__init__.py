"""The contract-net dispatcher: jobs are announced on the bus and go to the best bid."""

from fleet_plugins.auction.dispatcher import AuctionDispatcher

__all__ = ["AuctionDispatcher"]
