"""The bus: how the engine talks to robot agents over ZeroMQ.

`schema` is the versioned wire format, `transport` the address checks and sockets, `exchange`
the engine's side (`Exchange`: one OBSERVE/ACT round trip per control tick, with `roster` for
who is connected, `lockstep` for one round, `answers` for the valid parts of the ACTs,
`router` for its socket and `ledger` for what each peer sent that was refused) and `agent`
the robots' side (`AgentHost`: wraps the controllers of the robots it hosts, with `link` for
its socket and `responder` for calling the controllers).
The same classes work in one process over ``inproc://`` (pumped synchronously,
deterministic) and across processes over ``ipc://`` and ``tcp://``. Besides commands, the bus
carries the contract net (job announcements, bids, handbacks) and liveness (heartbeats;
`BusEvent` says which agents joined, were lost, left or were refused). This room imports
`fleet.plugins` (the contracts its messages carry) and `fleet.errors`, nothing above.
"""

from fleet.bus.agent import AGENT_STATS, AgentHost
from fleet.bus.exchange import EXCHANGE_STATS, Exchange
from fleet.bus.responder import braking_command
from fleet.bus.roster import BusEvent, BusEventKind
from fleet.bus.schema import (
    SCHEMA_VERSION,
    Message,
    MessageKind,
    announcement_to_wire,
    bid_to_wire,
    command_from_wire,
    command_to_wire,
    decode,
    encode,
    handback_to_wire,
    observation_from_wire,
    observation_to_wire,
)
from fleet.bus.transport import AddressError, parse_address

__all__ = [
    "SCHEMA_VERSION",
    "MessageKind",
    "Message",
    "encode",
    "decode",
    "observation_to_wire",
    "observation_from_wire",
    "command_to_wire",
    "command_from_wire",
    "announcement_to_wire",
    "bid_to_wire",
    "handback_to_wire",
    "AddressError",
    "parse_address",
    "Exchange",
    "EXCHANGE_STATS",
    "BusEvent",
    "BusEventKind",
    "AgentHost",
    "AGENT_STATS",
    "braking_command",
]
