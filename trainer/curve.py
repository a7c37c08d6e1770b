"""The learning curve: one row per iteration, as CSV and PNG, and its progress bar.

A row (:data:`CURVE_FIELDS`) holds the iteration, the pattern stage, the
training episodes and agent steps so far, the wall time, the mean reward and
success of recent training episodes (noisy: sampled actions), the held-out
evaluation when one ran (``nan`` otherwise; blank in the CSV), and the update's
statistics. ``<stem>.curve.csv`` holds every row; ``<stem>.curve.png`` draws the
reward and both success rates against training episodes, a dotted line at each
new pattern stage. :class:`TensorBoardCurve` writes each row, as it is made, as
TensorBoard scalars (``patternrl train --tensorboard DIR``).
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from runtime.errors import InputError
from trainer.ppo.update import UpdateStats

CURVE_FIELDS = (
    "iteration",
    "stage",
    "pattern",
    "episodes",
    "agent_steps",
    "wall_s",
    "mean_reward",
    "train_success",
    "eval_success",
    "eval_steps",
    "kl",
    "kl_encoder",
    "kl_coef",
    "ae_loss",
    "policy_loss",
    "value_loss",
    "std",
    "explained_var",
    "lr_scale",
)
WALL_FIELDS = ("wall_s",)
"""The columns that differ between two runs of the same seed."""

SCALAR_TAGS: dict[str, str] = {
    "stage": "progress/stage",
    "episodes": "progress/episodes",
    "agent_steps": "progress/agent_steps",
    "wall_s": "progress/wall_s",
    "lr_scale": "progress/lr_scale",
    "mean_reward": "rollout/mean_reward",
    "train_success": "rollout/train_success",
    "eval_success": "eval/eval_success",
    "eval_steps": "eval/eval_steps",
    "kl": "update/kl",
    "kl_encoder": "update/kl_encoder",
    "kl_coef": "update/kl_coef",
    "ae_loss": "update/ae_loss",
    "policy_loss": "update/policy_loss",
    "value_loss": "update/value_loss",
    "std": "update/std",
    "explained_var": "update/explained_var",
}
"""TensorBoard tag of every numeric column; ``iteration`` is the step, ``pattern`` a text."""


def curve_row(
    *,
    iteration: int,
    stage: int,
    pattern: str,
    episodes: int,
    agent_steps: int,
    wall_s: float,
    recent_returns: list[float],
    recent_success: list[bool],
    eval_success: float,
    eval_steps: float,
    stats: UpdateStats,
    kl_coef: float,
    lr_scale: float,
) -> dict[str, Any]:
    """One row of the curve; ``recent_*`` are the last training episodes' returns and successes."""
    return {
        "iteration": iteration,
        "stage": stage,
        "pattern": pattern,
        "episodes": episodes,
        "agent_steps": agent_steps,
        "wall_s": wall_s,
        "mean_reward": float(np.mean(recent_returns)) if recent_returns else math.nan,
        "train_success": float(np.mean(recent_success)) if recent_returns else math.nan,
        "eval_success": eval_success,
        "eval_steps": eval_steps,
        "kl": stats.kl,
        "kl_encoder": stats.kl_encoder,
        "kl_coef": kl_coef,
        "ae_loss": stats.ae_loss,
        "policy_loss": stats.policy_loss,
        "value_loss": stats.value_loss,
        "std": stats.std,
        "explained_var": stats.explained_var,
        "lr_scale": lr_scale,
    }


def write_curve(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CURVE_FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(r.get(k)) for k in CURVE_FIELDS})


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def plot_curve(path: Path, rows: list[dict[str, Any]], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = [r["episodes"] for r in rows]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    a1.plot(ep, [r["mean_reward"] for r in rows], lw=1)
    a1.set_ylabel("mean episode reward")
    a1.set_title(title)
    ev = [(r["episodes"], r["eval_success"]) for r in rows if not math.isnan(r["eval_success"])]
    a2.plot(ep, [r["train_success"] for r in rows], lw=1, alpha=0.6, label="training episodes")
    if ev:
        a2.plot(*zip(*ev, strict=True), "o-", ms=3, label="held-out, deterministic")
    a2.set_ylabel("success rate")
    a2.set_xlabel("training episodes")
    a2.set_ylim(-0.02, 1.02)
    a2.legend(loc="lower right")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    stages = [r["episodes"] for i, r in enumerate(rows) if i and r["stage"] != rows[i - 1]["stage"]]
    for x in stages:
        a1.axvline(x, color="grey", ls=":")
        a2.axvline(x, color="grey", ls=":")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


class ProgressBar:
    """A tqdm bar on stderr when it is a terminal; else one plain line every N iterations."""

    def __init__(self, enabled: bool | None, total: int | None, log_every: int) -> None:
        self.bar: Any = None
        self.log_every = log_every
        use_bar = sys.stderr.isatty() if enabled is None else enabled
        if use_bar:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="ep", file=sys.stderr, dynamic_ncols=True)
        self.quiet = enabled is False

    def update(self, row: dict[str, Any], new_episodes: int) -> None:
        fields = {
            "rew": f"{row['mean_reward']:.2f}",
            "succ": f"{row['train_success']:.2f}",
            "eval": "-" if math.isnan(row["eval_success"]) else f"{row['eval_success']:.2f}",
            "kl": f"{row['kl']:.4f}",
            "lam": f"{row['kl_coef']:.3g}",
        }
        if self.bar is not None:
            self.bar.set_description(f"{row['pattern']}")
            self.bar.set_postfix(fields, refresh=False)
            self.bar.update(new_episodes)
        elif not self.quiet and row["iteration"] % self.log_every == 0:
            text = " ".join(f"{k}={v}" for k, v in fields.items())
            print(
                f"train it={row['iteration']} {row['pattern']} ep={row['episodes']} "
                f"t={row['wall_s']:.0f}s {text}",
                file=sys.stderr,
                flush=True,
            )

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class TensorBoardCurve:
    """The curve as TensorBoard scalars, one step per iteration, flushed as each row comes.

    Call it with each row (it is a ``train(on_iteration=...)`` hook). Every column of
    :data:`CURVE_FIELDS` is written: the numbers under :data:`SCALAR_TAGS` (a ``nan``,
    e.g. an iteration without held-out evaluation, is left out, as the CSV leaves it
    blank), the pattern as the text ``pattern`` whenever it changes. ``texts`` (e.g. the
    configuration as TOML) are written once at the start. Use it as a context manager:
    the file is closed at the end and on Ctrl-C.
    """

    def __init__(self, logdir: Path, texts: dict[str, str] | None = None) -> None:
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as e:
            raise InputError(
                f"--tensorboard needs the tensorboard package ({e}); "
                "pip install 'pattern-rl[train]'"
            ) from None
        if logdir.exists() and not logdir.is_dir():
            raise InputError(f"--tensorboard {logdir}: not a directory")
        try:
            self.writer = SummaryWriter(log_dir=str(logdir))
        except OSError as e:
            raise InputError(f"--tensorboard {logdir}: {e.strerror or e}") from None
        self._pattern: str | None = None
        for tag, text in (texts or {}).items():
            # markdown: indented lines show as they are
            self.writer.add_text(tag, "\n".join("    " + ln for ln in text.splitlines()), 0)
        self.writer.flush()

    def __call__(self, row: dict[str, Any]) -> None:
        step = int(row["iteration"])
        for col, tag in SCALAR_TAGS.items():
            v = row.get(col)
            if v is not None and math.isfinite(float(v)):
                self.writer.add_scalar(tag, float(v), step)
        if row.get("pattern") != self._pattern:
            self._pattern = str(row.get("pattern"))
            self.writer.add_text("pattern", self._pattern, step)
        self.writer.flush()  # seen live by ``tensorboard --logdir``

    def close(self) -> None:
        self.writer.close()

    def __enter__(self) -> TensorBoardCurve:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
