"""A pair seen inside the safety guard needs two views to leave it (noisy views only).

Under noise a robot pressing against a peer inside the guard used to take the room of any
single view that put the peer outside it: a view 2-4 sigmas long let it close in, and the
next view, from where it then stood, never gave that back. Robots pressed together in a team
that never formed crept into each other over tens of steps
(:meth:`runtime.decision.controller.Controller._seen_twice`).
"""

from __future__ import annotations

import numpy as np

from runtime.conditions import parse_conditions
from runtime.decision.controller import Controller
from runtime.decision.safety import OrcaParams, guard_distance, uncertainty_params
from runtime.decision.settle import settle_for
from trainer.adversary import ChargeBrain

PATTERN = np.array([[-0.2, 0.0], [0.2, 0.0]])


def _controller(spec: str) -> tuple[Controller, float]:
    cond = parse_conditions(spec)
    safety = uncertainty_params(OrcaParams(), cond)
    ctl = Controller(ChargeBrain(), safety=safety, settle=settle_for(cond, estimator=True))
    return ctl, guard_distance(safety)


def _ref(peer_x: float) -> np.ndarray:
    """The guard's references: robot 1 seen at (peer_x, 0), from robot 0 standing at the
    origin, on time (nothing unseen), half the room each."""
    ref = np.zeros((2, 6))
    ref[:, 5] = 0.5
    ref[1, 0:2] = (peer_x, 0.0)
    return ref


def _charge(ctl: Controller, step: int, peer_x: float) -> float:
    """Robot 0's command toward robot 1 (m/s along +x), the team seen with robot 1 at
    (peer_x, 0): the brain charges at it."""
    pos = np.array([[0.0, 0.0], [peer_x, 0.0]])
    d = ctl.decide(0, pos, PATTERN, step, np.zeros((2, 2)), pos, _ref(peer_x))
    return d.velocity[0]


def test_one_far_view_of_a_peer_seen_inside_the_guard_does_not_let_a_robot_close_in() -> None:
    ctl, g = _controller("noise_m=0.05")
    assert 0.26 < g < 0.45
    assert _charge(ctl, 0, 0.26) <= 1e-9  # inside: no approach
    assert _charge(ctl, 1, 0.45) <= 1e-9  # one view outside: still none
    assert _charge(ctl, 2, 0.45) > 0.1  # two views outside: the room they show
    fresh, _ = _controller("noise_m=0.05")
    assert _charge(fresh, 0, 0.45) > 0.1  # a robot with no earlier view takes the one it has


def test_a_repeated_step_keeps_the_view_of_the_step_before() -> None:
    """Real time: a robot may decide the same world step twice; the second decision still
    compares with the step before, not with its own first look at this step."""
    ctl, _ = _controller("noise_m=0.05")
    _charge(ctl, 0, 0.26)
    assert _charge(ctl, 1, 0.45) <= 1e-9
    assert _charge(ctl, 1, 0.45) <= 1e-9


def test_exact_views_take_the_room_of_their_one_view() -> None:
    """Without noise a view is the pair as it was: a peer seen farther has gone farther."""
    ctl, g = _controller("latency_steps=2,act_noise_mps=0.02")
    assert g > 0.0
    late = 0.5 * (g + 0.2)  # inside this guard
    assert _charge(ctl, 0, late) <= 1e-9
    assert _charge(ctl, 1, g + 0.1) > 0.02


def test_a_pattern_inside_the_guard_takes_the_room_of_one_view() -> None:
    """At 10 cm of noise the guard (0.45 m) is wider than the pattern's 0.40 m: robots reach
    their slots only as the noise lets them through, one view at a time."""
    ctl, g = _controller("noise_m=0.1")
    assert g > 0.4
    assert _charge(ctl, 0, 0.3) <= 1e-9
    assert _charge(ctl, 1, g + 0.15) > 0.1
