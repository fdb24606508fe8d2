"""What can go wrong with one virtual servo, and the mechanical imperfections it has when nothing does.

Both are plain mutable dataclasses so a test (or the simulated rig) switches them at runtime from any
thread: ``bus.servo(1).faults.drop_replies = 3``. Random faults draw from the servo's own seeded RNG, so a
run is reproducible whatever the other servos do.
"""

from __future__ import annotations

import enum
import random
from dataclasses import dataclass, field


class HardwareError(enum.IntFlag):
    """Hardware Error Status (70) / Shutdown (63) bits of an X-series servo."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20


@dataclass(frozen=True)
class ReplyFate:
    """What happens to one status packet (or Fast Read segment) on its way to the client."""

    drop: bool = False
    corrupt: bool = False
    delay_s: float = 0.0
    #: Real seconds between the reply's first half and the rest (0: the whole reply at once).
    split_s: float = 0.0


@dataclass
class ServoFaults:
    """Faults of one servo's link and motion; every field may be changed while the bus runs.

    Attributes
    ----------
    drop_replies:
        Drop the next N status packets (the client sees no reply: ``COMM_RX_TIMEOUT``).
    drop_probability:
        Drop each status packet with this probability (seeded RNG).
    corrupt_replies:
        Send the next N status packets with a wrong CRC (``COMM_RX_CORRUPT``).
    corrupt_probability:
        Corrupt each status packet's CRC with this probability (seeded RNG).
    reply_delay_s:
        Real seconds to wait before each reply: the one delay that must be real, because a client on the
        other end of the pseudo-terminal measures it with its own wall clock.
    reply_split_s:
        Real seconds between the first half of each reply and the rest, as a USB adapter's latency timer or a
        loaded host delivers a reply in two pieces: a client whose window closes in between sees a partial
        reply (the SDK's ``COMM_RX_CORRUPT``), whose rest then arrives late.
    stall_short_ticks:
        When set, moves started afterwards stop this many ticks short of their goal and never arrive:
        Moving (122) stays 1 and Moving Status (123) shows a following error, like a joint pushing
        against an obstruction. ``None`` (default) disables it.
    seed:
        Seed of the RNG behind the probabilities; ``reseed`` restarts the sequence.
    """

    drop_replies: int = 0
    drop_probability: float = 0.0
    corrupt_replies: int = 0
    corrupt_probability: float = 0.0
    reply_delay_s: float = 0.0
    reply_split_s: float = 0.0
    stall_short_ticks: int | None = None
    seed: int = 0
    _rng: random.Random = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)

    def reseed(self, seed: int) -> None:
        """Restart the random faults from ``seed``."""
        self.seed = seed
        self._rng = random.Random(seed)

    def clear(self) -> None:
        """Switch every fault off (the RNG keeps its position)."""
        self.drop_replies = 0
        self.drop_probability = 0.0
        self.corrupt_replies = 0
        self.corrupt_probability = 0.0
        self.reply_delay_s = 0.0
        self.reply_split_s = 0.0
        self.stall_short_ticks = None

    def next_reply_fate(self) -> ReplyFate:
        """Decide (and consume counters for) the next reply this servo sends."""
        if self._strikes("drop_replies", self.drop_probability):
            return ReplyFate(drop=True)
        corrupt = self._strikes("corrupt_replies", self.corrupt_probability)
        return ReplyFate(corrupt=corrupt, delay_s=max(0.0, float(self.reply_delay_s)),
                         split_s=max(0.0, float(self.reply_split_s)))

    def _strikes(self, counter: str, probability: float) -> bool:
        """Whether a fault strikes this reply: one of the ``counter`` attribute's next N (used up), else by chance."""
        left: int = getattr(self, counter)
        if left > 0:
            setattr(self, counter, left - 1)
            return True
        return probability > 0.0 and self._rng.random() < probability


@dataclass
class ServoMechanics:
    """Imperfections of a healthy servo, in encoder ticks (4096 per turn); changeable at runtime.

    Attributes
    ----------
    steady_state_error_ticks:
        Each move settles this many ticks short of its goal (a load the position loop cannot quite
        overcome). The encoder sees it: Present Position reports it.
    backlash_ticks:
        Total play between the encoder and the load. The encoder does not see it: Present Position is
        unaffected, but ``VirtualServo.physical_position_ticks`` lags by half the play behind the
        direction of the last move, which is what a camera looking at the joint would see.
    settle_ticks:
        Width of the band the load comes to rest in around each goal (1.0: a real encoder's count, inside
        which the position loop cannot tell one place from another). The encoder does not see it: the
        load stands ``settle_offset(goal)`` off, a fixed draw per goal in [-settle_ticks / 2, settle_ticks / 2).
    """

    steady_state_error_ticks: float = 0.0
    backlash_ticks: float = 0.0
    settle_ticks: float = 0.0

    def settle_offset(self, servo_id: int, goal_ticks: int) -> float:
        """Where the load rests relative to the encoder's reading after a move to ``goal_ticks`` (ticks)."""
        if not self.settle_ticks:
            return 0.0
        # The same goal settles the same way (a resumed run sees the rig it left), different goals do not.
        u = random.Random(servo_id * 1_000_003 + goal_ticks).random()
        return (u - 0.5) * self.settle_ticks
