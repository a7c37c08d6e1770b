"""``patternrl robot`` options: their definitions and their checks."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

from runtime.brain.signing import TrustedKeys, default_trust
from runtime.conditions import PERFECT, Conditions, parse_conditions
from runtime.decision.agreement import DEFAULT_AGREE, add_agree_argument
from runtime.decision.patterns import PatternError, make_pattern
from runtime.decision.safety import OrcaParams, uncertainty_params
from runtime.errors import InputError
from runtime.net.session import add_zenoh_arguments
from runtime.ros2.options import Ros2Options, add_ros2_arguments, ros2_options_from_args
from runtime.wire import keys
from runtime.world_config import WorldConfig

__all__ = ["FALLBACK_RULE", "NONFINITE_FALLBACKS", "VIEW_EVERY", "RobotConfig", "add_arguments",
           "config_from_args"]

NONFINITE_FALLBACKS = ("rule", "hold")
VIEW_EVERY = 10
"""Steps between two views a robot under imperfect sensing publishes, by default: a 100-robot
swarm at 10 Hz sends 100 views a second (about 240 KB), a tenth of its poses' messages."""
FALLBACK_RULE = "rule:frame-balanced"
"""The rule a robot falls back on when its brain's output is not finite: the shipped plan
brains' own base, so a step decided by it is the step the brain was built on."""


@dataclass
class RobotConfig:
    """How one robot runs (``patternrl robot`` options; times in seconds)."""

    swarm: str
    robot_id: int
    mode: str = "lockstep"
    rate_hz: float = 10.0
    lockstep_deadline_s: float = 0.02
    watchdog_s: float = 1.0
    stale_s: float = 1.0
    exit_after_silence_s: float = 0.0
    status_period_s: float = 1.0
    pattern: str | None = None
    world_timeout_s: float = 30.0
    nonfinite_fallback: str = "rule"
    """What decides a step whose brain output is not finite: ``rule`` (the brain's base rule,
    :data:`FALLBACK_RULE`, or the robot's own rule brain) or ``hold`` (hold still)."""
    trust: TrustedKeys | None = None
    """Keys a brain must be signed by (None: unchecked, for embedding and tests)."""
    conditions: Conditions = PERFECT
    """Sensing the robot simulates on the world's poses (noise, range, latency, loss), for a
    simulated swarm; a real robot's sensing is real (leave it perfect there)."""
    sensing_seed: int = 0
    """Seeds the simulated sensing (with the robot id)."""
    estimator: bool = False
    """Track peers (``runtime.decision.estimator``) and decide on the estimates."""
    agree: str = DEFAULT_AGREE
    """What it tells its team and hears of theirs (:data:`runtime.decision.agreement.AGREE_MODES`):
    under noise the leader's plan frame, which every robot plans in (``frame``); with ``slots``
    under imperfect sensing also each robot's slot, and a robot that hears a peer claim its
    slot goes by the leader's assignment; ``off``: nothing."""
    view_every: int = VIEW_EVERY
    """Under imperfect sensing, publish the team as perceived (a
    :class:`runtime.wire.messages.View`) for one decision every this many steps (0: never)."""
    ros2: Ros2Options | None = None
    """A ROS 2 robot: pose from a ROS 2 topic, command as a Twist (``--ros2``)."""
    debug_delay_ms: float = 0.0
    """Testing only: each command goes out after a random extra delay in [0, this] ms
    (seeded by the robot id), to check that late commands never make the swarm unsafe."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Every option of ``patternrl robot``."""
    parser.epilog = (
        "environment: ZENOH_RUNTIME sets Zenoh's threads (default here: one); the start line "
        "says whether the decision runs compiled (runtime/core, built at install)"
    )
    parser.add_argument("--swarm", required=True, help="swarm name ([A-Za-z0-9_-]+)")
    parser.add_argument("--id", type=int, required=True, help="this robot's id (>= 0)")
    parser.add_argument(
        "--brain", required=True, help="a brain: path to .onnx (manifest beside it) or rule:assign"
    )
    parser.add_argument(
        "--mode",
        choices=("lockstep", "realtime"),
        default=None,
        help="(default lockstep; realtime with --ros2)",
    )
    parser.add_argument(
        "--rate-hz",
        type=float,
        default=None,
        help="realtime decision rate from per-robot pose keys (default 1/dt = 10); with the "
        "world's all-poses message the robot decides on each step as it arrives",
    )
    parser.add_argument(
        "--pattern",
        default=None,
        help="target until the swarm's pattern key says otherwise: built-in name or file",
    )
    parser.add_argument(
        "--lockstep-deadline-s",
        type=float,
        default=0.02,
        help="decide step t this long after its first pose even if poses are missing "
        "(below --watchdog-s)",
    )
    parser.add_argument(
        "--watchdog-s", type=float, default=1.0, help="hold still after this long without poses"
    )
    parser.add_argument(
        "--stale-s", type=float, default=1.0, help="a peer's pose older than this is absent"
    )
    parser.add_argument(
        "--exit-after-silence-s",
        type=float,
        default=0.0,
        help="exit (code 0) once the world has been silent this long (0: never); keep it above "
        "the world's wait for a team's first steps (5 s by default), or robots leave while "
        "the world waits for a slow one",
    )
    parser.add_argument(
        "--world-timeout-s",
        type=float,
        default=30.0,
        help="exit (code 1, one line) when the world is silent this long, or when no pose "
        "came this long after the start (default 30; 0: never)",
    )
    parser.add_argument(
        "--nonfinite-fallback",
        choices=NONFINITE_FALLBACKS,
        default="rule",
        help="a step whose brain output is not finite (NaN, inf) is decided by the rule "
        f"({FALLBACK_RULE}, or the robot's own rule brain) or the robot holds still (hold); "
        "counted in the status (nonfinite_fallbacks) either way (default rule)",
    )
    parser.add_argument(
        "--trust",
        action="append",
        default=[],
        metavar="KEY.pub",
        help="run brains signed by this public key, or by any *.pub of a directory "
        "(repeatable); the release key and your own key are always trusted",
    )
    parser.add_argument("--status-period-s", type=float, default=1.0, help=argparse.SUPPRESS)
    parser.add_argument("--debug-delay-ms", type=float, default=0.0, help=argparse.SUPPRESS)
    cg = parser.add_argument_group("sensing")
    cg.add_argument(
        "--conditions",
        default="perfect",
        help="in a simulated swarm, sense the world's poses under these conditions: a preset "
        "(perfect, realistic, harsh) with field=value overrides (runtime/conditions.py); the "
        "safety margin and the landing follow the noise and latency it knows (default perfect)",
    )
    cg.add_argument("--sensing-seed", type=int, default=0,
                    help="seed of the simulated sensing, with the robot id (default 0)")
    cg.add_argument("--estimator", action="store_true",
                    help="track each peer (alpha-beta filter, latency compensation) and decide "
                    "on the estimates")
    add_agree_argument(cg, "the team's robots")
    cg.add_argument("--view-every", type=int, default=VIEW_EVERY, metavar="N",
                    help="under imperfect --conditions, publish the team as this robot perceived "
                    "it (robot/<id>/view) for one decision every N steps, so the log holds "
                    "it and 'patternrl replay' reports the estimation error; 0: never "
                    f"(default {VIEW_EVERY})")
    g = parser.add_argument_group("safety filter (ORCA)")
    d = OrcaParams()
    g.add_argument("--safety", choices=("orca", "off"), default="orca", help="(default orca)")
    g.add_argument(
        "--orca-time-horizon-s",
        type=float,
        default=d.time_horizon_s,
        help=f"avoid collisions this far ahead (default {d.time_horizon_s})",
    )
    g.add_argument(
        "--orca-radius-margin-m",
        type=float,
        default=d.radius_margin_m,
        help=f"added to R for the filter (default {d.radius_margin_m})",
    )
    g.add_argument(
        "--orca-max-neighbours",
        type=int,
        default=d.max_neighbours,
        help=f"nearest neighbours considered (default {d.max_neighbours})",
    )
    g.add_argument(
        "--orca-neighbour-dist-m",
        type=float,
        default=d.neighbour_dist_m,
        help=f"neighbours farther are ignored (default {d.neighbour_dist_m})",
    )
    g.add_argument(
        "--orca-keep-right-rad",
        type=float,
        default=d.keep_right_rad,
        help=f"deadlock breaking turn, 0 = plain RVO2 (default {d.keep_right_rad})",
    )
    g.add_argument(
        "--orca-no-landing",
        action="store_true",
        help="keep the full horizon at the end of a plan too (default: a team on a "
        "synchronised plan filters with the plan's time left when it is shorter)",
    )
    add_ros2_arguments(parser)
    add_zenoh_arguments(parser)
    lg = parser.add_argument_group("logging")
    lg.add_argument("--json-logs", action="store_true", help="one JSON object per log line")
    lg.add_argument("-v", "--verbose", action="store_true", help="debug events too")


def config_from_args(
    args: argparse.Namespace, world: WorldConfig
) -> tuple[RobotConfig, OrcaParams | None]:
    """The robot's config and safety filter (None: off) from the parsed options.

    Raises :class:`InputError` with a one-line reason for a bad option.
    """
    try:
        keys.validate_swarm(args.swarm)
    except ValueError as e:
        raise InputError(str(e)) from None
    if args.id < 0:
        raise InputError(f"--id must be >= 0, got {args.id}")
    rate = args.rate_hz if args.rate_hz is not None else 1.0 / world.dt_s
    for name, v in (
        ("--rate-hz", rate),
        ("--watchdog-s", args.watchdog_s),
        ("--stale-s", args.stale_s),
        ("--status-period-s", args.status_period_s),
        ("--orca-time-horizon-s", args.orca_time_horizon_s),
        ("--orca-neighbour-dist-m", args.orca_neighbour_dist_m),
    ):
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v}")
    for name, v in (
        ("--lockstep-deadline-s", args.lockstep_deadline_s),
        ("--exit-after-silence-s", args.exit_after_silence_s),
        ("--world-timeout-s", args.world_timeout_s),
        ("--orca-radius-margin-m", args.orca_radius_margin_m),
        ("--debug-delay-ms", args.debug_delay_ms),
    ):
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"{name} must be >= 0, got {v}")
    if args.lockstep_deadline_s >= args.watchdog_s:  # else a lost pose holds it for good
        raise InputError(f"--lockstep-deadline-s must be below --watchdog-s "
                         f"({args.watchdog_s:g}), got {args.lockstep_deadline_s:g}")
    if args.view_every < 0:
        raise InputError(f"--view-every must be >= 0 (0: no views), got {args.view_every}")
    if args.orca_max_neighbours < 1:
        raise InputError("--orca-max-neighbours must be >= 1")
    conditions = parse_conditions(args.conditions)
    if args.pattern is not None:
        try:
            make_pattern(args.pattern, 4, world)  # readable and well-formed
        except PatternError as e:
            # a pattern fine for the real team may be too dense for 4: only reject unreadable
            if "closer than 2R" not in str(e):
                raise InputError(str(e)) from None
    safety = (
        None
        if args.safety == "off"
        else OrcaParams(
            time_horizon_s=args.orca_time_horizon_s,
            radius_margin_m=args.orca_radius_margin_m,
            max_neighbours=args.orca_max_neighbours,
            neighbour_dist_m=args.orca_neighbour_dist_m,
            keep_right_rad=args.orca_keep_right_rad,
            landing=not args.orca_no_landing,
        )
    )
    ros2 = ros2_options_from_args(args)
    cfg = RobotConfig(
        swarm=args.swarm,
        robot_id=args.id,
        mode=args.mode or ("realtime" if ros2 is not None else "lockstep"),
        rate_hz=rate,
        lockstep_deadline_s=args.lockstep_deadline_s,
        watchdog_s=args.watchdog_s,
        stale_s=args.stale_s,
        exit_after_silence_s=args.exit_after_silence_s,
        status_period_s=args.status_period_s,
        pattern=args.pattern,
        world_timeout_s=args.world_timeout_s,
        nonfinite_fallback=args.nonfinite_fallback,
        trust=default_trust(args.trust),
        debug_delay_ms=args.debug_delay_ms,
        conditions=conditions,
        estimator=args.estimator,
        agree=args.agree,
        sensing_seed=args.sensing_seed,
        view_every=args.view_every,
        ros2=ros2,
    )
    if safety is not None:
        safety = uncertainty_params(safety, conditions, world)
    return cfg, safety
