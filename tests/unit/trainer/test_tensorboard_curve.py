"""The learning curve as TensorBoard events: the writer, and a ``--tensorboard`` path refused.

Training runs that write them are in tests/integration/test_tensorboard.py."""

from __future__ import annotations

import math

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from patternrl.cli import main
from trainer.curve import CURVE_FIELDS, TensorBoardCurve

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


def test_rows_are_on_disk_before_close_and_nan_is_left_out(tmp_path) -> None:
    row = dict.fromkeys(CURVE_FIELDS, 0.5) | {"iteration": 3, "pattern": "heart",
                                              "eval_success": math.nan}
    with TensorBoardCurve(tmp_path, {"config": "seed = 1"}) as board:
        board(row)
        acc = _events(tmp_path)  # flushed at once: what tensorboard --logdir shows live
        assert [e.step for e in acc.Scalars("update/kl")] == [3]
        assert "eval/eval_success" not in acc.Tags()["scalars"]
        board(row | {"iteration": 4, "eval_success": 1.0})
    acc = _events(tmp_path)
    assert [(e.step, e.value) for e in acc.Scalars("eval/eval_success")] == [(4, 1.0)]
    assert [e.step for e in acc.Scalars("rollout/mean_reward")] == [3, 4]


def test_a_file_in_the_way_is_one_line_exit_2(tmp_path, capsys) -> None:
    blocker = tmp_path / "tb"
    blocker.write_text("not a directory")
    code = main(["train", "--pattern", "circle", *TINY, "--time-budget-s", "0",
                 "--no-progress", "--out", str(tmp_path / "b.onnx"), "--tensorboard",
                 str(blocker)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"patternrl train: --tensorboard {blocker}: not a directory"]


