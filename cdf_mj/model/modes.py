"""The obstacle driver's modes and intents: one vocabulary for the filter's driver model
(:mod:`cdf_mj.model.driver`, its kernels), the world's driver families
(:mod:`cdf_mj.scenario.drivers`, written apart from the filter) and the records.

This module imports nothing of the package, so that code kept apart from the filter can
share its numbers without loading it::

    from cdf_mj.model.modes import Mode, Intent            # the enums (records, Python code)
    from cdf_mj.model.modes import WAITING, GOING, LEFT    # plain ints (compiled kernels)

The plain ints are for Numba: a module-level ``int`` global is a compile-time constant in
``@njit`` code (an enum member is too, but as an enum type). Their values are part of the
records (``obstacle_modes``) and are frozen into Numba's on-disk caches of the kernels
that read them, which do not notice a change here: never renumber them.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

__all__ = ["COMMITTED", "GOING", "LEFT", "RIGHT", "WAITING", "YIELDING", "Intent", "Mode"]


class Mode(IntEnum):
    """Discrete mode of the obstacle driver's finite state machine."""

    WAITING = 0  # at its stop line (or on its approach to it)
    GOING = 1  # pulling out along its route
    YIELDING = 2  # braking (then stopped) for the ego
    COMMITTED = 3  # past its commit point: keeps going


class Intent(IntEnum):
    """The obstacle's intent, constant during an episode (the index of its route)."""

    LEFT = 0  # turns left, into the ego's lane across its path
    RIGHT = 1  # turns right, into the other lane: never the ego's


#: The modes as plain ints (for compiled code and the drivers kept apart from the filter).
WAITING: Final[int] = int(Mode.WAITING)
GOING: Final[int] = int(Mode.GOING)
YIELDING: Final[int] = int(Mode.YIELDING)
COMMITTED: Final[int] = int(Mode.COMMITTED)
#: The intents as plain ints.
LEFT: Final[int] = int(Intent.LEFT)
RIGHT: Final[int] = int(Intent.RIGHT)
