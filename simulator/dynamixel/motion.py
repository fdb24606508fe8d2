"""One commanded move of a position-controlled servo, evaluated in closed form at any instant.

A ``Move`` is the planned profile (``profile.plan``) plus what the mechanism does with it: a steady-state
error or a stall makes the encoder settle short of the goal. The Moving (122) and Moving Status (123)
flags follow from where the profile and the encoder are at the time asked.

Positions are encoder ticks, velocities ticks/s, accelerations ticks/s^2, times seconds of the servo's
clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from simulator.dynamixel import control_table as ct
from simulator.dynamixel.profile import Profile, ProfileType, plan

TICKS_PER_S_PER_VELOCITY_UNIT = ct.VELOCITY_UNIT_RPM * ct.TICKS_PER_REV / 60.0
"""One Profile/Present Velocity unit (0.229 rev/min) in ticks/s."""
TICKS_PER_S2_PER_ACCELERATION_UNIT = ct.ACCELERATION_UNIT_RPM2 * ct.TICKS_PER_REV / 3600.0
"""One Profile Acceleration unit (214.577 rev/min^2) in ticks/s^2."""
NO_LOAD_SPEED_TICKS_PER_S = ct.NO_LOAD_SPEED_RPM * ct.TICKS_PER_REV / 60.0
"""The fastest the output shaft turns (46 rev/min at 12 V), in ticks/s."""


@dataclass(frozen=True)
class ServoState:
    """Kinematic state of one servo at one instant (ticks, ticks/s, ticks/s^2; homing offset included)."""

    time_s: float
    position: float
    velocity: float
    acceleration: float
    trajectory_position: float
    trajectory_velocity: float
    profile_ongoing: bool
    in_position: bool
    following_error: bool
    moving: bool
    profile_type: ProfileType

    @classmethod
    def at_rest(cls, time_s: float, position: float, *, holding: bool) -> ServoState:
        """A servo standing at ``position`` ticks; ``holding`` (torque on) counts as in position."""
        return cls(time_s, position, 0.0, 0.0, position, 0.0, False, holding, False, False, ProfileType.NONE)


def profile_limits(
    distance: float, profile_velocity: int, profile_acceleration: int, velocity_limit: int, time_based: bool
) -> tuple[float, float, bool]:
    """Cruise speed (ticks/s), acceleration (ticks/s^2, inf for none) and "step" for a move of ``distance``.

    Register values are raw: velocities in 0.229 rpm, accelerations in 214.577 rpm^2, or both in ms for a
    time-based profile (Drive Mode bit 2). Profile Velocity 0 means no profile: a step at the Velocity
    Limit. Nothing ever exceeds the no-load speed.
    """
    pv, pa = profile_velocity, profile_acceleration
    limit = velocity_limit * TICKS_PER_S_PER_VELOCITY_UNIT
    cap = min(NO_LOAD_SPEED_TICKS_PER_S, limit) if limit > 0 else NO_LOAD_SPEED_TICKS_PER_S
    accel = pa * TICKS_PER_S2_PER_ACCELERATION_UNIT if pa else math.inf
    if pv == 0 or distance == 0.0:
        return cap, accel, pv == 0
    if time_based:
        # Profile Velocity is the move's duration and Profile Acceleration its ramp time, both in ms;
        # the ramp never exceeds half the move.
        total_s = pv / 1000.0
        ramp_s = min(pa, pv / 2.0) / 1000.0
        if ramp_s == 0.0:
            return min(distance / total_s, NO_LOAD_SPEED_TICKS_PER_S), math.inf, False
        v = distance / (total_s - ramp_s)
        return min(v, NO_LOAD_SPEED_TICKS_PER_S), v / ramp_s, False
    return min(pv * TICKS_PER_S_PER_VELOCITY_UNIT, NO_LOAD_SPEED_TICKS_PER_S), accel, False


@dataclass(frozen=True)
class Move:
    """A move started at ``t0`` whose encoder settles at ``end`` (ticks, homing offset excluded)."""

    t0: float
    profile: Profile
    end: float
    direction: int
    stalls: bool
    kind: ProfileType

    @classmethod
    def start(
        cls,
        t0: float,
        position: float,
        velocity: float,
        goal: float,
        limits: tuple[float, float, bool],
        *,
        shortfall: float = 0.0,
        stalls: bool = False,
    ) -> Move:
        """Plan from ``position`` (ticks) moving at ``velocity`` (ticks/s) to ``goal``, settling ``shortfall`` short."""
        v_max, a_max, step = limits
        profile = plan(position, velocity, goal, v_max, a_max)
        direction = (goal > position) - (goal < position)
        end = goal - direction * min(max(shortfall, 0.0), abs(goal - position))
        return cls(t0, profile, end, direction, stalls, ProfileType.NONE if step else profile.kind)

    def state(self, now: float, offset: float, moving_threshold: float) -> ServoState:
        """State at ``now``; ``offset`` (ticks) is added to positions, ``moving_threshold`` is in ticks/s."""
        t = now - self.t0
        tx, tv, ta = self.profile.at(t)
        done = t >= self.profile.duration
        passed = (self.direction > 0 and tx >= self.end) or (self.direction < 0 and tx <= self.end)
        clamped = passed and (self.stalls or self.end != self.profile.target)
        x, v, a = (self.end, 0.0, 0.0) if clamped else (tx, tv, ta)
        following_error = self.stalls and (clamped or done)
        ongoing = not done and self.kind != ProfileType.NONE
        # A stalled servo keeps pushing, so it never reports itself still (Moving stays 1).
        moving = not done or abs(v) > moving_threshold or self.stalls
        in_position = done and not self.stalls
        return ServoState(
            now, x + offset, v, a, tx + offset, tv, ongoing, in_position, following_error, moving, self.kind
        )
