"""Pictures of a run: the PNG figures (`figures`) and the self-contained HTML replay (`replay`).

Both read a finished run directory, never a live engine; this room imports only `fleet.floor`
(to draw the map) and `fleet.errors`. Import the module you need.
"""
