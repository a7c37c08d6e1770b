"""``patternrl robot``: one robot's process. Check the options, load the brain, run the
:class:`runtime.robot.robot.Robot` until a signal or silence.

Brains must be signed (:mod:`runtime.brain.signing`) by a key the robot trusts: the
project's release key, the user's own key and every ``--trust`` key; a brain
file or swap without such a signature is refused (rule brains need none).

Exit codes: 0 on SIGINT/SIGTERM or ``--exit-after-silence-s``; 2 on bad input
(missing, invalid or untrusted brain, bad pattern, bad options), with one line
on stderr; 1 when the world is gone or never came (``--world-timeout-s``: no
pose for that long, counted from the start until the first) or on an
unexpected failure.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from types import FrameType
from typing import Final

from runtime import heap
from runtime.brain.brain import BrainError, load_brain, short_id
from runtime.core import kernel_status
from runtime.errors import InputError
from runtime.log import Log, one_line
from runtime.net.session import ZenohSetupError, open_session_from_args
from runtime.robot.cli import add_arguments, config_from_args
from runtime.robot.robot import Robot
from runtime.world_config import DEFAULT_WORLD

# add_arguments and run: the sub-command interface patternrl.cli loads from this module
__all__ = ["add_arguments", "heavy_modules", "run"]


HEAVY_MODULES: Final = ("torch", "onnx", "pymunk", "mcap", "matplotlib")
ROBOT_ZENOH_RUNTIME: Final = (
    "(app: (worker_threads: 1), rx: (handover: app), tx: (handover: app), "
    "acc: (handover: app), net: (handover: app))"
)
"""Zenoh's runtimes in a robot process (``ZENOH_RUNTIME``, unless set): one thread for all
of them. A robot has one link, one subscription that matters and one publisher; Zenoh's
default gives it five threads (app, acc, tx, rx x2) that hand every message from one to
the next, each hand-over a wake-up. Measured side by side (``benchmarks/compare.py ...
swarm_scale.py``, load 40-55): lockstep 10 robots 149 -> 204 steps/s, CPU per robot-step
0.64 -> 0.43 ms; realtime 100 robots 9.5 % -> 5.5 % of decisions late; 12 -> 8 threads."""


def heavy_modules() -> list[str]:
    """The heavy packages this process has loaded (a robot should have none)."""
    return [m for m in HEAVY_MODULES if m in sys.modules]


def run(args: argparse.Namespace) -> int:
    """``patternrl robot``: check the options, load the brain, run until a signal or silence."""
    world = DEFAULT_WORLD
    log = Log(f"robot {args.id}", args.json_logs, "debug" if args.verbose else "info")
    try:
        cfg, safety = config_from_args(args, world)
        brain = load_brain(args.brain, world, cfg.trust)
        if cfg.ros2 is not None:  # rclpy's libraries on the loader's path, before any thread
            from runtime.ros2.environment import ensure_library_path, import_rclpy

            ensure_library_path()
            import_rclpy()
    except (InputError, BrainError) as e:
        print(f"patternrl robot: error: {one_line(str(e))}", file=sys.stderr)
        return 2
    sys.setswitchinterval(0.001)  # a validating swap thread yields the GIL quickly
    os.environ.setdefault("ZENOH_RUNTIME", ROBOT_ZENOH_RUNTIME)  # before the first session
    stop = threading.Event()
    robot_ref: list[Robot] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()
        if robot_ref:
            robot_ref[0].stop()

    old_handlers = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            session = open_session_from_args(args, "robot", cfg.swarm)
        except ZenohSetupError as e:
            print(f"patternrl robot: error: {e}", file=sys.stderr)
            return 2
        # the robot undeclares what it declared, then the session closes
        with session, contextlib.closing(Robot(cfg, brain, session, world, safety, log)) as robot:
            robot_ref.append(robot)
            if stop.is_set():
                return 0
            robot.start()
            heap.settle()
            log(
                "info",
                "start",
                f"swarm {cfg.swarm}, {cfg.mode}, brain {short_id(brain.brain_id)} "
                f"({brain.spec.name}), safety {'orca' if safety else 'off'}, "
                f"decision {kernel_status()}",
            )
            code = robot.run()
        heavy = heavy_modules()
        st = robot.stats
        log(
            "info",
            "stop",
            f"after {st.steps} steps",
            dropped=st.dropped,
            errors=st.errors,
            backlog_skipped=robot.backlog_skipped,
            heavy_modules=",".join(heavy) if heavy else "none",
            **({} if robot.slot_talk is None else {
                "slots_heard": robot.slot_talk.heard_messages,
                "leader_steps": robot.slot_talk.adopted_steps,
                "frame_steps": robot.slot_talk.frame_steps}),
        )
        return code
    except Exception as e:  # unexpected: one line, no traceback
        print(f"patternrl robot: error: {one_line(f'{type(e).__name__}: {e}')}", file=sys.stderr)
        return 1
    finally:
        for s, h in old_handlers.items():
            signal.signal(s, h)
