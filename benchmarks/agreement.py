"""Agreement (``--agree off|frame|slots``): what it saves on the demo's transitions, and what
it costs.

    .venv/bin/python benchmarks/agreement.py [--episodes 20] [--launches 3] [--json]

Side by side in one run, the robots telling each other nothing (``off``), the leader telling
its plan's frame (``frame``, the default) and every robot its slot too (``slots``;
:mod:`runtime.decision.agreement`):

1. **Transitions** as ``patternrl eval --from A --pattern B --agree MODE`` runs them: 10 robots,
   every episode starting with A just formed, the demo's circle -> cross -> line -> heart,
   under the realistic preset and 5 cm of noise alone; ``rule:frame-balanced`` with the
   tracker and the shipped ``general.onnx`` as the demo runs it (no tracker). Success and
   steps over each episode's lower bound (mean over formed), the same seeds both ways.
2. **The demo**: ``patternrl launch --conditions realistic --agree MODE`` as a user runs it
   (the pymunk world, one process per robot, mutual TLS, the launcher's defaults),
   ``--launches`` times each way, seeds 0, 1, ...: the steps of each phase.
3. **Decision cost**: what hearing the team and agreeing adds to one robot's decision
   (:class:`runtime.robot.slot_talk.SlotTalk` over a team whose every peer told a step
   before, then :class:`runtime.decision.agreement.SlotAgreement`), median microseconds at
   n = 10, 25, 50, 100; and the messages a swarm exchanges a step for it (``slots``: n robots
   tell, each hears n - 1, n (n - 1) deliveries; ``frame``: the leader tells, n - 1).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402 -- path set-up

from runtime.brain.brain import load_brain  # noqa: E402
from runtime.conditions import parse_conditions  # noqa: E402
from runtime.decision.agreement import AGREE_MODES, SlotAgreement  # noqa: E402
from runtime.robot.slot_talk import SlotTalk  # noqa: E402
from runtime.wire import keys  # noqa: E402
from runtime.wire.messages import Slots, encode_slots  # noqa: E402
from trainer.evaluate import evaluate_brain  # noqa: E402

TRANSITIONS = (("circle", "cross"), ("cross", "line"), ("line", "heart"))
CASES = ("realistic", "noise_m=0.05")
BRAINS = ("rule:frame-balanced+est", "exports/general.onnx")
SEED = 3_000_000


def transitions(episodes: int) -> list[dict[str, Any]]:
    rows = []
    for name in BRAINS:
        estimator = name.endswith("+est")
        path = name.removesuffix("+est")
        brain = load_brain(str(ROOT / path) if path.endswith(".onnx") else path)
        for case in CASES:
            for a, b in TRANSITIONS:
                row: dict[str, Any] = {"brain": name, "case": case, "from": a, "to": b}
                for mode in AGREE_MODES:
                    r = evaluate_brain(brain, b, 10, episodes, seed=SEED,
                                       conditions=parse_conditions(case), estimator=estimator,
                                       progress=False, start_pattern=a, agree=mode)
                    row[mode] = {"success": r.success_rate, "steps": r.steps_ratio,
                                 "collisions": r.collisions}
                rows.append(row)
    return rows


def launches(count: int) -> list[dict[str, Any]]:
    out = []
    for seed in range(count):
        row: dict[str, Any] = {"seed": seed}
        for mode in AGREE_MODES:
            cmd = [str(ROOT / ".venv/bin/patternrl"), "launch", "--conditions", "realistic",
                   "--seed", str(seed), "--no-record", "--no-plot", "--json",
                   "--swarm", f"bench-agree-{seed}-{mode}", "--agree", mode]
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
            if p.returncode != 0:
                raise SystemExit(f"agreement: launch failed: {p.stderr.strip()[-300:]}")
            res = json.loads(p.stdout.strip().splitlines()[-1])
            row[mode] = {
                "steps": res["steps"], "all_formed": res["all_formed"],
                "phases": [(ph["pattern"], ph["steps"], ph["lower_bound_steps"],
                            ph["collisions"]) for ph in res["phases"]]}
        out.append(row)
    return out


def decision_cost(calls: int = 2000) -> list[dict[str, Any]]:
    out = []
    cond = parse_conditions("realistic")
    for mode in ("frame", "slots"):
        slots = mode == "slots"
        for n in (10, 25, 50, 100):
            ids = list(range(n))
            talk = SlotTalk(1, cond, (0, 1), lambda what, why: None, slots=slots)
            agreement = SlotAgreement()
            rng = np.random.default_rng(n)
            perm = rng.permutation(n)
            lead = Slots(0, 0, 1, int(perm[0]), np.array(ids), perm, (5.0, 5.0))
            for s in range(calls + 2):  # the leader tells every step; with slots every peer
                for rid in range(n) if slots else (0,):
                    if rid == 1:
                        continue
                    msg = (Slots(0, s, 1, int(perm[0]), np.array(ids), perm, (5.0, 5.0))
                           if rid == 0 else Slots(rid, s, 1, int(perm[rid])))
                    talk.take(keys.slots_key("b", rid), encode_slots(msg))
            own = perm.copy()
            own[[1, 2]] = own[[2, 1]]  # robot 1 disagrees with robot 2: a conflict to resolve
            mine = np.array([5.1, 4.9])
            times = []
            for s in range(1, calls + 1):
                t0 = time.perf_counter_ns()
                heard = talk.heard(s, ids, 1, 1)
                if slots:
                    agreement.agree(1, own, s, heard)
                agreement.follow_frame(heard, mine, 10.0)
                times.append((time.perf_counter_ns() - t0) / 1000.0)
            out.append({"mode": mode, "n": n, "median_us": statistics.median(times),
                        "deliveries_per_step": n * (n - 1) if slots else n - 1,
                        "leader_bytes": len(encode_slots(lead))})
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=20, help="episodes per transition (20)")
    p.add_argument("--launches", type=int, default=3, help="demo launches each way (3)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    a = p.parse_args(argv)
    if a.episodes < 1 or a.launches < 0:
        print("agreement: --episodes must be >= 1 and --launches >= 0", file=sys.stderr)
        return 2
    res = {"transitions": transitions(a.episodes), "launches": launches(a.launches),
           "decision_cost": decision_cost()}
    if a.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"transitions, 10 robots, {a.episodes} episodes, seed {SEED}: success, steps over "
          "the bound; " + " -> ".join(AGREE_MODES))
    for r in res["transitions"]:
        cells = "  ->  ".join(f"{r[m]['success'] * 100:5.1f} % {r[m]['steps']:.3f}x"
                              for m in AGREE_MODES)
        coll = " / ".join(str(r[m]["collisions"]) for m in AGREE_MODES)
        print(f"  {r['brain']:24s} {r['case']:13s} {r['from']:>6s} -> {r['to']:6s} "
              f"{cells}  (collisions {coll})")
    if res["launches"]:
        print("patternrl launch --conditions realistic: steps per phase (bound); "
              + " -> ".join(AGREE_MODES))
        for r in res["launches"]:
            runs = " -> ".join(
                f"{r[m]['steps']} [" + " ".join(f"{p}:{s}({lb})" for p, s, lb, _ in
                                                r[m]["phases"]) + "]" for m in AGREE_MODES)
            print(f"  seed {r['seed']}: {runs}")
        medians = " -> ".join(str(statistics.median(r[m]["steps"] for r in res["launches"]))
                              for m in AGREE_MODES)
        print(f"  median steps: {medians}")
    print("decision cost of hearing and agreeing (one robot, median), messages a step:")
    for c in res["decision_cost"]:
        print(f"  {c['mode']:5s} n = {c['n']:3d}: {c['median_us']:7.1f} us, "
              f"{c['deliveries_per_step']} deliveries a step, the leader's message "
              f"{c['leader_bytes']} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
