"""``patternrl train --config FILE.toml --set key=value --print-config``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import tomllib
from pathlib import Path

import pytest

from patternrl.cli import main
from trainer.cli import add_arguments, config_from_args
from trainer.config import (
    ConfigError,
    TrainConfig,
    apply_changes,
    config_toml,
    parse_set,
)
from trainer.world.reward import PAPER_REWARD, RewardConfig


def _config(*argv: str) -> TrainConfig:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return config_from_args(p.parse_args(list(argv)))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_precedence_defaults_file_options_set(tmp_path) -> None:
    f = _write(tmp_path / "c.toml", "n_robots = 12\nseed = 5\nn_envs = 3\nlr_policy = 1e-4\n"
               "gamma = 1\ndesync = false\n[reward]\nbeta = 2.0\n")
    d = TrainConfig()
    assert _config() == d
    cfg = _config("--config", str(f))
    assert (cfg.n_robots, cfg.seed, cfg.n_envs, cfg.lr_policy) == (12, 5, 3, 1e-4)
    assert cfg.gamma == 1.0 and isinstance(cfg.gamma, float)  # a TOML int is a float field
    assert cfg.desync is False and cfg.reward == {"beta": 2.0}
    assert cfg.rollout_steps == d.rollout_steps  # untouched fields keep their defaults
    # an option given beats the file, even when it gives the default's value
    cfg = _config("--config", str(f), "--robots", "8", "--envs", str(d.n_envs))
    assert (cfg.n_robots, cfg.n_envs, cfg.seed) == (8, d.n_envs, 5)
    # --set beats both, and a later --set beats an earlier one
    cfg = _config("--config", str(f), "--seed", "9", "--set", "seed=11", "--set", "n_envs=4",
                  "--set", "n_envs=6", "--set", "desync=true", "--set", "reward.beta=3")
    assert (cfg.seed, cfg.n_envs, cfg.desync, cfg.reward) == (11, 6, True, {"beta": 3.0})
    # --reward replaces the whole table; --set then changes one constant of it
    cfg = _config("--config", str(f), "--reward", "paper", "--set", "reward.formed_bonus=0.5")
    assert cfg.reward == {**dataclasses.asdict(PAPER_REWARD), "formed_bonus": 0.5}
    assert _config("--config", str(f), "--reward", "shaped").reward == {}
    cfg = _config("--paper-lrs", "--set", "lr_value=1e-3")
    assert (cfg.lr_policy, cfg.lr_value) == (1e-4, 1e-3)


def test_every_field_can_be_set_both_ways() -> None:
    base = TrainConfig()
    strings = {"algo": "ppo", "obs": "paper", "returns": "mc", "front_end": "none",
               "conditions": "kinematics=diff"}
    for f in dataclasses.fields(TrainConfig):
        if f.name == "reward":
            continue
        v = getattr(base, f.name)
        new: object
        if isinstance(v, bool):
            new, text = not v, str(not v).lower()
        elif isinstance(v, int):
            new, text = v + 1, str(v + 1)
        elif isinstance(v, float):
            new = 0.5 if v == 0 else v * 0.9 if v < 1 else v * 1.1
            text = repr(new)
        else:
            new = text = strings[f.name]
        assert new != v
        via_set = apply_changes(base, parse_set([f"{f.name}={text}"]), "--set")
        via_file = apply_changes(base, tomllib.loads(f"{f.name} = {json.dumps(new)}"), "f")
        assert getattr(via_set, f.name) == new == getattr(via_file, f.name), f.name
    for k in (f.name for f in dataclasses.fields(RewardConfig)):
        assert apply_changes(base, parse_set([f"reward.{k}=0.25"]), "--set").reward == {k: 0.25}


def test_front_end_is_checked_against_the_observation() -> None:
    paper = TrainConfig(obs="paper")
    assert apply_changes(paper, parse_set(["front_end=rank"]), "--set").front == "rank"
    with pytest.raises(ConfigError, match="transport front end reads the paper observation"):
        apply_changes(TrainConfig(), parse_set(["front_end=transport"]), "--set")
    with pytest.raises(ConfigError, match="unknown front end 'ot'"):
        apply_changes(paper, parse_set(["front_end=ot"]), "--set")


@pytest.mark.parametrize(
    ("toml", "sets", "named"),
    [
        ("n_env = 3\n", [], "unknown key 'n_env' (did you mean 'n_envs'?)"),
        ("[reward]\nbta = 1.0\n", [], "unknown key 'reward.bta'"),
        ("[ppo]\nclip = 0.1\n", [], "unknown key 'ppo'"),
        ("n_envs = 'four'\n", [], "n_envs must be an integer"),
        ("n_envs = 2.5\n", [], "n_envs must be an integer"),
        ("lr_policy = true\n", [], "lr_policy must be a number"),
        ("desync = 1\n", [], "desync must be true or false"),
        ("reward = 2\n", [], "reward must be a table"),
        ("n_envs = 0\n", [], "n_envs must be >= 1"),
        ("gamma = 1.5\n", [], "gamma must be in (0, 1]"),
        ("algo = 'sac'\n", [], "algo: unknown algorithm 'sac'"),
        ("obs = 'lidar'\n", [], "obs: unknown observation 'lidar'"),
        ("lr_value = nan\n", [], "lr_value must be finite"),
        ("n_envs = \n", [], "not valid TOML"),
        ("", ["n_envs"], "--set expects KEY=VALUE, got 'n_envs'"),
        ("", ["n_envs=many"], "--set: n_envs must be an integer, got 'many'"),
        ("", ["desync=maybe"], "--set: desync must be true or false"),
        ("", ["lr_ae=fast"], "--set: lr_ae must be a number"),
        ("", ["seed=-1"], "--set: seed must be >= 0"),
        ("", ["reward=1"], "--set: reward is a table"),
        ("", ["reward.speed=1"], "--set: unknown key 'reward.speed'"),
        ("", ["returns=td"], "--set: returns: unknown returns 'td'"),
        ("", ["crowded_share=1.5"], "crowded share must be in [0, 1]"),
        ("", ["crowded_share=0.5", "crowded_arena_m=0.3"], "do not fit apart in a crowded"),
    ],
)
def test_bad_config_is_one_line_exit_2_naming_the_key(tmp_path, capsys, toml, sets, named) -> None:
    f = _write(tmp_path / "bad.toml", toml)
    argv = ["train", "--config", str(f), "--out", str(tmp_path / "b.onnx")]
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("patternrl train: ")
    assert named in err[0]
    if not sets:
        assert str(f) in err[0]
    assert not (tmp_path / "b.onnx").exists()


def test_bad_option_values_and_missing_file(tmp_path, capsys) -> None:
    assert main(["train", "--robots", "0", "--out", str(tmp_path / "b.onnx")]) == 2
    assert capsys.readouterr().err.strip() == "patternrl train: --robots: n_robots must be >= 1"
    assert main(["train", "--config", str(tmp_path / "none.toml"), "--print-config"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot read config" in err[0] and "none.toml" in err[0]
    with pytest.raises(ConfigError, match="unknown key 'x'"):
        apply_changes(TrainConfig(), {"x": 1}, "here")


def test_print_config_round_trips_and_needs_no_out(tmp_path, capsys) -> None:
    assert main(["train", "--print-config", "--robots", "6", "--algo", "ppo",
                 "--set", "reward.beta=2", "--set", "lr_policy=0.0001"]) == 0
    text = capsys.readouterr().out
    expected = TrainConfig(n_robots=6, algo="ppo", lr_policy=1e-4, reward={"beta": 2.0})
    assert tomllib.loads(text) == {**expected.to_dict(), "reward": {"beta": 2.0}}
    # the dump is a file to start from: read back, it gives the same configuration
    f = _write(tmp_path / "start.toml", text)
    assert _config("--config", str(f)) == expected
    assert main(["train", "--dump-config", "--config", str(f)]) == 0
    assert capsys.readouterr().out == text == config_toml(expected)
    # the defaults' dump lists every field and, commented, the reward's constants
    defaults = tomllib.loads(config_toml(TrainConfig()))
    assert set(defaults) == {f.name for f in dataclasses.fields(TrainConfig)}
    assert defaults["reward"] == {}
    assert "# progress_weight = 1.0" in config_toml(TrainConfig())


def test_the_manifest_keeps_the_effective_configuration(tmp_path, capsys) -> None:
    f = _write(tmp_path / "tiny.toml", "n_robots = 4\nn_envs = 2\nrollout_steps = 4\n"
               "minibatch = 16\nae_steps = 1\npolicy_steps = 1\nvalue_steps = 1\n"
               "latent_dim = 4\nae_hidden = 8\neval_episodes = 1\nseed = 3\n"
               "[reward]\nformed_bonus = 2.0\n")
    out = tmp_path / "tiny.onnx"
    code = main(["train", "--pattern", "line", "--config", str(f), "--seed", "4",
                 "--set", "eval_every=1", "--set", "reward.beta=0.5", "--time-budget-s", "0",
                 "--final-eval-episodes", "0", "--no-progress", "--json", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    manifest = json.loads(out.with_suffix(".json").read_text())
    cfg = manifest["training"]["config"]
    assert (cfg["n_robots"], cfg["n_envs"], cfg["seed"], cfg["eval_every"]) == (4, 2, 4, 1)
    assert cfg["reward"] == {"formed_bonus": 2.0, "beta": 0.5}
    assert manifest["training"]["reward"]["formed_bonus"] == 2.0
    assert TrainConfig.from_dict(cfg) == _config("--config", str(f), "--seed", "4", "--set",
                                                 "eval_every=1", "--set", "reward.beta=0.5")
    # a resumed run goes on with its checkpoint's configuration, and says so
    ckpt = tmp_path / "tiny.ckpt.pt"
    capsys.readouterr()
    assert main(["train", "--resume", str(ckpt), "--set", "seed=99", "--print-config"]) == 0
    printed, err = capsys.readouterr()
    assert tomllib.loads(printed)["seed"] == 4
    assert "checkpoint's configuration" in err and len(err.strip().splitlines()) == 1
    # ... and with its checkpoint's patterns when no --pattern is given
    code = main(["train", "--resume", str(ckpt), "--time-budget-s", "0", "--final-eval-episodes",
                 "0", "--no-progress", "--json", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    assert json.loads(out.with_suffix(".json").read_text())["training"]["patterns"] == ["line"]
