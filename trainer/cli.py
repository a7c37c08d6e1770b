"""``patternrl train``: train a brain with Pattern-RL (or standard PPO) and export it.

Example::

    patternrl train --pattern heart --robots 10 --out exports/heart-10-general.onnx

trains until the deterministic policy forms the heart in >= 95 % of held-out
episodes (or the time budget runs out), exports the best policy by held-out
evaluation as ``heart-10-general.onnx`` with its manifest ``heart-10-general.json``,
evaluates it as a robot runs it (ORCA on, 100 fresh episodes; the numbers go
into the manifest) and leaves the learning curve (``.curve.csv``, ``.curve.png``)
and checkpoints (``.ckpt.pt``, ``.best.pt``) beside it.

Bad input (unknown pattern, unreadable ``--init``/``--resume`` file, a brain of
the wrong observation) gives a one-line error and exit code 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from runtime.brain.brain import BrainError, BrainManifest, load_brain
from runtime.brain.signing import load_private_key, user_key
from runtime.decision.patterns import PatternError
from runtime.errors import InputError
from runtime.world_config import DEFAULT_WORLD
from trainer.checkpoints import InitError, load_checkpoint
from trainer.config import (
    ALGOS,
    PAPER_LRS,
    TrainConfig,
    apply_changes,
    config_toml,
    load_config_file,
    obs_spec_for,
    parse_set,
    reward_for,
)
from trainer.curve import TensorBoardCurve
from trainer.evaluate import manifest_evaluation
from trainer.ppo.export import write_brain
from trainer.rollout import RolloutMode, env_shares
from trainer.train import RunPlan, TrainResult, artefact_paths, train
from trainer.world.episodes import check_pattern
from trainer.world.reward import PAPER_REWARD

DEFAULT_TIME_BUDGET_S = 1800.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    d = TrainConfig()
    p.add_argument("--pattern", help="built-in name or points file (default circle; a resumed "
                                     "run: its checkpoint's patterns)")
    p.add_argument(
        "--patterns",
        help="comma-separated sequence (e.g. circle,cross,line,heart), each continuing the last",
    )
    # Options that set a TrainConfig field default to None: only one given on the command
    # line overrides --config (precedence: defaults < --config < options < --set).
    p.add_argument("--robots", type=int, help=f"team size (default {d.n_robots})")
    p.add_argument("--algo", choices=ALGOS, help=f"default {d.algo}")
    p.add_argument("--obs", choices=("paper", "general", "plan"),
                   help=f"the brain's observation: paper (the paper's, fixed n), general (slot "
                        f"vector and neighbours, any n) or plan (the general layout in the "
                        f"synchronised plan's frame); default {d.obs}")
    p.add_argument("--seed", type=int, help=f"default {d.seed}")
    p.add_argument("--out", type=Path, help="the brain to write (.onnx); required to train")
    stop = p.add_argument_group("stopping (per pattern; the first reached wins)")
    stop.add_argument("--episodes", type=int, help="training episodes")
    stop.add_argument(
        "--until-success",
        type=float,
        help="held-out deterministic success rate (default 0.95 when --episodes is not given)",
    )
    stop.add_argument(
        "--time-budget-s",
        type=float,
        help=f"seconds (default {DEFAULT_TIME_BUDGET_S:.0f} without --episodes)",
    )
    p.add_argument("--init", help="fine-tune from a brain (.onnx) or a checkpoint (.pt)")
    p.add_argument("--resume", help="continue an interrupted run from its .ckpt.pt")
    p.add_argument("--envs", type=int, help=f"worlds side by side (default {d.n_envs})")
    p.add_argument("--conditions",
                   help="the conditions to train under: a preset or spec of "
                   "runtime.conditions, e.g. 'realistic' or 'gain_noise=0.1,kinematics=diff' "
                   "(default perfect; recorded in the manifest). Under imperfect sensing each "
                   "robot observes its own view through its peer tracker (general and plan "
                   "observations only). Several joined by ';' ('perfect;realistic;noise_m=0.1') "
                   "train under all at once: the envs and held-out episodes are split among "
                   "them")
    p.add_argument("--hold-steps", type=int,
                   help="an episode that forms goes on this many steps more, each step still "
                   "formed rewarded, and held-out success asks that it held (>= 90%% of them); "
                   "default 0: episodes end at the first passage")
    p.add_argument("--memory-frames", type=int,
                   help="a brain with memory: it reads its own last K rows, newest first, "
                   "carried in and out of its ONNX graph (general and plan observations; "
                   "default 1: no memory). With --init of a brain without memory, the brain "
                   "starts as it was, the weights on its older rows at zero", metavar="K")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument(
        "--sign-key",
        type=Path,
        default=None,
        help="sign the brain with this private key (default: your own, "
        "$PATTERNRL_HOME/brain-key or ~/.config/patternrl/brain-key, made on first use)",
    )
    tune = p.add_argument_group("tuning")
    tune.add_argument(
        "--paper-lrs", action="store_true", help="the paper's learning rates (1e-4, 2e-4)"
    )
    tune.add_argument("--lr-decay", action="store_true", help="linear decay over the budget")
    tune.add_argument(
        "--reward",
        choices=("shaped", "paper"),
        help="shaped (default): the world's default with the per-robot progress term "
        "(training-only credit signal); paper: eq. 6 alone",
    )
    tune.add_argument("--k-neighbours", type=int, help=f"default {d.k_neighbours}")
    tune.add_argument(
        "--eval-episodes", type=int, help=f"held-out episodes per evaluation ({d.eval_episodes})"
    )
    tune.add_argument(
        "--final-eval-episodes",
        type=int,
        default=100,
        help="episodes of the exported brain's evaluation for its manifest, with the safety "
        "filter (ORCA) and raw (filter off); 0 skips",
    )
    tune.add_argument("--threads", type=int, help=f"torch threads (default {d.threads})")
    tune.add_argument("--no-progress", action="store_true", help="no bar, no log lines")
    dist = p.add_argument_group("rollouts on Ray (the 'distributed' extra)")
    dist.add_argument(
        "--ray",
        nargs="?",
        const="",
        default=None,
        metavar="ADDRESS",
        help="play the rollouts on Ray actors, the update here; with ADDRESS (e.g. "
        "10.0.0.5:6379, from 'ray start --head') join that cluster, else start a local one",
    )
    dist.add_argument(
        "--ray-workers", type=int, default=1, help="Ray rollout actors, each a share of --envs (1)"
    )
    add_config_arguments(p)


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    """--config, --set, --print-config and --tensorboard."""
    g = p.add_argument_group("configuration file and live curves")
    g.add_argument(
        "--config",
        type=Path,
        metavar="FILE.toml",
        help="training configuration (every field of trainer/config.py TrainConfig, and a "
        "[reward] table); options given on the command line override it",
    )
    g.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set one field, over --config and the options (repeatable; e.g. --set "
        "lr_policy=1e-4 --set reward.beta=2)",
    )
    g.add_argument(
        "--print-config",
        "--dump-config",
        action="store_true",
        help="print the effective configuration as TOML (a file to start from) and exit",
    )
    g.add_argument(
        "--tensorboard",
        type=Path,
        metavar="DIR",
        help="write every column of the learning curve each iteration, and the "
        "configuration, as TensorBoard events under DIR (tensorboard --logdir DIR)",
    )


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """The effective configuration: defaults < ``--config`` < options given < ``--set``.

    Raises :class:`trainer.config.ConfigError` (one line naming the key) on bad input.
    """
    cfg = TrainConfig()
    if getattr(args, "config", None) is not None:
        cfg = apply_changes(cfg, load_config_file(args.config), str(args.config))
    options = {  # flag -> (field, value given or None)
        "--algo": ("algo", args.algo),
        "--obs": ("obs", args.obs),
        "--robots": ("n_robots", args.robots),
        "--seed": ("seed", args.seed),
        "--envs": ("n_envs", args.envs),
        "--k-neighbours": ("k_neighbours", args.k_neighbours),
        "--eval-episodes": ("eval_episodes", args.eval_episodes),
        "--threads": ("threads", args.threads),
        "--lr-decay": ("lr_decay", True if args.lr_decay else None),
        "--conditions": ("conditions", args.conditions),
        "--hold-steps": ("hold_steps", args.hold_steps),
        "--memory-frames": ("memory_frames", args.memory_frames),
    }
    for flag, (name, value) in options.items():
        if value is not None:
            cfg = apply_changes(cfg, {name: value}, flag)
    if args.paper_lrs:
        cfg = apply_changes(cfg, PAPER_LRS, "--paper-lrs")
    if args.reward is not None:  # the whole table; shaped is the world's default
        cfg = cfg.with_(reward=dataclasses.asdict(PAPER_REWARD) if args.reward == "paper" else {})
    return apply_changes(cfg, parse_set(getattr(args, "set", None) or []), "--set")


def _train(args: argparse.Namespace, cfg: TrainConfig, plan: RunPlan) -> TrainResult:
    """``train``, with the curve written to TensorBoard as it grows when asked."""
    if args.tensorboard is None:
        return train(cfg, plan)
    if plan.resume:  # the run goes on with its checkpoint's configuration
        cfg = TrainConfig.from_dict(load_checkpoint(Path(plan.resume))["config"])
    run_text = (
        f"patterns: {' > '.join(plan.patterns)}\nout: {plan.out}\n"
        f"episodes: {plan.episodes}\nuntil_success: {plan.until_success}\n"
        f"time_budget_s: {plan.time_budget_s}\ninit: {plan.init}\nresume: {plan.resume}"
    )
    texts = {"config": config_toml(cfg), "run": run_text}
    with TensorBoardCurve(args.tensorboard, texts) as board:
        return train(cfg, plan, on_iteration=board)


def _fail(msg: str) -> int:
    print(f"patternrl train: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    given = args.patterns or args.pattern
    if given is None and args.resume:  # the interrupted run's own patterns
        try:
            given = ",".join(load_checkpoint(Path(args.resume)).get("patterns") or []) or None
        except InitError as e:
            return _fail(str(e))
    patterns = [s.strip() for s in (given or "circle").split(",") if s.strip()]
    if not patterns:
        return _fail("no pattern given")
    try:
        cfg = config_from_args(args)
    except ValueError as e:
        return _fail(str(e))
    if args.resume and (args.config or args.set):
        print("patternrl train: note: a resumed run goes on with its checkpoint's "
              "configuration; --config and --set do not change it", file=sys.stderr)
    if args.print_config:
        if args.resume:
            try:
                cfg = TrainConfig.from_dict(load_checkpoint(Path(args.resume))["config"])
            except InitError as e:
                return _fail(str(e))
        print(config_toml(cfg), end="")
        return 0
    try:
        for p in patterns:
            check_pattern(p, cfg.n_robots, DEFAULT_WORLD)
    except PatternError as e:
        return _fail(str(e))
    if args.out is None:
        return _fail("--out is required: the brain to write (.onnx)")
    if args.out.suffix != ".onnx":
        return _fail(f"--out must name an .onnx file, got {args.out}")
    try:  # a key that cannot sign fails now, not after the training
        load_private_key(args.sign_key if args.sign_key is not None else user_key() or "")
    except InputError as e:
        return _fail(str(e))
    for flag, path in (("--init", args.init), ("--resume", args.resume)):
        if path and not Path(path).is_file():
            return _fail(f"cannot read {flag} {path}: no such file")
    until = args.until_success
    if until is None and args.episodes is None:
        until = 0.95
    budget = args.time_budget_s
    if budget is None and args.episodes is None:
        budget = DEFAULT_TIME_BUDGET_S
    try:
        rollouts = RolloutMode(ray=args.ray is not None, address=args.ray or None,
                               workers=args.ray_workers)
        if rollouts.ray:
            env_shares(cfg.n_envs, rollouts.workers)
    except ValueError as e:
        return _fail(str(e))
    plan = RunPlan(
        patterns=patterns,
        out=args.out,
        episodes=args.episodes,
        until_success=until,
        time_budget_s=budget,
        init=args.init,
        resume=args.resume,
        progress=False if args.no_progress else None,
        rollouts=rollouts,
    )
    try:
        result = _train(args, cfg, plan)
    except InputError as e:  # a bad --init/--resume file, Ray missing or unreachable
        return _fail(str(e))
    cfg = result.config  # a resumed run keeps its checkpoint's configuration

    spec = obs_spec_for(cfg)
    world = plan.world
    init_id = None
    if args.init and args.init.endswith(".onnx"):
        try:
            init_id = load_brain(args.init).brain_id
        except BrainError:
            init_id = None
    manifest = BrainManifest(
        observation=spec,
        action={"kind": "cartesian", "v_max_mps": world.v_max_mps, "dt_s": world.dt_s},
        # a brain trained on random shapes is meant for any pattern
        pattern=None if patterns[-1] == "random" else patterns[-1],
        n_robots=cfg.n_robots,
        world=dataclasses.asdict(world),
        training={
            "algorithm": cfg.algo,
            "episodes": result.episodes,
            "agent_steps": result.curve[-1]["agent_steps"] if result.curve else 0,
            "iterations": len(result.curve),
            "seed": cfg.seed,
            "wall_time_s": round(result.wall_s, 1),
            "patterns": patterns,
            "stopped": result.stopped,
            "best_iteration": result.best_iteration,
            "held_out_success": result.best_eval_success,
            "held_out_episodes": cfg.eval_episodes,
            "init": args.init,
            "init_brain_id": init_id,
            "reward": dataclasses.asdict(reward_for(cfg)),
            "config": cfg.to_dict(),
            "rollouts": result.rollouts,
        },
    )
    write_brain(result.agent, args.out, manifest, args.sign_key)
    if args.final_eval_episodes > 0:
        brain = load_brain(str(args.out))
        manifest.evaluation = manifest_evaluation(
            brain,
            patterns[-1],
            cfg.n_robots,
            args.final_eval_episodes,
            progress=False if args.no_progress else None,
            label=args.out.stem,
            conditions=cfg.condition_specs,
        )
        write_brain(result.agent, args.out, manifest, args.sign_key)

    files = {k: str(v) for k, v in artefact_paths(args.out).items()}
    summary = {
        "brain": str(args.out),
        "brain_id": manifest.brain_id,
        "size_bytes": args.out.stat().st_size,
        "algorithm": cfg.algo,
        "observation": spec.to_dict(),
        "patterns": patterns,
        "n_robots": cfg.n_robots,
        "episodes": result.episodes,
        "wall_time_s": round(result.wall_s, 1),
        "stopped": result.stopped,
        "held_out_success": result.best_eval_success,
        "evaluation": manifest.evaluation,
        "files": files,
    }
    if args.json:
        print(json.dumps(summary, allow_nan=False))
    else:
        ev_text = ""
        if manifest.evaluation:
            m = manifest.evaluation
            ev_text = (
                f"; evaluation ({m['episodes']} episodes, ORCA): success "
                f"{100 * m['success_rate']:.1f} %, {m['collisions']} collisions"
                + (f", steps {m['steps_ratio']:.3f}x the lower bound" if m["steps_ratio"] else "")
                + f"; raw (filter off): success {100 * m['raw']['success_rate']:.1f} %, "
                f"{m['raw']['collisions']} collisions"
                + "".join(f"; {spec} (tracker, held): success {100 * c['success_rate']:.1f} %, "
                          f"{c['collisions']} collisions"
                          + (f", steps {c['steps_ratio']:.3f}x" if c["steps_ratio"] else "")
                          for spec, c in m.get("conditions", {}).items())
            )
        print(
            f"{args.out} ({summary['size_bytes'] // 1024} KB): {cfg.algo}, {spec.name} "
            f"observation, {result.episodes} episodes in {result.wall_s:.0f} s "
            f"(stopped: {result.stopped}); held-out success "
            f"{100 * result.best_eval_success:.1f} %{ev_text}\n"
            f"curve: {files['curve_png']}"
        )
    return 0
