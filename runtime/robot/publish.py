"""What a robot tells the swarm: :class:`Outbox`.

Each step it decides: its slots (``--agree``, :mod:`runtime.robot.slot_talk`) just before
the command, the :class:`runtime.wire.messages.Command` on its cmd key (and to its ROS 2
base with ``--ros2``), then its view when one is due.

View: under imperfect sensing (``--conditions`` other than perfect), once every
``--view-every`` steps (default 10; 0: never) the team as the robot perceived it for that
step's decision (:class:`runtime.wire.messages.View`: its tracker's estimate of where each
member is at the step, or the view as sensed without a tracker, and each member's age), on
the robot's view key, right after the step's command: the log keeps it beside the world's
ground truth, and ``patternrl replay`` reports the estimation error.

Status: about once a second on the robot's status key (decision latency p50 and
p99 over the last period, loop jitter = p99 - p50 of the interval between
consecutive decisions, messages dropped, errors, safety interventions), and at once
after a brain swap with its answer.
"""

from __future__ import annotations

import contextlib
import math
from typing import TYPE_CHECKING

import numpy as np
import zenoh

from runtime.decision.local import Perception, Seen
from runtime.decision.pipeline import Decision
from runtime.robot.inbox import Step
from runtime.robot.status import RobotStats
from runtime.robot.swap_worker import SwapReply
from runtime.wire import keys
from runtime.wire.messages import (
    Command,
    MessageError,
    Slots,
    View,
    encode,
    encode_command,
    encode_status,
)

if TYPE_CHECKING:
    from runtime.ros2.robot_link import Ros2Link

__all__ = ["Outbox"]


class Outbox:
    """One robot's publishers, and the slots and view a decision stages for after it."""

    def __init__(self, robot_id: int, stats: RobotStats, view_every: int) -> None:
        self.id = robot_id
        self.stats = stats
        self.view_every = view_every
        self.ros2: Ros2Link | None = None  # --ros2: each command to it too
        self._view_pub: zenoh.Publisher | None = None  # under imperfect sensing (--view-every)
        self._view_step = -math.inf  # the step of the last view staged
        self._view: View | None = None  # staged by the decision, sent after its command
        self._slots_pub: zenoh.Publisher | None = None
        self._slots: Slots | None = None  # staged by the decision, sent before its command

    def declare(self, session: zenoh.Session, swarm: str, declared: contextlib.ExitStack,
                views: bool, slots: bool) -> None:
        """Declare the publishers (undeclared with ``declared``): command and status, the view
        when ``views``, the slots when ``slots``."""
        s, sw, z = session, swarm, declared
        self._cmd_pub = z.enter_context(
            s.declare_publisher(keys.cmd_key(sw, self.id), express=True)
        )
        self._status_pub = z.enter_context(
            s.declare_publisher(keys.status_key(sw, self.id), express=True)
        )
        if views:
            self._view_pub = z.enter_context(
                s.declare_publisher(keys.view_key(sw, self.id), express=True)
            )
        if slots:
            # batched with the command that follows it (in order, so still before it): a
            # third express publisher beside the command's and the view's lost every view
            # after the first on the world's side
            self._slots_pub = z.enter_context(
                s.declare_publisher(keys.slots_key(sw, self.id), express=False))

    @property
    def sends_views(self) -> bool:
        """Whether views are published (``--view-every`` under imperfect sensing)."""
        return self._view_pub is not None

    def stage_slots(self, msg: Slots | None) -> None:
        """Keep the slots told for this step, to send before its command."""
        self._slots = msg

    def stage_view(self, step: Step, seen: Seen, perception: Perception) -> None:
        """Keep this step's perceived team to send after its command, once every
        ``--view-every`` steps: the tracker's estimate of the team now, else the plan's view."""
        if step.step - self._view_step < self.view_every:
            return
        age = perception.last_age
        if age is None:
            return
        self._view_step = step.step
        xy = seen.plan if seen.now is None else seen.now
        try:
            self._view = View(self.id, step.step, np.asarray(step.ids), xy, age[0])
        except MessageError as e:
            self.stats.error(f"view: {e}")

    def send(self, step: int, d: Decision, brain_id: str) -> None:
        """A step's messages in order: the staged slots, the command, the staged view."""
        if self._slots is not None:  # before the command: the world steps on commands
            msg, self._slots = self._slots, None
            self._put("slots", self._slots_pub, msg)
        self.command(step, d, brain_id)
        if self._view is not None:
            view, self._view = self._view, None
            self._put("view", self._view_pub, view)

    def command(self, step: int, d: Decision, brain_id: str) -> None:
        """The command of ``d`` for ``step``, decided by the brain ``brain_id``."""
        bvx, bvy = d.brain_velocity
        if not (math.isfinite(bvx) and math.isfinite(bvy)):  # the robot held still
            bvx, bvy = d.velocity
        cmd = Command(
            robot_id=self.id,
            step=step,
            vx=d.velocity[0],
            vy=d.velocity[1],
            brain_id=brain_id[:64],
            safety_changed=d.safety_changed,
            safety_change_mps=d.safety_change_mps if math.isfinite(d.safety_change_mps) else 0.0,
            decision_us=d.decision_us,
            brain_vx=bvx,
            brain_vy=bvy,
        )
        self._cmd_pub.put(encode_command(cmd))
        if self.ros2 is not None:
            self.ros2.command(cmd.vx, cmd.vy)

    def status(self, brain_id: str, reply: SwapReply | None = None) -> None:
        """The status now, with a swap's answer when ``reply``."""
        status = self.stats.status(self.id, brain_id, reply)
        try:
            self._status_pub.put(encode_status(status))
        except MessageError as e:
            self.stats.error(f"status: {e}")

    def _put(self, what: str, pub: zenoh.Publisher | None, msg: Slots | View | None) -> None:
        """Encode and put a staged message (none staged, or no publisher: nothing)."""
        if msg is None or pub is None:
            return
        try:
            pub.put(encode(msg))
        except MessageError as e:
            self.stats.error(f"{what}: {e}")
