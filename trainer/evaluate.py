"""``patternrl eval``: how good a brain is, in numbers.

The brain runs exactly as on a robot: :func:`runtime.brain.brain.load_brain` loads
it (onnxruntime, the manifest's observation spec, validation), and
:func:`runtime.decision.pipeline.decide_batch` makes every decision with the robot's
own pipeline (shared slot assignment with hysteresis, the same observation
builder, deterministic action = the policy mean, clamp to v_max, the ORCA
safety filter unless ``--safety off``). The world is the training world
(:class:`trainer.world.training_world.BatchWorld`) with lower bounds computed per episode.
Episode ``e`` is the first episode of env ``e`` of a world seeded with
``--seed``: the same seed gives the same starts, whatever the brain.

Reported (``--json`` prints one object with these keys):

=================== ==============================================================
success_rate        formed within the step limit with no collision, and held (at least
                    90 % of the next ``--hold-steps`` steps still formed), fraction
formed_rate         formed within the step limit, collisions or not
collisions          colliding pairs summed over all episodes (and per episode),
                    the hold window's included
held_rate           of the formed episodes, the share that held
hold_share          of the formed episodes, the mean share of the window formed
conditions          the sensing and wheels (``--conditions``, ``runtime.conditions``)
steps_ratio         mean over formed episodes of steps / lower-bound steps
travel_ratio        mean over formed episodes of travel / lower-bound travel
formation_error     mean final formation error (m)
safety_interventions fraction of robot-steps where the filter changed the command
min_separation_m    closest approach of two robot centres along the commanded
                    straight moves, over all steps and episodes (m; below 2R is
                    a collision: the world's contact model then pushes the
                    discs apart, so the positions themselves never show it)
=================== ==============================================================

``EvalResult.episode_stats`` keeps the per-episode numbers (formed, steps,
travel, both lower bounds, collisions, min separation) for paired comparisons
of brains on the same seeds; ``--json`` leaves them out.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from runtime.brain.brain import Brain, BrainError, load_brain
from runtime.conditions import PERFECT, Conditions, parse_conditions
from runtime.decision.agreement import DEFAULT_AGREE, add_agree_argument
from runtime.decision.formation import min_swept_separation
from runtime.decision.local import LocalDecisions
from runtime.decision.patterns import PatternError, make_pattern, pattern_label
from runtime.decision.pipeline import decide_batch
from runtime.decision.safety import (
    SAFETY_MODES,
    OrcaParams,
    pattern_guard_note,
    safety_mode,
    safety_params,
)
from runtime.errors import InputError
from runtime.types import Array, BoolArray
from runtime.world_config import DEFAULT_WORLD, HOLD_SHARE, WorldConfig
from trainer.adversary import ADVERSARY, ChargeBrain
from trainer.world.episodes import RANDOM_PATTERN, check_pattern
from trainer.world.training_world import BatchWorld

_T = TypeVar("_T", bound=np.generic)
HOLD_STEPS = 20
"""After a team first forms, it is watched this many steps more (a formation holds when
formed on :data:`~runtime.world_config.HOLD_SHARE` of them, the world's rule too)."""

DEFAULT_EVAL_SEED = 1_000_000
"""Training uses ``--seed`` (default 0) and selects checkpoints on ``seed + 1_000_003``."""


@dataclass
class EvalResult:
    brain: str
    brain_id: str
    pattern: str
    n_robots: int
    episodes: int
    seed: int
    safety: str
    success_rate: float
    formed_rate: float
    collisions: int
    collisions_per_episode: float
    steps_ratio: float
    travel_ratio: float
    formation_error: float
    mean_steps: float
    safety_interventions: float
    wall_s: float
    min_separation_m: float = math.nan
    orca: dict[str, float] | None = None
    """The safety filter's parameters (None with the filter off)."""
    conditions: str = "perfect"
    """The conditions' preset name or spec (``runtime.conditions``)."""
    estimator: bool = False
    hold_steps: int = 0
    """Steps watched after the first passage (0: success at the first passage)."""
    held_rate: float = math.nan
    """Of the formed episodes, the share that held (>= HOLD_SHARE of the window formed)."""
    hold_share: float = math.nan
    """Of the formed episodes, the mean share of the hold window's steps formed."""
    start: str = "random"
    """Where the episodes start: ``random`` starts, or the pattern they start formed in."""
    agree: str = "off"
    """What the robots told each other: ``off`` (nothing), ``frame`` (the leader its plan's
    frame) or ``slots`` (every robot its slot, the leader its assignment and frame too;
    :mod:`runtime.decision.agreement`)."""
    episode_stats: dict[str, list[float]] = field(default_factory=dict, repr=False)
    """Per episode (index e = env e): formed, steps, travel_m, lower_bound_steps,
    lower_bound_travel_m, collisions, min_separation_m."""

    def to_dict(self) -> dict[str, Any]:
        return {
            k: (None if isinstance(v, float) and math.isnan(v) else v)
            for k, v in asdict(self).items()
            if k != "episode_stats"
        }

    def manifest_block(self) -> dict[str, Any]:
        """The ``evaluation`` block of a brain manifest."""
        d = self.to_dict()
        return {
            "episodes": self.episodes,
            "seeds": [self.seed],
            "hold_steps": self.hold_steps,
            "seeding": "episode e is the first episode of env e of BatchWorld(seed)",
            "safety": self.safety,
            **({"orca": self.orca} if self.orca is not None else {}),
            **{
                k: d[k]
                for k in (
                    "success_rate",
                    "formed_rate",
                    "collisions",
                    "collisions_per_episode",
                    "steps_ratio",
                    "travel_ratio",
                    "formation_error",
                    "mean_steps",
                    "safety_interventions",
                )
            },
        }


def _read_only(a: NDArray[_T]) -> NDArray[_T]:
    """A view of ``a`` that a caller cannot write through."""
    out = a.view()
    out.flags.writeable = False
    return out


def evaluate_brain(
    brain: Brain,
    pattern: str,
    n_robots: int,
    episodes: int,
    seed: int = DEFAULT_EVAL_SEED,
    safety: OrcaParams | None = OrcaParams(),  # noqa: B008 - frozen, immutable default
    world: WorldConfig = DEFAULT_WORLD,
    progress: bool | None = None,
    label: str = "",
    conditions: Conditions = PERFECT,
    estimator: bool = False,
    hold_steps: int = HOLD_STEPS,
    naive: bool = False,
    on_step: Callable[[Array, Array, BoolArray], None] | None = None,
    start_pattern: str | None = None,
    agree: bool | str = DEFAULT_AGREE,
) -> EvalResult:
    """Run ``episodes`` seeded episodes with the brain deciding as on a robot.

    In the perfect world (and without the estimator) every robot of a team sees the same
    team, and one batch decision per step serves them all; otherwise each robot decides on
    its own view, with its own safety filter sized for the conditions and, on a
    differential-drive base, its own heading (:class:`runtime.decision.local.LocalDecisions`;
    ``naive``: without what a robot knows of its sensing and wheels, for comparison). The
    wheels of ``conditions`` act in the world either way. ``on_step(positions, pattern,
    running)`` is called before each step with the teams as they truly are ((E, n, 2) m),
    their patterns ((E, n, 2)) and which episodes still run ((E,)): read-only views, for a
    caller that follows the episodes step by step (``benchmarks/steps_breakdown.py``).
    ``start_pattern``: every episode starts with that pattern just formed (a transition, as
    in ``patternrl launch``'s sequence), not from random starts. ``agree``, a mode of
    :data:`runtime.decision.agreement.AGREE_MODES` (True: ``slots``, False: ``off``): under
    noise every plan goes in the leader's frame, as it tells it (``frame``, the default, as
    for ``patternrl robot``); with ``slots`` the robots also tell each other their slots and
    go by the leader's assignment where two of them hold one slot
    (:mod:`runtime.decision.agreement`)."""
    t0 = time.perf_counter()
    bw = BatchWorld(
        episodes,
        n_robots,
        pattern,
        brain.spec,
        world=world,
        seed=seed,
        compute_bounds=True,
        build_obs=False,
        conditions=conditions,
        hold_steps=hold_steps,
        start_pattern=start_pattern,
    )
    local = None
    if estimator or conditions != PERFECT or brain.spec.memory_dim:  # robot by robot
        local = LocalDecisions(brain, episodes, n_robots, conditions, estimator=estimator,
                               safety=safety, seed=seed, world=world, naive=naive,
                               agree=agree)
    E = episodes
    done = np.zeros(E, bool)
    formed = np.zeros(E, bool)
    steps = np.zeros(E)
    travel = np.zeros(E)
    lb_steps = np.ones(E)
    lb_travel = np.ones(E)
    collisions = np.zeros(E, np.int64)
    error = np.zeros(E)
    min_sep = np.full(E, np.inf)
    held = np.zeros(E)
    dt = world.dt_s
    changed_steps = 0
    robot_steps = 0
    prev_slots = bw.slots.copy()
    bar = _bar(progress, E, label or pattern_label(pattern))
    try:
        while not done.all():
            live = np.flatnonzero(~done)
            if on_step is not None:
                on_step(_read_only(bw.frames[:, 0]), _read_only(bw.pattern), _read_only(~done))
            vel = np.zeros((E, n_robots, 2))
            if local is not None:
                v_all, slots_all, changed_all = local.decide(bw.frames[:, 0], bw.pattern,
                                                             ~done)
                v, slots, changed = v_all[live], slots_all[live], changed_all[live]
            else:
                v, slots, changed = decide_batch(
                    brain, bw.frames[live], bw.pattern[live], prev_slots[live], safety, world
                )
            vel[live] = v
            p0 = bw.frames[live, 0]
            swept = min_swept_separation(p0, p0 + dt * v)  # the moves as commanded
            min_sep[live] = np.minimum(min_sep[live], swept)
            prev_slots[live] = slots
            changed_steps += int(changed.sum())
            robot_steps += changed.size
            res = bw.step(vel)
            ep = res.episode
            if ep is None:
                continue
            prev_slots[ep.env_ids] = bw.slots[ep.env_ids]  # a new episode: no hysteresis
            new = ~done[ep.env_ids]
            ids = ep.env_ids[new]
            formed[ids], steps[ids], travel[ids] = ep.formed[new], ep.steps[new], ep.travel[new]
            collisions[ids], error[ids] = ep.collisions[new], ep.final_error[new]
            assert ep.lower_bound_steps is not None and ep.lower_bound_travel is not None
            lb_steps[ids] = np.maximum(ep.lower_bound_steps[new], 1)
            lb_travel[ids] = np.maximum(ep.lower_bound_travel[new], 1e-9)
            if ep.held is not None:
                held[ids] = ep.held[new]
            done[ids] = True
            if bar is not None:
                bar.update(len(ids))
    finally:
        if bar is not None:
            bar.close()
    holds = held >= HOLD_SHARE if hold_steps else formed
    ok = formed & (collisions == 0) & holds
    manifest = getattr(brain, "manifest", None)
    return EvalResult(
        brain=str(getattr(manifest, "file", "") or brain.brain_id),
        brain_id=brain.brain_id,
        pattern=pattern_label(pattern),
        n_robots=n_robots,
        episodes=E,
        seed=seed,
        safety=safety_mode(safety),
        orca=asdict(safety) if safety is not None else None,
        success_rate=float(ok.mean()),
        formed_rate=float(formed.mean()),
        collisions=int(collisions.sum()),
        collisions_per_episode=float(collisions.mean()),
        steps_ratio=float((steps / lb_steps)[formed].mean()) if formed.any() else math.nan,
        travel_ratio=float((travel / lb_travel)[formed].mean()) if formed.any() else math.nan,
        formation_error=float(error.mean()),
        mean_steps=float(steps[formed].mean()) if formed.any() else math.nan,
        safety_interventions=changed_steps / max(robot_steps, 1),
        wall_s=time.perf_counter() - t0,
        min_separation_m=float(min_sep.min()),
        conditions=conditions.name(),
        estimator=estimator,
        hold_steps=hold_steps,
        held_rate=float(holds[formed].mean()) if hold_steps and formed.any() else math.nan,
        hold_share=float(held[formed].mean()) if hold_steps and formed.any() else math.nan,
        start="random" if start_pattern is None else pattern_label(start_pattern),
        agree=("off" if local is None or local.hearing is None
               else "slots" if local.tells_slots else "frame"),
        episode_stats={
            "formed": formed.astype(float).tolist(),
            "steps": steps.tolist(),
            "travel_m": travel.tolist(),
            "lower_bound_steps": lb_steps.tolist(),
            "lower_bound_travel_m": lb_travel.tolist(),
            "collisions": collisions.astype(float).tolist(),
            "min_separation_m": min_sep.tolist(),
            "held": held.tolist(),
        },
    )


def manifest_evaluation(brain: Brain, pattern: str, n_robots: int, episodes: int,
                        progress: bool | None = None, label: str = "",
                        conditions: Sequence[str] = ()) -> dict[str, Any]:
    """A brain manifest's ``evaluation`` block: ``episodes`` held-out episodes with the
    safety filter at its defaults (as shipped), and under ``raw`` the same episodes with
    the filter off (the brain alone, as the paper runs it). Success at the first passage
    (``hold_steps`` 0), as every shipped manifest measured it; ``held_rate`` says how many of
    the formed held the next ``HOLD_STEPS`` steps. Under ``conditions`` (the specs a run
    trained under, the perfect world apart) the same episodes again, each robot on its own
    view with the tracker and the filter, success asking that it held: one block a spec."""
    block = evaluate_brain(brain, pattern, n_robots, episodes, seed=DEFAULT_EVAL_SEED,
                           progress=progress, label=label, hold_steps=0).manifest_block()
    held = evaluate_brain(brain, pattern, n_robots, episodes, seed=DEFAULT_EVAL_SEED,
                          progress=progress, label=f"{label} hold")
    block["held_rate"] = None if math.isnan(held.held_rate) else held.held_rate
    raw = evaluate_brain(brain, pattern, n_robots, episodes, seed=DEFAULT_EVAL_SEED,
                         safety=None, progress=progress, label=f"{label} raw", hold_steps=0)
    block["raw"] = raw.manifest_block()
    under = {}
    for spec in conditions:
        cond = parse_conditions(spec)
        if cond != PERFECT:
            under[spec] = evaluate_brain(brain, pattern, n_robots, episodes,
                                         seed=DEFAULT_EVAL_SEED, progress=progress,
                                         label=f"{label} {spec}", conditions=cond,
                                         estimator=True).manifest_block() | {"estimator": True}
    if under:
        block["conditions"] = under
    return block


def _bar(enabled: bool | None, total: int, desc: str) -> Any:
    if not (sys.stderr.isatty() if enabled is None else enabled):
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="ep", desc=f"eval {desc}", file=sys.stderr, leave=False)


def format_table(r: EvalResult) -> str:
    def pct(x: float) -> str:
        return "-" if math.isnan(x) else f"{100 * x:.1f} %"

    def ratio(x: float) -> str:
        return "-" if math.isnan(x) else f"{x:.3f}x"

    rows = [
        ("brain", f"{r.brain} ({r.brain_id[:12]})"),
        ("task", f"{r.pattern}, {r.n_robots} robots, {r.episodes} episodes, seed {r.seed}"
                 + ("" if r.start == "random" else f", from {r.start} formed")),
        ("safety filter", r.safety),
        ("success", f"{pct(r.success_rate)}  (formed, no collision, within the step limit)"),
        ("formed", pct(r.formed_rate) + "  (first passage)"),
        ("held", "-" if not r.hold_steps else
         f"{pct(r.held_rate)} of the formed held  (mean {pct(r.hold_share)} of the next "
         f"{r.hold_steps} steps formed)"),
        ("conditions", r.conditions + ("  + estimator" if r.estimator else "")
         + {"off": "", "frame": "  + the leader's frame",
            "slots": "  + slot and frame agreement"}.get(r.agree, "")),
        ("collisions", f"{r.collisions} total, {r.collisions_per_episode:.3f} per episode"),
        ("steps", f"{ratio(r.steps_ratio)} the lower bound (mean {r.mean_steps:.1f})"),
        ("travel", f"{ratio(r.travel_ratio)} the lower bound"),
        ("formation error", f"{r.formation_error:.4f} m (mean final)"),
        ("min separation", f"{r.min_separation_m:.4f} m (closest commanded approach)"),
        ("filter changed", pct(r.safety_interventions) + " of robot-steps"),
        ("wall time", f"{r.wall_s:.1f} s"),
    ]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


# ------------------------------------------------------------------------ CLI


MIN_EVAL_ROBOTS = 2
"""Smallest team evaluated: a pattern needs at least two robots."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--brain", required=True,
                   help="an ONNX brain (.onnx), a rule (rule:assign, rule:frame-balanced, ...) "
                   f"or {ADVERSARY} (every robot at full speed at its nearest peer: a test of "
                   "the safety filter alone)")
    p.add_argument("--pattern", help="built-in name or file (default: the brain's own pattern)")
    p.add_argument("--robots", type=int, help="team size (default: the brain's, else 10)")
    p.add_argument("--episodes", type=int, default=100, help="episodes (default 100)")
    p.add_argument(
        "--seed",
        type=int,
        default=DEFAULT_EVAL_SEED,
        help=f"world seed of the starts (default {DEFAULT_EVAL_SEED}, never used in training)",
    )
    p.add_argument(
        "--safety",
        choices=SAFETY_MODES,
        default="orca",
        help="the robot's ORCA filter (default), the raw brain ('off'), or ORCA without its "
        "last-resort guard ('orca-no-guard': not safe on imperfect views; it measures what "
        "the guard costs)",
    )
    p.add_argument(
        "--orca-time-horizon-s",
        type=float,
        default=OrcaParams().time_horizon_s,
        help=f"ORCA's time horizon (default {OrcaParams().time_horizon_s}, as on a robot)",
    )
    p.add_argument(
        "--orca-no-landing",
        action="store_true",
        help="keep the full horizon at the end of a plan too (default: a team on a "
        "synchronised plan filters with the plan's time left when shorter, as on a robot)",
    )
    p.add_argument(
        "--conditions",
        default="perfect",
        help="sensing and wheels: a preset (perfect, realistic, harsh) with field=value "
        "overrides, e.g. 'realistic,latency_steps=2' (default perfect); each robot then "
        "decides on its own view",
    )
    p.add_argument("--estimator", action="store_true",
                   help="each robot tracks its peers (alpha-beta filter with latency "
                   "compensation) and decides on the estimates")
    p.add_argument("--hold-steps", type=int, default=HOLD_STEPS,
                   help=f"steps watched after the team first forms; a success holds the "
                   f"formation {HOLD_SHARE * 100:.0f}%% of them (default {HOLD_STEPS}; 0: success "
                   f"at the first passage)")
    p.add_argument("--from", dest="start_pattern", metavar="PATTERN",
                   help="start every episode with this pattern just formed (a built-in or a "
                   "file, the same team size): the transition from it, as in a launch's "
                   "sequence (default: random starts)")
    add_agree_argument(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.robots is not None and args.robots < MIN_EVAL_ROBOTS:
        print(f"patternrl eval: --robots must be >= {MIN_EVAL_ROBOTS} (a pattern needs "
              f"{MIN_EVAL_ROBOTS} robots), got {args.robots}", file=sys.stderr)
        return 2
    try:
        brain = ChargeBrain() if args.brain == ADVERSARY else load_brain(args.brain)
    except BrainError as e:
        print(f"patternrl eval: {e}", file=sys.stderr)
        return 2
    manifest = getattr(brain, "manifest", None)
    pattern = args.pattern or (manifest.pattern if manifest is not None else None)
    if not pattern:
        print("patternrl eval: give --pattern (the brain names none)", file=sys.stderr)
        return 2
    if args.robots is not None:
        n = args.robots
    else:
        n = manifest.n_robots if manifest is not None and manifest.n_robots else 10
    if not brain.spec.accepts_team(n):
        print(
            f"patternrl eval: the brain reads the '{brain.spec.name}' observation of "
            f"{brain.spec.n_robots} robots, not {n}",
            file=sys.stderr,
        )
        return 2
    if args.episodes < 1:
        print("patternrl eval: --episodes must be >= 1", file=sys.stderr)
        return 2
    if not (math.isfinite(args.orca_time_horizon_s) and args.orca_time_horizon_s > 0):
        print("patternrl eval: --orca-time-horizon-s must be > 0", file=sys.stderr)
        return 2
    try:
        check_pattern(pattern, n)
        if args.start_pattern is not None:
            check_pattern(args.start_pattern, n)
        conditions = parse_conditions(args.conditions)
    except (PatternError, InputError) as e:
        print(f"patternrl eval: {e}", file=sys.stderr)
        return 2
    if args.hold_steps < 0:
        print("patternrl eval: --hold-steps must be >= 0", file=sys.stderr)
        return 2
    safety = safety_params(args.safety, OrcaParams(time_horizon_s=args.orca_time_horizon_s,
                                                   landing=not args.orca_no_landing))
    note = pattern_guard_note(None if pattern == RANDOM_PATTERN else make_pattern(pattern, n),
                              conditions, safety)
    if note is not None:
        print(f"patternrl eval: note: {note}", file=sys.stderr)
    res = evaluate_brain(
        brain,
        pattern,
        n,
        args.episodes,
        seed=args.seed,
        safety=safety,
        progress=False if args.no_progress else None,
        label=Path(args.brain).stem,
        conditions=conditions,
        estimator=args.estimator,
        hold_steps=args.hold_steps,
        start_pattern=args.start_pattern,
        agree=args.agree,
    )
    if args.json:
        print(json.dumps(res.to_dict(), allow_nan=False))
    else:
        print(format_table(res))
    return 0
