"""mambot-fleet: a discrete-event simulator for fleets of mobile additive-manufacturing robots.

Layers, in the direction data flows: `fleet.floor` (map files -> convex regions in
H-representation), `fleet.paths` (reference paths and trajectories), `fleet.engine` (the SimPy
World), `fleet.bus` (ZeroMQ messages between the engine and robot agents), `fleet.plugins`
(controller and dispatcher contracts), `fleet.safety` (the trajectory checker).
"""

__version__ = "0.1.0"
