"""A robot's brain swaps: validated off the loop, swapped in between two decisions.

A :class:`runtime.wire.messages.BrainMsg` arrives on a Zenoh thread
(:meth:`SwapWorker.offer`: queued, at most :data:`SWAP_QUEUE` waiting). The
worker thread decodes it, keeps it if it is addressed to this robot (or to
all), and validates it (:func:`runtime.brain.brain.load_sent_brain`: digest, a
signature by a key the robot trusts (``trust``), onnxruntime load,
input/output shapes, finite outputs on probes, warm-up; and
the brain must accept the team size the robot sees now). The robot's loop,
between two decisions, calls :meth:`SwapWorker.apply`: every validated brain
is installed and every request gets a :class:`SwapReply` for the robot's
status. A refused brain leaves the old one running; a request answered before
(a re-send) is answered again without swapping twice.
"""

from __future__ import annotations

import queue
import threading
from collections import deque
from collections.abc import Callable
from typing import Final, NamedTuple

from runtime.brain.brain import Brain, BrainError, load_sent_brain, short_id
from runtime.brain.signing import TrustedKeys
from runtime.log import Log, one_line
from runtime.wire.messages import BrainMsg, MessageError, decode_brain
from runtime.world_config import WorldConfig

__all__ = ["SWAP_QUEUE", "SwapReply", "SwapWorker"]

SWAP_QUEUE: Final = 4
RECENT_REPLIES: Final = 64  # requests remembered, to answer a re-send without swapping again


class SwapReply(NamedTuple):
    """The answer to one swap request, as the robot's status carries it."""

    request: str
    accepted: bool
    reason: str
    """Why refused (one line), ``already running``, or empty."""
    old_brain: str
    new_brain: str
    """The brain running after the request: the old one when refused."""


class SwapWorker:
    """The queue, thread and hand-over of one robot's brain swaps.

    ``wake`` is the condition the robot's loop waits on: the worker notifies it
    when a swap is ready, and :meth:`busy` must be called holding it.
    ``team_size`` gives the number of robots the robot decides for now (0 when
    none); ``drop(what, why)`` counts a malformed message, ``error(text)`` an
    error of the worker itself. ``trust``: the keys a brain must be signed by
    (None: no signature check, for tools and tests that build brains in place).
    """

    def __init__(
        self,
        robot_id: int,
        world: WorldConfig,
        log: Log,
        wake: threading.Condition,
        team_size: Callable[[], int],
        drop: Callable[[str, str], None],
        error: Callable[[str], None],
        trust: TrustedKeys | None = None,
    ) -> None:
        self.robot_id = robot_id
        self.trust = trust
        self.world = world
        self._log = log
        self._wake = wake
        self._team_size = team_size
        self._drop = drop
        self._error = error
        self._queue: queue.Queue[bytes] = queue.Queue(maxsize=SWAP_QUEUE)
        self._validated: deque[tuple[str, Brain | None, str]] = deque()  # (request, brain, why)
        self._replies: deque[SwapReply] = deque()
        self._recent: dict[str, SwapReply] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="brain-swap", daemon=True)

    # ---------------------------------------------------------------- threads

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        """Stop the worker (it ends after the brain it is validating, if any)."""
        self._stop.set()
        try:
            self._queue.put_nowait(b"")
        except queue.Full:
            pass

    def offer(self, payload: bytes) -> None:
        """A brain message's bytes, from a Zenoh callback; dropped when the queue is full."""
        try:
            self._queue.put_nowait(payload)
        except queue.Full:
            self._drop("brain", "swap queue full")

    def _run(self) -> None:
        # Not niced on purpose: this thread holds the GIL in stretches, and a
        # low-priority GIL holder would stall the control loop under CPU load.
        while not self._stop.is_set():
            payload = self._queue.get()
            if self._stop.is_set() or not payload:
                return
            try:
                self._handle(payload)
            except Exception as e:  # never let a brain take the worker down
                self._error(f"swap worker: {e}")

    def _handle(self, payload: bytes) -> None:
        try:
            msg = decode_brain(payload)
        except MessageError as e:
            self._drop("brain", str(e))
            return
        if msg.target_robots and self.robot_id not in msg.target_robots:
            return
        done = self._recent.get(msg.request_id)
        if done is not None:  # a re-sent request: answer again, do not swap again
            with self._wake:
                self._replies.append(done._replace(request=msg.request_id))
                self._wake.notify()
            return
        brain, reason = self._validate(msg)
        with self._wake:
            self._validated.append((msg.request_id, brain, reason))
            self._wake.notify()

    def _validate(self, msg: BrainMsg) -> tuple[Brain | None, str]:
        try:
            brain = load_sent_brain(msg.manifest_json, msg.onnx_bytes, self.world, self.trust)
            n = self._team_size()
            if n and not brain.spec.accepts_team(n):
                raise BrainError(f"brain observes {brain.spec.n_robots} robots, the team has {n}")
            return brain, ""
        except BrainError as e:
            return None, one_line(str(e))

    # ------------------------------------------------------------- robot loop

    def busy(self) -> bool:
        """A swap or an answer waits for :meth:`apply` (call holding ``wake``)."""
        return bool(self._validated or self._replies)

    def apply(
        self, running: Callable[[], str], install: Callable[[Brain], None]
    ) -> list[SwapReply]:
        """Between two decisions: install every validated brain; the replies to publish.

        ``running()`` is the id of the brain running now, ``install(brain)``
        makes ``brain`` the one that decides from the next step on.
        """
        while True:
            with self._wake:
                if not self._validated:
                    break
                request, brain, reason = self._validated.popleft()
            old = running()
            if brain is None:
                reply = SwapReply(request, False, reason, old, old)
                self._log(
                    "info", "swap", f"refused: {reason}", request=request, brain=short_id(old)
                )
            else:
                install(brain)
                why = "already running" if brain.brain_id == old else reason
                reply = SwapReply(request, True, why, old, brain.brain_id)
                self._log(
                    "info",
                    "swap",
                    "accepted",
                    request=request,
                    old=short_id(old),
                    new=short_id(brain.brain_id),
                )
            self._recent[request] = reply
            while len(self._recent) > RECENT_REPLIES:
                self._recent.pop(next(iter(self._recent)))
            self._replies.append(reply)
        out: list[SwapReply] = []
        while self._replies:
            out.append(self._replies.popleft())
        return out
