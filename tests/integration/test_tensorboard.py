"""``patternrl train --tensorboard DIR``: the learning curve as TensorBoard events."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
import tomllib

import pytest
from support import ROOT
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from patternrl.cli import main
from trainer.config import TrainConfig
from trainer.curve import CURVE_FIELDS, SCALAR_TAGS

# rollout_steps = the step limit: every world's first (desynchronised) episode ends in the
# first iteration, so the rows have training rewards
TINY = ["--robots", "4", "--envs", "2", "--eval-episodes", "1", "--set", "rollout_steps=400",
        "--set", "minibatch=16", "--set", "ae_steps=1", "--set", "policy_steps=1",
        "--set", "value_steps=1", "--set", "latent_dim=4", "--set", "ae_hidden=8",
        "--set", "eval_every=1", "--seed", "2"]


def _events(logdir) -> EventAccumulator:
    acc = EventAccumulator(str(logdir), size_guidance={"scalars": 0, "tensors": 0})
    acc.Reload()
    return acc


def _text(acc: EventAccumulator, tag: str) -> list[tuple[int, str]]:
    events = acc.Tensors(f"{tag}/text_summary")
    return [(e.step, e.tensor_proto.string_val[0].decode()) for e in events]


def test_train_writes_every_curve_column_each_iteration(tmp_path, capsys) -> None:
    out, logdir = tmp_path / "b.onnx", tmp_path / "tb"
    # two pattern stages, each stopped after its first iteration: two rows
    code = main(["train", "--patterns", "circle,line", *TINY, "--time-budget-s", "0",
                 "--final-eval-episodes", "0", "--no-progress", "--json", "--out", str(out),
                 "--tensorboard", str(logdir)])
    assert code == 0, capsys.readouterr().err
    assert len(list(logdir.glob("events.out.tfevents.*"))) == 1
    with (tmp_path / "b.curve.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["iteration"] for r in rows] == ["1", "2"]
    acc = _events(logdir)
    # every column: the numbers as scalars, the iteration as their step, the pattern as text
    assert set(SCALAR_TAGS) | {"iteration", "pattern"} == set(CURVE_FIELDS)
    # a blank cell of the CSV (nan: e.g. no formed episode for eval_steps) has no scalar
    written = {col for col in SCALAR_TAGS if any(r[col] for r in rows)}
    assert written >= set(SCALAR_TAGS) - {"eval_steps"}
    assert set(acc.Tags()["scalars"]) == {SCALAR_TAGS[c] for c in written}
    for col in written:
        got = {e.step: e.value for e in acc.Scalars(SCALAR_TAGS[col])}
        want = {int(r["iteration"]): float(r[col]) for r in rows if r[col]}
        assert got == pytest.approx(want, rel=1e-5), col
    assert _text(acc, "pattern") == [(1, "circle"), (2, "line")]
    config = _text(acc, "config")
    assert len(config) == 1
    toml = "\n".join(line.removeprefix("    ") for line in config[0][1].splitlines())
    cfg = TrainConfig.from_dict(tomllib.loads(toml))
    assert (cfg.n_robots, cfg.n_envs, cfg.seed, cfg.latent_dim) == (4, 2, 2, 4)
    assert "circle > line" in _text(acc, "run")[0][1]


def test_ctrl_c_leaves_a_readable_event_file(tmp_path) -> None:
    logdir = tmp_path / "tb"
    # the train process takes Ctrl-C even where this one was started with SIGINT ignored
    # (a background job of a non-interactive shell): Python would then ignore it too
    cmd = [sys.executable, "-c", "import runpy, signal, sys; signal.signal(signal.SIGINT, "
           "signal.default_int_handler); sys.argv[0] = 'patternrl'; "
           "runpy.run_module('patternrl.cli', run_name='__main__')",
           "train", "--pattern", "circle", *TINY,
           "--set", "rollout_steps=8", "--time-budget-s", "600", "--no-progress",
           "--until-success", "1.01",  # never met: a tiny circle may pass its first eval
           "--out", str(tmp_path / "b.onnx"), "--tensorboard", str(logdir)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        deadline = time.monotonic() + 120
        steps: list[int] = []
        while len(steps) < 2 and proc.poll() is None and time.monotonic() < deadline:
            if logdir.is_dir():  # the rows are flushed as they come: seen while it trains
                acc = _events(logdir)
                if "update/kl" in acc.Tags()["scalars"]:
                    steps = [e.step for e in acc.Scalars("update/kl")]
            time.sleep(0.2)  # polling interval, not a wait for a result
        assert len(steps) >= 2, "no rows appeared while training"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=150)  # a hang guard: a loaded machine is slow
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    # 130, or killed by the SIGINT itself after saying so (the shell shows 130 for both)
    assert proc.returncode in (130, -signal.SIGINT)
    assert err.strip().splitlines()[-1] == "patternrl train: interrupted"
    final = [e.step for e in _events(logdir).Scalars("update/kl")]
    assert final[: len(steps)] == steps and final == list(range(1, len(final) + 1))
