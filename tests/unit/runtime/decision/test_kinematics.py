"""The differential-drive law: turn toward the command, drive by its projection."""

from __future__ import annotations

import math

import numpy as np
import pytest

from runtime.decision.kinematics import diff_drive, diff_drive_step, wrap_angle


def test_aligned_command_drives_straight() -> None:
    forward, rate = diff_drive(0.8, 0.0, 0.0, 2.0, 0.1)
    assert float(forward) == pytest.approx(0.8)
    assert float(rate) == 0.0


def test_side_command_turns_at_the_limit_and_moves_by_the_projection() -> None:
    forward, rate = diff_drive(0.0, 1.0, 0.0, 2.0, 0.1)
    assert float(rate) == pytest.approx(2.0)
    assert float(forward) == pytest.approx(math.sin(0.2))


def test_backward_command_reverses_or_turns_without_moving() -> None:
    f_rev, r_rev = diff_drive(-0.5, 0.0, 0.0, 2.0, 0.1)
    assert float(f_rev) == pytest.approx(-0.5) and float(r_rev) == 0.0
    f_fwd, r_fwd = diff_drive(-0.5, 0.0, 0.0, 2.0, 0.1, reverse=False)
    assert float(f_fwd) == 0.0 and abs(float(r_fwd)) == pytest.approx(2.0)


def test_still_command_keeps_heading() -> None:
    forward, rate = diff_drive(0.0, 0.0, 1.0, 2.0, 0.1)
    assert float(forward) == 0.0 and float(rate) == 0.0


def test_batch_never_exceeds_the_command_and_moves_along_the_heading() -> None:
    rng = np.random.default_rng(3)
    v = rng.uniform(-1, 1, (500, 2))
    h = rng.uniform(-np.pi, np.pi, 500)
    vx, vy, h_new = diff_drive_step(v[:, 0], v[:, 1], h, 2.0, 0.1)
    assert np.all(np.hypot(vx, vy) <= np.hypot(v[:, 0], v[:, 1]) + 1e-12)
    assert np.all(np.abs(wrap_angle(h_new - h)) <= 0.2 + 1e-12)
    cross = vx * np.sin(h_new) - vy * np.cos(h_new)  # no sideways motion
    assert np.allclose(cross, 0.0, atol=1e-12)
    assert np.all(vx * v[:, 0] + vy * v[:, 1] >= -1e-12)  # never against the command
