"""Where a brain's raw contacts happen: pairs that touch on the way, and how they move then.

It runs a brain without the safety filter (``patternrl eval --safety off``, the hold window of
20 steps) and follows every episode step by step through ground truth. A pair *touches* in a
step when its centres end the step within ``2R + 1 mm``; such a pair-step is *side by side*
when both robots moved more than half a step's reach and the pair closed by less than 1 cm:
the two travel together in contact, each leaning a little into the other, rather than meeting
head on. Per brain: the touching pair-steps, the episodes they fall in, the share side by side
and the longest run of one pair in contact.

    .venv/bin/python benchmarks/raw_contacts.py --brain exports/cross-10-paper.onnx
        [--pattern cross] [--episodes 300] [--seed 9000000] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.brain.brain import BrainError, load_brain  # noqa: E402 -- path set-up
from runtime.errors import InputError  # noqa: E402
from runtime.types import Array, BoolArray  # noqa: E402
from runtime.world_config import DEFAULT_WORLD  # noqa: E402
from trainer.evaluate import evaluate_brain  # noqa: E402

TOUCH_M = 1e-3
"""A pair touches when its centres are within 2R + this (m) at the end of a step."""
SIDE_CLOSING_M = 0.01
"""Side by side: the pair closed by less than this (m) in the step ..."""
SIDE_SPEED = 0.5
"""... and both robots moved more than this share of a step's reach."""


def classify(P0: Array, P1: Array, running: BoolArray) -> tuple[BoolArray, BoolArray]:
    """Per env and pair (upper triangle order) of one step ``P0 -> P1`` ((E, n, 2) m): which
    pairs touch at its end, and which of those move side by side."""
    n = P0.shape[1]
    i, j = np.triu_indices(n, 1)
    d0 = np.linalg.norm(P0[:, i] - P0[:, j], axis=-1)
    d1 = np.linalg.norm(P1[:, i] - P1[:, j], axis=-1)
    touch = (d1 < DEFAULT_WORLD.min_separation_m + TOUCH_M) & running[:, None]
    moved = np.linalg.norm(P1 - P0, axis=-1)  # (E, n)
    fast = np.minimum(moved[:, i], moved[:, j]) > SIDE_SPEED * DEFAULT_WORLD.max_step_m
    side: BoolArray = touch & fast & (np.abs(d0 - d1) < SIDE_CLOSING_M)
    return touch, side


def run(brain_path: str, pattern: str | None, episodes: int, seed: int) -> dict[str, Any]:
    """Follow ``episodes`` raw episodes of the brain; the contact figures as one row."""
    brain = load_brain(brain_path)
    manifest = brain.manifest
    name = pattern or (manifest.pattern if manifest is not None else None)
    if not name or name == "random":
        raise InputError(f"{brain_path} names no pattern: give --pattern")
    n = brain.spec.n_robots or (manifest.n_robots if manifest and manifest.n_robots else 10)
    frames: list[Array] = []
    alive: list[BoolArray] = []

    def on_step(pos: Array, _pattern: Array, running: BoolArray) -> None:
        frames.append(pos.copy())
        alive.append(running.copy())

    r = evaluate_brain(brain, name, n, episodes, seed=seed, safety=None, on_step=on_step,
                       progress=False)
    touching = side = 0
    hit = np.zeros(episodes, bool)
    run_len = np.zeros((episodes, n * (n - 1) // 2), np.int64)
    longest = 0
    for s in range(len(frames) - 1):
        touch, along = classify(frames[s], frames[s + 1], alive[s])
        touching += int(touch.sum())
        side += int(along.sum())
        hit |= touch.any(axis=1)
        run_len = np.where(touch, run_len + 1, 0)
        longest = max(longest, int(run_len.max(initial=0)))
    return {"brain": brain_path, "pattern": name, "robots": n, "episodes": episodes,
            "seed": seed, "success": r.success_rate,
            "collisions_per_episode": r.collisions / episodes,
            "touching_pair_steps": touching, "episodes_with_contact": int(hit.sum()),
            "side_by_side": side, "side_by_side_share": side / touching if touching else 0.0,
            "longest_contact_steps": longest}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--brain", action="append", required=True,
                   help="an .onnx brain; give it again for more brains")
    p.add_argument("--pattern", help="the pattern (default: the brain's own)")
    p.add_argument("--episodes", type=int, default=300, help="episodes (default 300)")
    p.add_argument("--seed", type=int, default=9_000_000, help="world seed (default 9000000)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    a = p.parse_args(argv)
    if a.episodes < 1:
        print("raw_contacts: --episodes must be >= 1", file=sys.stderr)
        return 2
    try:
        rows = [run(b, a.pattern, a.episodes, a.seed) for b in a.brain]
    except (InputError, BrainError, ValueError, FileNotFoundError) as err:
        print(f"raw_contacts: {err}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps({"rows": rows}, indent=1))
        return 0
    for r in rows:
        print(f"{r['brain']} ({r['pattern']}, {r['episodes']} episodes, seed {r['seed']}): "
              f"success {r['success']:.1%}, {r['collisions_per_episode']:.3f} collisions per "
              f"episode; {r['touching_pair_steps']} touching pair-steps in "
              f"{r['episodes_with_contact']} episodes, {r['side_by_side']} side by side "
              f"({r['side_by_side_share']:.0%}), longest contact {r['longest_contact_steps']} "
              "steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
