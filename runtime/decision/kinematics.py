"""Wheels: how a velocity command becomes motion on a differential-drive base.

The decision speaks holonomic velocities (vx, vy) in m/s. A differential-drive
base (a TurtleBot, most wheeled robots) takes a forward speed and a turn rate
(``geometry_msgs/Twist``: ``linear.x``, ``angular.z``) and can only move along
its heading. :func:`diff_drive` is the one law that turns the first into the
second, used by the worlds that simulate such bases (``Conditions.kinematics``)
and by the ROS 2 bridge that drives a real one:

1. the target heading is the command's direction, or its opposite when
   ``reverse`` is allowed and that needs less turning (a base drives backwards
   as well as forwards);
2. the base turns toward it at most ``max_turn_rps`` (one step of ``dt_s``);
3. it drives by the command's projection on the new heading, so a command at
   right angles to the heading turns without moving, and a robot never moves
   in a direction the command did not ask for (the projection's sign is the
   command's: with ``reverse`` off, a backward projection is 0).

A command below ``still_mps`` in norm neither turns nor moves. All functions
take NumPy arrays of any matching shape (one robot or a batch) and scalars.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from runtime.types import Array

__all__ = ["Wheels", "diff_drive", "diff_drive_step", "wrap_angle"]

STILL_MPS = 1e-6
"""A command slower than this (m/s) leaves the heading as it is."""


def wrap_angle(a: Array | float) -> Array:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi


def diff_drive(
    vx: Array | float,
    vy: Array | float,
    heading: Array | float,
    max_turn_rps: float,
    dt_s: float,
    *,
    reverse: bool = True,
    still_mps: float = STILL_MPS,
) -> tuple[Array, Array]:
    """(forward speed m/s, turn rate rad/s) that a differential-drive base at ``heading`` (rad)
    runs for the holonomic command (``vx``, ``vy``) over one step of ``dt_s``.

    The forward speed is never larger than the command's norm, so a command within
    v_max stays within it."""
    vx = np.asarray(vx, dtype=np.float64)
    vy = np.asarray(vy, dtype=np.float64)
    h = np.asarray(heading, dtype=np.float64)
    speed = np.hypot(vx, vy)
    moving = speed > still_mps
    err = wrap_angle(np.arctan2(vy, vx) - h)
    if reverse:  # the opposite heading when it is nearer
        back = np.abs(err) > 0.5 * np.pi
        err = np.where(back, wrap_angle(err + np.pi), err)
    max_turn = max(float(max_turn_rps), 0.0) * dt_s
    turn = np.where(moving, np.clip(err, -max_turn, max_turn), 0.0)
    h_new = h + turn
    forward = vx * np.cos(h_new) + vy * np.sin(h_new)
    if not reverse:
        forward = np.maximum(forward, 0.0)
    forward = np.where(moving, forward, 0.0)
    rate = turn / dt_s if dt_s > 0 else np.zeros_like(turn)
    return forward, rate


def diff_drive_step(
    vx: Array | float,
    vy: Array | float,
    heading: Array | float,
    max_turn_rps: float,
    dt_s: float,
    *,
    reverse: bool = True,
) -> tuple[Array, Array, Array]:
    """The velocity (vx, vy) a differential-drive base actually moves at this step, and its
    heading after the step: :func:`diff_drive`'s turn first, then the drive along the new
    heading (the order a discrete base controller runs them)."""
    forward, rate = diff_drive(vx, vy, heading, max_turn_rps, dt_s, reverse=reverse)
    h_new = wrap_angle(np.asarray(heading, dtype=np.float64) + rate * dt_s)
    return forward * np.cos(h_new), forward * np.sin(h_new), h_new


class Wheels:
    """How E teams of N robots execute their commands under ``conditions``: each robot's
    wheel gain (drawn per episode in [1 - gain_noise, 1 + gain_noise]), Gaussian
    actuation noise per step, and a differential-drive base's heading (drawn per
    episode, uniform). One generator per env, apart from the world's start draws."""

    def __init__(self, conditions: Any, n_envs: int, n_robots: int,
                 seeds: list[np.random.SeedSequence], dt_s: float) -> None:
        self.conditions = conditions
        self.dt_s = dt_s
        self._rngs = [np.random.default_rng(s) for s in seeds]
        self.gain = np.ones((n_envs, n_robots))
        self.heading = np.zeros((n_envs, n_robots))
        self.reset(np.arange(n_envs))

    def reset(self, env_ids: Any) -> None:
        """A new episode in these envs: fresh gains and headings."""
        c = self.conditions
        n = self.gain.shape[1]
        for e in np.asarray(env_ids, dtype=np.int64):
            rng = self._rngs[e]
            self.gain[e] = 1.0 + rng.uniform(-c.gain_noise, c.gain_noise, n) \
                if c.gain_noise > 0 else 1.0
            self.heading[e] = rng.uniform(-np.pi, np.pi, n) if c.kinematics == "diff" else 0.0

    def apply(self, command: Array) -> Array:
        """The velocities (E, N, 2) m/s the robots move at for ``command`` (E, N, 2) m/s."""
        c = self.conditions
        u = np.nan_to_num(np.asarray(command, dtype=np.float64), nan=0.0, posinf=0.0,
                          neginf=0.0)
        if c.kinematics == "diff":
            vx, vy, self.heading = diff_drive_step(u[..., 0], u[..., 1], self.heading,
                                                   c.turn_rate_rps, self.dt_s)
            u = np.stack([vx, vy], axis=-1)
        u = u * self.gain[..., None]
        if c.act_noise_mps > 0:
            moving = (np.abs(u).sum(-1) > 0)[..., None]  # a robot at rest stays at rest
            for e, rng in enumerate(self._rngs):
                u[e] += moving[e] * rng.normal(0.0, c.act_noise_mps, u[e].shape)
        return u
