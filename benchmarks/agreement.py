"""Slot agreement (``--agree``): what it saves on the demo's transitions, and what it costs.

    .venv/bin/python benchmarks/agreement.py [--episodes 20] [--launches 3] [--json]

Side by side in one run, without and with the agreement (:mod:`runtime.decision.agreement`):

1. **Transitions** as ``patternrl eval --from A --pattern B [--agree]`` runs them: 10 robots,
   every episode starting with A just formed, the demo's circle -> cross -> line -> heart,
   under the realistic preset and 5 cm of noise alone; ``rule:frame-balanced`` with the
   tracker and the shipped ``general.onnx`` as the demo runs it (no tracker). Success and
   steps over each episode's lower bound (mean over formed), the same seeds both ways.
2. **The demo**: ``patternrl launch --conditions realistic [--agree]`` as a user runs it (the
   pymunk world, one process per robot, mutual TLS, the launcher's defaults), ``--launches``
   times each way, seeds 0, 1, ...: the steps of each phase.
3. **Decision cost**: what hearing the team's slots and agreeing adds to one robot's decision
   (:class:`runtime.robot.slot_talk.SlotTalk` over a team whose every peer told a step
   before, then :class:`runtime.decision.agreement.SlotAgreement`), median microseconds at
   n = 10, 25, 50, 100; and the messages a swarm exchanges a step for it (n robots tell, each
   hears n - 1: n (n - 1) deliveries).
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
from runtime.decision.agreement import SlotAgreement  # noqa: E402
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
                for agree in (False, True):
                    r = evaluate_brain(brain, b, 10, episodes, seed=SEED,
                                       conditions=parse_conditions(case), estimator=estimator,
                                       progress=False, start_pattern=a, agree=agree)
                    tag = "agree" if agree else "own"
                    row[tag] = {"success": r.success_rate, "steps": r.steps_ratio,
                                "collisions": r.collisions}
                rows.append(row)
    return rows


def launches(count: int) -> list[dict[str, Any]]:
    out = []
    for seed in range(count):
        row: dict[str, Any] = {"seed": seed}
        for agree in (False, True):
            cmd = [str(ROOT / ".venv/bin/patternrl"), "launch", "--conditions", "realistic",
                   "--seed", str(seed), "--no-record", "--no-plot", "--json",
                   "--swarm", f"bench-agree-{seed}-{int(agree)}"]
            if agree:
                cmd.append("--agree")
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
            if p.returncode != 0:
                raise SystemExit(f"agreement: launch failed: {p.stderr.strip()[-300:]}")
            res = json.loads(p.stdout.strip().splitlines()[-1])
            row["agree" if agree else "own"] = {
                "steps": res["steps"], "all_formed": res["all_formed"],
                "phases": [(ph["pattern"], ph["steps"], ph["lower_bound_steps"],
                            ph["collisions"]) for ph in res["phases"]]}
        out.append(row)
    return out


def decision_cost(calls: int = 2000) -> list[dict[str, Any]]:
    out = []
    cond = parse_conditions("realistic")
    for n in (10, 25, 50, 100):
        ids = list(range(n))
        talk = SlotTalk(1, cond, (0, 1), lambda what, why: None)
        agreement = SlotAgreement()
        rng = np.random.default_rng(n)
        perm = rng.permutation(n)
        for s in range(calls + 2):  # every peer tells every step; the leader its assignment
            for rid in range(n):
                if rid == 1:
                    continue
                msg = (Slots(0, s, 1, int(perm[0]), np.array(ids), perm) if rid == 0
                       else Slots(rid, s, 1, int(perm[rid])))
                talk.take(keys.slots_key("b", rid), encode_slots(msg))
        own = perm.copy()
        own[[1, 2]] = own[[2, 1]]  # robot 1 disagrees with robot 2: a conflict to resolve
        times = []
        for s in range(1, calls + 1):
            t0 = time.perf_counter_ns()
            heard = talk.heard(s, ids, 1, 1)
            agreement.agree(1, own, s, heard)
            times.append((time.perf_counter_ns() - t0) / 1000.0)
        out.append({"n": n, "median_us": statistics.median(times),
                    "deliveries_per_step": n * (n - 1),
                    "leader_bytes": len(encode_slots(Slots(0, 1, 1, int(perm[0]),
                                                           np.array(ids), perm)))})
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
          "the bound; own assignment -> slot agreement")
    for r in res["transitions"]:
        o, g = r["own"], r["agree"]
        print(f"  {r['brain']:24s} {r['case']:13s} {r['from']:>6s} -> {r['to']:6s} "
              f"{o['success'] * 100:5.1f} % {o['steps']:.3f}x  ->  "
              f"{g['success'] * 100:5.1f} % {g['steps']:.3f}x  "
              f"(collisions {o['collisions']} / {g['collisions']})")
    if res["launches"]:
        print("patternrl launch --conditions realistic: steps per phase (bound); own -> agree")
        for r in res["launches"]:
            fmt = " ".join(f"{p}:{s}({lb})" for p, s, lb, _ in r["own"]["phases"])
            fmt2 = " ".join(f"{p}:{s}({lb})" for p, s, lb, _ in r["agree"]["phases"])
            print(f"  seed {r['seed']}: {r['own']['steps']} [{fmt}] -> "
                  f"{r['agree']['steps']} [{fmt2}]")
        own = [r["own"]["steps"] for r in res["launches"]]
        agr = [r["agree"]["steps"] for r in res["launches"]]
        print(f"  median steps: {statistics.median(own)} -> {statistics.median(agr)}")
    print("decision cost of hearing and agreeing (one robot, median), messages a step:")
    for c in res["decision_cost"]:
        print(f"  n = {c['n']:3d}: {c['median_us']:7.1f} us, {c['deliveries_per_step']} "
              f"deliveries a step, the leader's message {c['leader_bytes']} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
