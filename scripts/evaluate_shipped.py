"""Evaluate every shipped brain again into its manifest, and sign the manifest.

Usage: .venv/bin/python scripts/evaluate_shipped.py --key RELEASE_KEY [exports]

Each brain is evaluated as `patternrl train` evaluates what it exports: 100 held-out episodes
(seed 1,000,000) of its pattern (random shapes for a general brain) with the current ORCA
defaults, as a robot decides, and the same episodes raw (filter off) under ``raw``. The
manifest's ``evaluation`` block is replaced (with the ORCA parameters it was measured with),
the sidecar ``.json`` rewritten and signed with ``--key`` (the ONNX bytes, and so the brain's
id, never change). Run it after a change of the safety filter's defaults, then
`scripts/brains_table.py` for the README's table.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from runtime.brain.brain import load_brain, sidecar_path
from runtime.brain.cli import sign_brain_file
from runtime.errors import InputError
from trainer.evaluate import manifest_evaluation

EPISODES = 100


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("folder", nargs="?", default="exports", type=Path)
    p.add_argument("--key", required=True, help="the signing key (the release key for exports/)")
    args = p.parse_args()
    try:
        for onnx in sorted(args.folder.glob("*.onnx")):
            side = sidecar_path(onnx)
            manifest = json.loads(side.read_text(encoding="utf-8"))
            pattern = manifest.get("pattern") or "random"
            ev = manifest_evaluation(load_brain(str(onnx)), pattern, int(manifest["n_robots"]),
                                     EPISODES, progress=False)
            manifest["evaluation"] = ev
            manifest.pop("signature", None)
            side.write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
            sign_brain_file(str(onnx), args.key)
            raw = ev["raw"]
            print(f"{onnx.name}: success {ev['success_rate']:.2f} (raw {raw['success_rate']:.2f}),"
                  f" collisions {ev['collisions']} (raw {raw['collisions']}), steps/lb "
                  f"{ev['steps_ratio']}, travel/lb {ev['travel_ratio']}", flush=True)
    except InputError as e:
        print(f"evaluate_shipped: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
