"""Machine description (moved to :mod:`cnctwin.machine.description`; re-exported here).

The simulator runs the one machine description of :mod:`cnctwin.machine`; this module keeps
the old import path ``cnctwin.sim.machine`` working.
"""

from cnctwin.machine.description import (
    KV_UNIT_PER_S,
    FeedAxis,
    Machine,
    SpindleMotor,
    dynamic_response_adaptation_times,
)

__all__ = [
    "KV_UNIT_PER_S",
    "FeedAxis",
    "Machine",
    "SpindleMotor",
    "dynamic_response_adaptation_times",
]
