"""Hyper-parameters of Pattern-RL training, in one dataclass.

Symbols follow the paper's Algorithm 1 (Table I): ``P``, ``M`` and ``B`` are the
auto-encoder, policy and value gradient steps per iteration; ``lambda`` the KL
penalty coefficient adapted by the factor ``alpha`` against a KL target inside
the range ``[theta_low, theta_high]`` (the paper's vartheta).

Where a default departs from the paper it says so and why. The paper trains on
whole episodes in Webots (about 300 episodes, 30 minutes); here a numpy world
runs 48 episodes side by side, so the defaults are chosen to reach >= 95 %
held-out success on a 10-robot circle with the ``general`` observation in about
two minutes on a 2-core laptop (see ``benchmarks/train_speed.py``).

| field     | default | paper | why                                                     |
|-----------|---------|-------|---------------------------------------------------------|
| lr_policy | 3e-4    | 1e-4  | 1e-4 works but is ~3x slower to 95 % (78-81 s vs 24-27 s)|
| lr_value  | 6e-4    | 2e-4  | keeps the paper's 2:1 ratio; ``--paper-lrs`` restores both|
| kl_alpha  | 0.5     | 0.5   | applied in the direction that bounds the policy change  |
| P, M, B   | 32,16,16| -     | not given in the paper                                  |
| returns   | gae     | mc    | rollouts are cut every T steps and bootstrapped anyway;  |
|           |         |       | GAE(0.95) has lower variance; ``mc`` is the paper's Phi  |

Not in the paper at all: the auto-encoder's size (36 -> 128 -> 32 for the
``general`` observation), the observation normaliser, advantage normalisation,
gradient clipping and the desynchronised first episodes (see the fields).
"""

from __future__ import annotations

import difflib
import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal, get_type_hints

from runtime.conditions import Conditions, parse_conditions
from runtime.decision.observation import MAX_MEMORY_FRAMES, ObservationSpec
from runtime.errors import InputError
from runtime.world_config import DEFAULT_WORLD
from trainer.world.episodes import check_crowd
from trainer.world.reward import RewardConfig

Algo = Literal["pattern-rl", "ppo"]
ALGOS: tuple[str, ...] = ("pattern-rl", "ppo")
FRONT_END_NAMES: tuple[str, ...] = ("auto", "none", "rank", "slots", "transport")
CONDITION_MIX_SEPARATOR = ";"
"""Joins the specs of a run that trains under several conditions at once."""
MAX_CONDITION_MIX = 8
"""The most conditions one run mixes."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything that shapes a training run (not where it writes)."""

    # ---- problem
    algo: str = "pattern-rl"
    """``pattern-rl`` (auto-encoder + adaptive-KL penalty) or ``ppo`` (clipped, no auto-encoder)."""
    obs: str = "general"
    """Observation spec name: ``paper``, ``general`` or ``plan`` (the general layout in the
    synchronised plan's frame, with the plan's step: runtime.decision.observation)."""
    k_neighbours: int = 6
    """``general`` observation: neighbours seen."""
    residual: bool = False
    """``general`` and ``plan``: the action is a rule's velocity plus the policy's
    (:class:`trainer.ppo.networks.Agent`), so a brain starts at the rule: ``rule:assign`` on the
    general observation, the plan's step (``rule:frame`` at ``travel_weight``) on the plan's."""
    travel_weight: float = 0.0
    """``plan`` only: where the plan's frame sits, 0 the frame of fewest steps (``rule:frame``),
    1 the team's centroid (``rule:frame-travel``); written into the brain's observation spec."""
    memory_frames: int = 1
    """``general`` and ``plan``: the rows the brain reads, its own last ``memory_frames``
    newest first (runtime.decision.observation, "Memory"); 1: no memory. The exported brain
    carries the older rows in and out as its ``memory``."""
    train_safety: bool = False
    """Train behind the robots' ORCA safety filter (runtime.decision.safety, its
    defaults): the worlds move each robot by the filtered command, as ``eval``, the world and
    the robots do, so a brain learns what the filter will make of its commands."""
    safety_imitation: float = 0.0
    """Weight of the safety filter's lesson (0: none). The run keeps the brain it starts from
    (``--init``; a resumed run: as it was at the resume) as a frozen teacher; each rollout step
    runs the robots' filter on the teacher's command for every robot's observation, and the
    policy's mean is fitted to it (squared error in units of v_max times this weight, with the
    KL penalty, in the surrogate's place: :func:`trainer.ppo.update.update`). The world moves
    by the policy's own commands (behind the filter with ``train_safety``), so the brain
    learns, on the states it reaches itself, to do what the filter makes of its teacher, and
    the run is judged without the filter."""
    lesson_margin_m: float = 0.06
    """The radius margin (m) of the filter that gives ``safety_imitation``'s lesson: wider than
    the robots' own (0.02 m), so that a brain a few centimetres off its lesson still keeps
    clear of its neighbours."""
    crowded_share: float = 0.0
    """The share of training episodes that start crowded: the team drawn in a square of
    ``crowded_arena_m`` at the arena's centre instead of the whole arena
    (:class:`trainer.world.episodes.EpisodeDraws`, "Crowded starts"), so that robots meet their
    neighbours on the way far more often than from spread starts. The held-out evaluation keeps
    the arena's starts. 0: none."""
    crowded_arena_m: float = 2.5
    """The side (m) of the crowded starts' square."""
    freeze_normaliser: bool = False
    """Keep the observation normaliser's statistics as the run starts with them (a fine-tune
    from ``--init``): otherwise the first rollouts' statistics, folded into the brain's, move
    every input the policy reads before it has taken a step."""
    conditions: str = "perfect"
    """The conditions the training world runs (runtime.conditions: a preset or spec); recorded
    in the brain's manifest. The wheels act in the world; under imperfect sensing each robot
    observes its own view through its peer tracker, with the damped landing
    (:mod:`trainer.world.sensed`; general and plan observations only). Several specs joined
    by ``;`` (``"perfect;realistic;noise_m=0.1"``) train under all of them at once: the envs
    are split among them in order (:func:`trainer.rollout.stage_parts`), every rollout and
    held-out evaluation holds each one's share."""
    hold_steps: int = 0
    """An episode that forms goes on this many steps more (the hold window, ``eval
    --hold-steps``): every step still formed earns the formed bonus again, and held-out success
    asks that it held (>= 90 % of the window). 0: episodes end at the first passage."""
    front_end: str = "auto"
    """The paper brain's fixed front end before the normaliser (trainer.ppo.front_end), read from
    the paper observation alone: ``transport`` (the team matched to its pattern by optimal
    transport, the robot's slot vector in front: the one that learns, see
    docs/paper_observation.md); ``rank`` (the robot's rank along the team axis, one-hot: the
    brain learns the slot table) and ``slots`` (the rank matching's slot vector), both with the
    per-robot progress toward the rank matching's slot (trainer.ppo.rank); ``none``: the
    observation as it is; ``auto``: ``transport`` for the paper observation, else ``none``."""
    n_robots: int = 10
    seed: int = 0

    # ---- rollouts ("Play game and update memory", Algorithm 1 lines 2-4)
    n_envs: int = 48
    """Worlds stepped side by side. Samples per iteration: n_envs * rollout_steps * n_robots."""
    rollout_steps: int = 32
    """T: steps each world runs per iteration before an update."""
    gamma: float = 0.99
    returns: str = "gae"
    """``mc``: the paper's Phi = discounted sum of the rewards from t on, advantage Phi - V.
    ``gae``: generalised advantage estimation with ``gae_lambda`` (lower variance)."""
    gae_lambda: float = 0.95
    desync: bool = True
    """Cut each world's first episode at a random step, so that the worlds, which all start
    together, do not keep resetting in lockstep (every memory would then hold one phase)."""

    # ---- auto-encoder (lines 5-7)
    latent_dim: int = 32
    ae_hidden: int = 128
    ae_steps: int = 32
    """P: auto-encoder gradient steps per iteration. The policy reads the encoder's code, so
    the sooner the code is faithful the sooner the policy can learn: with P = 8 at 3e-4 a
    10-robot circle took 55-140 s (one seed not at all in 150 s), with P = 32 at 1e-3, 25-27 s."""
    lr_ae: float = 1e-3

    # ---- policy (lines 8-13)
    lr_policy: float = 3e-4
    policy_steps: int = 16
    """M: policy gradient steps per iteration (minibatches drawn from memory)."""
    minibatch: int = 3072
    init_std: float = 0.5
    """Initial action standard deviation, as a fraction of v_max."""
    min_std: float = 0.02
    """Floor of the action standard deviation, fraction of v_max (keeps log-probs finite)."""
    norm_adv: bool = True
    """Normalise advantages per minibatch: ``lambda`` and ``kl_target`` then mean the same
    for any reward scale."""
    max_grad_norm: float = 0.5

    # ---- value (lines 14-18)
    lr_value: float = 6e-4
    value_steps: int = 16
    """B: value gradient steps per iteration."""

    # ---- adaptive KL penalty (lines 19-23), Pattern-RL only
    kl_target: float = 0.01
    kl_beta_high: float = 1.5
    kl_beta_low: float = 1.0 / 1.5
    kl_alpha: float = 0.5
    """alpha: lambda <- lambda / alpha when KL is too high, lambda * alpha when too low."""
    kl_coef_init: float = 1.0
    kl_coef_min: float = 1e-3
    kl_coef_max: float = 100.0

    # ---- standard PPO (the ablation)
    clip_coef: float = 0.2

    # ---- schedule and evaluation
    lr_decay: bool = False
    """Linearly decay learning rates over ``--episodes`` (only when an episode budget is set)."""
    eval_every: int = 4
    """Held-out deterministic evaluation every this many iterations."""
    eval_episodes: int = 64
    eval_seed_offset: int = 1_000_003
    """Held-out starts are drawn from seed + this offset: never the training stream."""
    threads: int = 1
    """torch threads. The world steps in the same thread; on a busy 2-core machine a second
    torch thread made the update 7x slower (oversubscription), so 1 is the default."""

    # ---- reward (trainer.world.training_world.RewardConfig fields); None keeps the world's default
    reward: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algorithm '{self.algo}' (known: {', '.join(ALGOS)})")
        if self.returns not in ("mc", "gae"):
            raise ValueError(f"unknown returns '{self.returns}' (known: mc, gae)")
        if self.front_end not in FRONT_END_NAMES:
            raise ValueError(f"unknown front end '{self.front_end}' "
                             f"(known: {', '.join(FRONT_END_NAMES)})")
        if self.front_end not in ("auto", "none") and self.obs != "paper":
            raise ValueError(f"the {self.front_end} front end reads the paper observation "
                             "(--obs paper)")
        if not 1 <= self.memory_frames <= MAX_MEMORY_FRAMES:
            raise ValueError(f"memory_frames must be in 1..{MAX_MEMORY_FRAMES}, "
                             f"got {self.memory_frames}")
        if self.memory_frames > 1 and self.obs == "paper":
            raise ValueError("the paper observation has its own three frames and no memory "
                             "(--obs general or plan)")
        if not (math.isfinite(self.safety_imitation) and self.safety_imitation >= 0):
            raise ValueError(f"safety_imitation must be >= 0, got {self.safety_imitation}")
        if not (math.isfinite(self.lesson_margin_m) and 0 <= self.lesson_margin_m <= 1):
            raise ValueError(f"lesson_margin_m must be in [0, 1] m, got {self.lesson_margin_m}")
        check_crowd((self.crowded_share, self.crowded_arena_m), self.n_robots, DEFAULT_WORLD)
        if not 0 <= self.hold_steps <= 1000:
            raise ValueError(f"hold_steps must be in 0..1000, got {self.hold_steps}")
        for name in ("n_envs", "rollout_steps", "minibatch", "n_robots"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1")
        mix = self.condition_mix  # raises ValueError, one line
        if len(mix) > min(self.n_envs, self.eval_episodes):
            raise ValueError(f"{len(mix)} conditions need at least as many envs and held-out "
                             f"episodes, got n_envs {self.n_envs}, eval_episodes "
                             f"{self.eval_episodes}")
        if not all(c.sensing_perfect for c in mix) and self.obs == "paper":
            raise ValueError("training under imperfect sensing builds each robot's general or "
                             "plan observation from its own view (--obs general or plan), not "
                             "the paper's")

    @property
    def condition_specs(self) -> tuple[str, ...]:
        """The specs of :attr:`conditions`: one, or the mixture's in order."""
        specs = tuple(p.strip() for p in self.conditions.split(CONDITION_MIX_SEPARATOR))
        if len(specs) > MAX_CONDITION_MIX or (not all(specs) and len(specs) > 1):
            raise ValueError(f"at most {MAX_CONDITION_MIX} non-empty specs joined "
                             f"by '{CONDITION_MIX_SEPARATOR}', got '{self.conditions}'")
        return specs

    @property
    def condition_mix(self) -> tuple[Conditions, ...]:
        """The parsed :attr:`conditions`: one, or the mixture's in order."""
        try:
            return tuple(parse_conditions(p) for p in self.condition_specs)
        except InputError as e:
            raise ValueError(str(e).removeprefix("conditions: ")) from None

    @property
    def world_conditions(self) -> Conditions:
        """The parsed :attr:`conditions` of a run under one; a mixture raises ValueError."""
        mix = self.condition_mix
        if len(mix) > 1:
            raise ValueError(f"'{self.conditions}' is a mixture of {len(mix)} conditions")
        return mix[0]

    @property
    def front(self) -> str:
        """The front end in effect: ``rank`` or ``none`` (``auto`` resolved)."""
        if self.front_end == "auto":
            return "transport" if self.obs == "paper" else "none"
        return self.front_end

    @property
    def uses_autoencoder(self) -> bool:
        return self.algo == "pattern-rl"

    @property
    def batch_size(self) -> int:
        """Samples gathered per iteration (every robot of every world, every step)."""
        return self.n_envs * self.rollout_steps * self.n_robots

    def with_(self, **changes: Any) -> TrainConfig:
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in fields(TrainConfig)}
        return TrainConfig(**{k: v for k, v in d.items() if k in known})


PAPER_LRS = {"lr_policy": 1e-4, "lr_value": 2e-4}
"""The paper's learning rates (Table I)."""


def obs_spec_for(cfg: TrainConfig) -> ObservationSpec:
    """The observation a run builds: ``paper`` for its team size, else ``general``."""
    if cfg.obs == "paper":
        return ObservationSpec("paper", n_robots=cfg.n_robots)
    if cfg.obs == "plan":
        return ObservationSpec("plan", k_neighbours=cfg.k_neighbours,
                               travel_weight=cfg.travel_weight, frames=cfg.memory_frames)
    return ObservationSpec("general", k_neighbours=cfg.k_neighbours, frames=cfg.memory_frames)


def reward_for(cfg: TrainConfig) -> RewardConfig:
    """The world's reward constants with the run's overrides."""
    return RewardConfig(**cfg.reward)


# ------------------------------------------------- the configuration as a file and --set
#
# ``patternrl train --config FILE.toml --set key=value``: every field above, by name,
# in a TOML file (``patternrl train --print-config`` writes one to start from). The
# reward's constants are a ``[reward]`` table (``--set reward.beta=2``).


class ConfigError(InputError):
    """A bad training configuration: unknown key, wrong type or bad value; names the key."""


_POSITIVE_INTS = ("n_robots", "n_envs", "rollout_steps", "minibatch", "latent_dim", "ae_hidden",
                  "eval_every", "eval_episodes", "threads", "k_neighbours")
_NON_NEGATIVE_INTS = ("seed", "ae_steps", "policy_steps", "value_steps", "eval_seed_offset")
_POSITIVE_FLOATS = ("lr_ae", "lr_policy", "lr_value", "init_std", "min_std", "max_grad_norm",
                    "kl_target", "kl_coef_init", "kl_coef_min", "kl_coef_max", "clip_coef")
_UNIT_RANGES = {"gamma": "(0, 1]", "gae_lambda": "[0, 1]", "kl_alpha": "(0, 1)",
                "kl_beta_low": "(0, 1]", "travel_weight": "[0, 1]"}
"""Fields within 0..1; a bracket closes the end, a parenthesis opens it."""
OBS_NAMES: tuple[str, ...] = ("paper", "general", "plan")


def _field_types() -> dict[str, Any]:
    """Field name -> its type (``str``, ``int``, ``float``, ``bool``, ``dict``)."""
    hints = get_type_hints(TrainConfig)
    return {f.name: getattr(hints[f.name], "__origin__", hints[f.name])
            for f in fields(TrainConfig)}


_TYPE_NAMES = {str: "a string", int: "an integer", float: "a number", bool: "true or false",
               dict: "a table"}


def _unknown(key: str, known: Sequence[str], source: str) -> ConfigError:
    near = difflib.get_close_matches(key, known, n=1)
    hint = f" (did you mean '{near[0]}'?)" if near else ""
    return ConfigError(f"{source}: unknown key '{key}'{hint}")


def _typed(key: str, value: Any, kind: Any, source: str) -> Any:
    """``value`` as a ``kind`` (an int is a float too); a ConfigError when it is not one."""
    ok = isinstance(value, kind) and not (kind is int and isinstance(value, bool))
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value, ok = float(value), True
    if not ok:
        raise ConfigError(f"{source}: {key} must be {_TYPE_NAMES[kind]}, got {value!r}")
    if kind is float and not math.isfinite(value):
        raise ConfigError(f"{source}: {key} must be finite, got {value!r}")
    return value


def _check_range(key: str, value: Any, source: str) -> None:
    problem = None
    if key in _POSITIVE_INTS and value < 1:
        problem = "must be >= 1"
    elif key in _NON_NEGATIVE_INTS and value < 0:
        problem = "must be >= 0"
    elif key in _POSITIVE_FLOATS and value <= 0:
        problem = "must be > 0"
    elif key in _UNIT_RANGES:
        text = _UNIT_RANGES[key]
        above = value >= 0 if text[0] == "[" else value > 0
        below = value <= 1 if text[-1] == "]" else value < 1
        problem = None if above and below else f"must be in {text}"
    elif key == "kl_beta_high" and value < 1:
        problem = "must be >= 1"
    elif key == "obs" and value not in OBS_NAMES:
        problem = f"unknown observation '{value}' (known: {', '.join(OBS_NAMES)})"
    elif key == "front_end" and value not in FRONT_END_NAMES:
        problem = f"unknown front end '{value}' (known: {', '.join(FRONT_END_NAMES)})"
    if problem is None and key != "front_end":  # front_end's fit to obs: checked as a whole
        try:  # the dataclass's own checks, one key at a time so the error names it
            TrainConfig().with_(**{key: value})
        except ValueError as e:
            problem = str(e)
    if problem is not None:
        sep = " " if problem.startswith("must") else ": "
        raise ConfigError(f"{source}: {key}{sep}{problem}")


def _reward_table(value: Any, source: str) -> dict[str, float]:
    if not isinstance(value, dict):
        raise ConfigError(f"{source}: reward must be a table of reward constants, got {value!r}")
    known = [f.name for f in fields(RewardConfig)]
    out = {}
    for k, v in value.items():
        if k not in known:
            raise _unknown(f"reward.{k}", [f"reward.{n}" for n in known], source)
        out[k] = _typed(f"reward.{k}", v, float, source)
    return out


def check_changes(changes: Mapping[str, Any], source: str) -> dict[str, Any]:
    """Validate ``changes`` (field -> value) from ``source`` (a file name, ``--set``).

    Returns them with ints widened to floats where a field is a float. Raises
    :class:`ConfigError` naming the first unknown key, wrong type or bad value.
    """
    types = _field_types()
    out: dict[str, Any] = {}
    for key, value in changes.items():
        if key not in types:
            raise _unknown(key, list(types), source)
        if key == "reward":
            out[key] = _reward_table(value, source)
            continue
        out[key] = _typed(key, value, types[key], source)
        _check_range(key, out[key], source)
    return out


def apply_changes(cfg: TrainConfig, changes: Mapping[str, Any], source: str) -> TrainConfig:
    """``cfg`` with validated ``changes``; a ``reward`` table merges key by key."""
    checked = check_changes(changes, source)
    if "reward" in checked:
        checked["reward"] = {**cfg.reward, **checked["reward"]}
    try:
        return cfg.with_(**checked)
    except ValueError as e:
        raise ConfigError(f"{source}: {e}") from None


def load_config_file(path: str | Path) -> dict[str, Any]:
    """The fields a TOML file sets (not yet validated: see :func:`check_changes`)."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as e:
        raise ConfigError(f"cannot read config {path}: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None


_TRUE, _FALSE = ("true", "yes", "on", "1"), ("false", "no", "off", "0")


def parse_set(items: Sequence[str]) -> dict[str, Any]:
    """``["key=value", "reward.beta=2", ...]`` -> typed changes (a later key wins)."""
    types = _field_types()
    reward_keys = [f.name for f in fields(RewardConfig)]
    out: dict[str, Any] = {}
    for item in items:
        key, eq, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not eq or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got '{item}'")
        if key.startswith("reward."):
            name = key.removeprefix("reward.")
            if name not in reward_keys:
                raise _unknown(key, [f"reward.{n}" for n in reward_keys], "--set")
            out.setdefault("reward", {})[name] = _parse_text(key, text, float)
            continue
        if key not in types:
            raise _unknown(key, list(types), "--set")
        if types[key] is dict:
            raise ConfigError(f"--set: {key} is a table: set its keys as {key}.NAME=VALUE")
        out[key] = _parse_text(key, text, types[key])
    return out


def _parse_text(key: str, text: str, kind: Any) -> Any:
    try:
        if kind is bool:
            if text.lower() not in _TRUE + _FALSE:
                raise ValueError(text)
            return text.lower() in _TRUE
        return kind(text)
    except ValueError:
        raise ConfigError(f"--set: {key} must be {_TYPE_NAMES[kind]}, got '{text}'") from None


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a TOML basic string
    return repr(v)


def config_toml(cfg: TrainConfig) -> str:
    """``cfg`` as a TOML file that ``--config`` reads back to the same configuration."""
    lines = ["# patternrl train --config FILE.toml (every key optional; see trainer/config.py)"]
    d = cfg.to_dict()
    lines += [f"{k} = {_toml_value(v)}" for k, v in d.items() if k != "reward"]
    lines += [
        "",
        "# the world's reward constants (trainer/world/reward.py); '#' lines are the defaults",
        "[reward]",
    ]
    for k, default in asdict(RewardConfig()).items():
        if k in cfg.reward:
            lines.append(f"{k} = {_toml_value(float(cfg.reward[k]))}")
        else:
            lines.append(f"# {k} = {_toml_value(default)}")
    return "\n".join(lines) + "\n"
