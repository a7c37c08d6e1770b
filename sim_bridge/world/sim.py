"""``patternrl sim``: the world process (:class:`sim_bridge.world.sim_world.SimWorld`), run.

Plays ``--patterns`` in turn with the robots that come on ``--swarm`` (see
:mod:`sim_bridge.world.sim_world` for what a step does, when a pattern is formed and how
joins and leaves are followed), records the MCAP log (``--record``; an existing
file is refused unless ``--force``), serves it live to Foxglove (``--foxglove``,
:mod:`sim_bridge.live.foxglove_live`) and prints a line per pattern, or the result as
JSON (``--json``).

Brains (``--brains``, :mod:`sim_bridge.world.brain_choice`): ``none`` leaves the robots'
brains alone; ``rule:assign`` or one brain file (``.onnx``, e.g.
``exports/general.onnx``) runs that brain for every pattern (swapped in once,
before the first, where a robot runs another); a directory of brains
(``<stem>.onnx`` + ``<stem>.json`` manifests) makes the world choose a brain per
pattern (by the manifest's ``pattern``, ``observation`` and ``n_robots``;
``--brain-kind`` says which observation to prefer) and, at every pattern change,
swap it into each robot that runs another one, through the runtime's swap
mechanism (:func:`runtime.brain.swap.swap_brain`); every answer is logged. So paper
brains, one per pattern, play a whole sequence.

ROS 2 (``--ros2``, :mod:`sim_bridge.ros2.fleet`): the robots move as a ROS 2 fleet, each
``robot_<i>`` publishing ``odom`` and taking ``cmd_vel`` Twists, in realtime; the robots run
``patternrl robot --ros2 robot_<i>``.

Holding (``--hold-steps N``): the world watches each formed pattern N steps more before
the next, the robots deciding as ever, and counts the steps after which the team is still
formed; a pattern **held** when that is at least 90 % of N
(:data:`runtime.world_config.HOLD_SHARE`, the rule of ``patternrl eval --hold-steps``). A
team that only passes through a formation (noisy sensing, ``--conditions realistic``) forms
but does not hold. The steps, travel and error per pattern stay the first passage's.

Exit codes: 0 when every pattern formed (and, with ``--hold-steps``, held); 1 when one did
not, or no robots came; 2 on bad input; 130 when interrupted (the log is finished either
way).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from types import FrameType

from runtime import heap
from runtime.conditions import parse_conditions
from runtime.decision.agreement import add_agree_argument
from runtime.decision.patterns import PatternError, make_pattern
from runtime.errors import InputError
from runtime.net.session import ZenohSetupError, add_zenoh_arguments, open_session_from_args
from runtime.wire import keys
from runtime.wire.fields import MAX_PATTERN_POINTS as MAX_TEAM
from runtime.world_config import DEFAULT_WORLD, HOLD_SHARE
from sim_bridge.live.foxglove_live import DEFAULT_ADDRESS, FoxgloveLive, parse_address
from sim_bridge.log.recorder import Recorder, check_output
from sim_bridge.world.brain_choice import BrainChoice, brains_from_arg
from sim_bridge.world.run_results import RunResult, result_dict
from sim_bridge.world.sim_world import (
    DEFAULT_PATTERNS,
    STEP_LIMIT_OVER_BOUND,
    SimConfig,
    SimWorld,
)
from sim_bridge.world.world_link import DEFAULT_MAX_AGE_STEPS

WORLD_SWITCH_INTERVAL_S = 0.001
"""The world process hands the interpreter between its threads (the step, Zenoh's receive
callbacks, the recorder's writer) at least this often (Python's default is 5 ms): a
command's callback does not wait behind the writer."""
MAX_AGE_STEPS_LIMIT = 50
"""The largest --max-command-age-steps accepted (5 s at 10 Hz)."""
MAX_HOLD_STEPS = 1000
"""The largest --hold-steps accepted (100 s at 10 Hz)."""

# --------------------------------------------------------------------------- CLI


def add_world_arguments(p: argparse.ArgumentParser, record_help: str = "write the MCAP log here"
                        ) -> None:
    """Options the world shares with ``patternrl launch``."""
    p.add_argument("--robots", type=int, default=10, help="team size N (default 10)")
    p.add_argument("--patterns", default=DEFAULT_PATTERNS,
                   help=f"comma-separated, built-ins or files (default {DEFAULT_PATTERNS})")
    p.add_argument("--record", type=Path, default=None, metavar="RUN.mcap", help=record_help)
    p.add_argument("--force", action="store_true",
                   help="overwrite the --record file if it exists (refused otherwise)")
    p.add_argument("--foxglove", nargs="?", const=DEFAULT_ADDRESS, default=None,
                   metavar="HOST:PORT",
                   help="serve the run live to Foxglove over WebSocket (needs the foxglove "
                        f"extra); default {DEFAULT_ADDRESS}, port 0 = any free port")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                   help="lockstep: wait for every command (reproducible); realtime: fixed rate")
    p.add_argument("--seed", type=int, default=0, help="seed of the start positions (default 0)")
    p.add_argument("--step-deadline-ms", type=float, default=250.0,
                   help="lockstep: a robot not answered by then holds still (default 250)")
    p.add_argument("--max-steps", type=int, default=None,
                   help=f"step limit per pattern (default: {STEP_LIMIT_OVER_BOUND}x the "
                        f"pattern's steps lower bound, at least {DEFAULT_WORLD.step_limit})")
    p.add_argument("--hold-steps", type=int, default=0, metavar="N",
                   help="watch each formed pattern N steps more before the next; it held when "
                        f"still formed on {HOLD_SHARE * 100:.0f}%% of them, else the run fails "
                        "(exit 1) as if it had not formed; steps, travel and error stay the "
                        f"first passage's (0..{MAX_HOLD_STEPS}, default 0: the next pattern at "
                        "once)")
    p.add_argument("--rate-hz", type=float, default=1.0 / DEFAULT_WORLD.dt_s,
                   help="realtime step rate (default 1/dt = 10)")
    p.add_argument("--min-rate-hz", type=float, default=None,
                   help="realtime: while most robots cannot keep up, the world slows down "
                        "to this rate at the slowest (default --rate-hz / 4; = --rate-hz: "
                        "a fixed rate)")
    p.add_argument("--max-command-age-steps", type=int, default=None, metavar="K",
                   help="a robot without a command for the step in time moves on its newest "
                        "one if decided from the poses of the last K steps, else holds still "
                        f"(default: {DEFAULT_MAX_AGE_STEPS} in realtime, 0 in lockstep)")
    p.add_argument("--brain-kind", choices=("general", "paper"), default="general",
                   help="with a brains directory, which observation to prefer (default general)")
    p.add_argument("--conditions", default="perfect",
                   help="the wheels' conditions the world applies (gain_noise, act_noise_mps, "
                        "kinematics=diff): a preset (perfect, realistic, harsh) with field=value "
                        "overrides; launch hands the same to every robot, which senses under its "
                        "sensing fields (default perfect)")
    p.add_argument("--estimator", action="store_true",
                   help="launch: every robot tracks its peers and decides on the estimates")
    add_agree_argument(p, "launch's robots")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--ros2", action="store_true",
                   help="the robots as a ROS 2 fleet: /robot_<i>/odom out, /robot_<i>/cmd_vel "
                        "(Twist) in, /swarm/poses and /swarm/markers for RViz; realtime "
                        "(needs the ros2 extra; robots run with --ros2 robot_<i>)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--swarm", default="demo", help="swarm name ([A-Za-z0-9_-]+, default demo)")
    add_world_arguments(p)
    p.add_argument("--brains", default="none",
                   help="none (robots keep theirs), rule:assign, a brain file (.onnx: one brain "
                        "for every pattern), or a directory of brains: the world swaps each "
                        "pattern's brain in at every pattern change")
    p.add_argument("--wait-robots-s", type=float, default=30.0,
                   help="start when --robots are alive, or after this long with >= 2")
    add_zenoh_arguments(p)


def config_from_args(args: argparse.Namespace, brains: dict[str, BrainChoice] | None) -> SimConfig:
    """Check the world's options; raises :class:`InputError` with a one-line reason."""
    try:
        keys.validate_swarm(args.swarm)
    except ValueError as e:
        raise InputError(str(e)) from None
    if not 2 <= args.robots <= MAX_TEAM:
        raise InputError(f"--robots must be in 2..{MAX_TEAM} (the largest team a pattern "
                         f"message carries), got {args.robots}")
    patterns = [p.strip() for p in str(args.patterns).split(",") if p.strip()]
    if not patterns:
        raise InputError("--patterns names no pattern")
    for p in patterns:
        try:
            make_pattern(p, args.robots)
        except PatternError as e:
            raise InputError(str(e)) from None
    for name in ("step_deadline_ms", "rate_hz"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"--{name.replace('_', '-')} must be > 0, got {v}")
    if args.max_steps is not None and args.max_steps < 1:
        raise InputError(f"--max-steps must be >= 1, got {args.max_steps}")
    hold = getattr(args, "hold_steps", 0)
    if not 0 <= hold <= MAX_HOLD_STEPS:
        raise InputError(f"--hold-steps must be in 0..{MAX_HOLD_STEPS}, got {hold}")
    if getattr(args, "ros2", False):  # realtime: a ROS 2 base applies its newest Twist
        args.mode = "realtime"
        from runtime.ros2.environment import import_rclpy

        import_rclpy()
    conditions = parse_conditions(getattr(args, "conditions", "perfect"))
    min_rate = getattr(args, "min_rate_hz", None)
    if min_rate is not None and not (math.isfinite(min_rate) and 0 < min_rate <= args.rate_hz):
        raise InputError(f"--min-rate-hz must be in (0, --rate-hz], got {min_rate}")
    age = getattr(args, "max_command_age_steps", None)
    if age is not None and not 0 <= age <= MAX_AGE_STEPS_LIMIT:
        raise InputError(f"--max-command-age-steps must be in 0..{MAX_AGE_STEPS_LIMIT}, "
                         f"got {age}")
    return SimConfig(
        swarm=args.swarm, robots=args.robots, patterns=patterns, mode=args.mode, seed=args.seed,
        step_deadline_ms=args.step_deadline_ms, max_steps=args.max_steps, hold_steps=hold,
        rate_hz=args.rate_hz,
        brains=brains, wait_robots_s=getattr(args, "wait_robots_s", 30.0),
        conditions=conditions,
        ros2=bool(getattr(args, "ros2", False)),
        max_command_age_steps=age, min_rate_hz=min_rate,
    )


def start_live(address: str | None, say: Callable[[str], None]) -> FoxgloveLive | None:
    """The live server of ``--foxglove`` (None without it); its URL is said."""
    if address is None:
        return None
    host, port = parse_address(address)
    live = FoxgloveLive(host, port)
    say(f"Foxglove live view on {live.url} (Foxglove: Open connection, that URL)")
    return live


def open_recorder(args: argparse.Namespace, live: FoxgloveLive | None) -> Recorder | None:
    """The recorder of ``--record`` and/or ``--foxglove``; :class:`InputError` for a bad path."""
    if args.record is None and live is None:
        return None
    return Recorder(args.record, live=live, overwrite=bool(args.force), threaded=True)


def run(args: argparse.Namespace) -> int:
    patterns = [p.strip() for p in str(args.patterns).split(",") if p.strip()]
    try:
        brains = brains_from_arg(args.brains, patterns, args.robots, args.brain_kind)
        cfg = config_from_args(args, brains)
        if args.record is not None:
            check_output(args.record, args.force)
        if args.foxglove is not None:
            parse_address(args.foxglove)
    except InputError as e:
        print(f"patternrl sim: error: {e}", file=sys.stderr)
        return 2
    try:
        session = open_session_from_args(args, "world", cfg.swarm)
    except ZenohSetupError as e:
        print(f"patternrl sim: error: {e}", file=sys.stderr)
        return 2
    live: FoxgloveLive | None = None
    try:
        live = start_live(args.foxglove, lambda m: print(f"sim: {m}", file=sys.stderr,
                                                         flush=True))
        rec = open_recorder(args, live)
    except InputError as e:
        if live is not None:
            live.close()
        session.close()  # type: ignore[no-untyped-call]
        print(f"patternrl sim: error: {e}", file=sys.stderr)
        return 2
    sys.setswitchinterval(WORLD_SWITCH_INTERVAL_S)
    world = SimWorld(cfg, session, rec)
    heap.settle()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        world.stop()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        res = world.run()
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if rec is not None:
            rec.close()
        if live is not None:
            live.close()
        session.close()  # type: ignore[no-untyped-call]
    print_result(res, args.json)
    if res.outcome == "interrupted":
        return 130
    return 0 if res.all_held else 1


def print_result(res: RunResult, as_json: bool) -> None:
    """A line per pattern and the outcome on stdout, or the one JSON line."""
    if as_json:
        print(json.dumps(result_dict(res)))
        return
    for p in res.phases:
        held = p.hold_text()
        print(f"{p.pattern:<10} {'formed' if p.formed else 'NOT formed':<10} "
              f"{p.steps:>4} steps" + (f", {held}" if held else "")
              + f" (lower bound {p.lower_bound_steps}), "
              f"travel {p.travel_m:.2f} m (lower bound {p.lower_bound_travel_m:.2f}), "
              f"{p.collisions} collisions, min sep {p.min_separation_m:.3f} m, "
              f"{p.deadline_misses} deadline misses")
    print(f"{res.outcome}: {res.steps} steps in {res.wall_s:.1f} s"
          + (f", log {res.record}" if res.record else ""))
