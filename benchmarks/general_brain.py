"""The general brain on patterns and team sizes it never saw in training, beside the baselines.

Part 1, formation quality. The brain (default ``exports/general.onnx``, trained on
random shapes only, with 10 and then 20 robots) forms patterns it never saw:
the built-ins (circle, cross, line, heart, triangle) and two shapes this script
writes as pattern files (``star``: a five-pointed star outline; ``spiral``: an
open Archimedean spiral of two and a half turns), with teams of 7, 13, 25 and 50
robots. Each case runs the same seeded episodes (episode ``e`` is the first
episode of env ``e`` of a world seeded with ``--seed + n``, so every brain and
every pattern of a team size starts from the same positions) with
:func:`trainer.evaluate.evaluate_brain`: the training world
(:class:`trainer.world.training_world.BatchWorld`) and the runtime's
:func:`runtime.decision.pipeline.decide_batch`, exactly as a robot decides (shared slot
assignment with hysteresis, the observation builder, the policy mean, the clamp
to v_max, the ORCA filter). Four brains on the same episodes:

============== ================================================================
general+orca   the general brain behind the ORCA safety filter (as shipped)
general raw    the general brain alone (``--safety off``)
rule+orca      ``rule:assign`` (straight to the shared slot) behind ORCA
rule raw       ``rule:assign`` alone
============== ================================================================

Figures per case (as ``patternrl eval`` reports them): success (formed within
the step limit with no collision), colliding pairs summed over the episodes,
steps and travel as ratios to the lower bounds (mean over formed episodes), the
closest approach of two centres along the commanded moves (below 2R = 0.2 m is a
collision) and how often the filter changed a command. The
goals (DESIGN.md section 5): success >= 99 %, zero collisions, steps <= 1.20x,
travel <= 1.10x; each row says ``pass`` or which goals it missed, with the true
figures. The summary pools every case of a brain (success and collisions over
all episodes, ratios over all formed episodes, and the worst case).

Part 2, dropout (``--no-dropout`` skips it). ``patternrl launch`` in a
subprocess: the world and 12 ``patternrl robot`` processes over Zenoh on
loopback, lockstep, every robot running the general brain behind ORCA, on
heart then star. When the world has run ``--kill-step`` steps of the heart (a
watcher on the swarm follows the poses), two robots are killed by PID
(SIGKILL); the world sees their liveliness go and publishes the pattern resized
to the 10 left. The result is read from the run's MCAP alone
(:func:`sim_bridge.log.report.report_log`): who left and when, whether and in how
many steps each phase formed, collisions and the smallest separation, and which
brains decided (and that no brain was swapped).

    .venv/bin/python benchmarks/general_brain.py [--brain exports/general.onnx]
        [--episodes 20] [--episodes-50 10] [--quick] [--json] [--no-dropout]

``--quick``: circle, cross, star and spiral with 7 and 13 robots, 4 episodes,
and the dropout run. A full run takes about 10-20 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.brain.brain import RULE_ASSIGN, Brain, load_brain  # noqa: E402 -- after the path set-up
from runtime.decision.patterns import make_pattern, min_spacing, resample_polyline  # noqa: E402
from runtime.decision.safety import OrcaParams  # noqa: E402
from runtime.world_config import DEFAULT_WORLD  # noqa: E402
from trainer.evaluate import EvalResult, evaluate_brain  # noqa: E402

BUILTINS = ("circle", "cross", "line", "heart", "triangle")
HANDMADE = ("star", "spiral")
SIZES = (7, 13, 25, 50)
DEFAULT_SEED = 2_000_000
"""Training draws from seeds 0 and 1, checkpoint selection and ``patternrl eval`` from
1_000_000 and up: 2_000_000 + n is used by neither."""

GOAL_SUCCESS = 0.99
GOAL_STEPS = 1.20
GOAL_TRAVEL = 1.10

CONFIGS = (  # (label, general brain?, ORCA?)
    ("general+orca", True, True),
    ("general raw", True, False),
    ("rule+orca", False, True),
    ("rule raw", False, False),
)


# ------------------------------------------------------------------- patterns


def star_polyline(points: int = 5, inner: float = 0.45, sub: int = 8) -> np.ndarray:
    """A star outline, each edge cut into ``sub`` pieces (a file never holds exactly n points)."""
    a = np.pi / 2 + np.arange(2 * points) * np.pi / points
    r = np.where(np.arange(2 * points) % 2 == 0, 1.0, inner)
    v = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    nxt = np.roll(v, -1, axis=0)
    t = np.arange(sub)[:, None, None] / sub
    out: np.ndarray = (v[None] * (1 - t) + nxt[None] * t).transpose(1, 0, 2).reshape(-1, 2)
    return out


def spiral_polyline(turns: float = 2.5, m: int = 400) -> np.ndarray:
    """An open Archimedean spiral r = 0.3 + theta / (2 pi), ``turns`` turns."""
    th = np.linspace(0.0, 2 * np.pi * turns, m)
    r = 0.3 + th / (2 * np.pi)
    out: np.ndarray = np.stack([r * np.cos(th), r * np.sin(th)], axis=1)
    return out


def write_pattern(directory: Path, name: str, n: int) -> Path:
    """``<directory>/<name>.json``: the shape's polyline, scaled so that its ``n``
    resampled points are ``pattern_spacing_m`` (4R) apart at the closest, like the
    built-ins."""
    closed = name == "star"
    verts = star_polyline() if name == "star" else spiral_polyline()
    gap = min_spacing(resample_polyline(verts, n, closed))
    verts = verts * (DEFAULT_WORLD.pattern_spacing_m / gap)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.json"
    path.write_text(json.dumps({"points": np.round(verts, 6).tolist(), "closed": closed}))
    make_pattern(path, n)  # refuses a bad shape here rather than mid-run
    return path


def pattern_ref(name: str, n: int, out_dir: Path) -> str:
    if name in HANDMADE:
        return str(write_pattern(out_dir / "patterns" / f"n{n}", name, n))
    return name


# ------------------------------------------------------------------- part 1


@dataclass
class Case:
    config: str
    pattern: str
    n: int
    episodes: int
    seed: int
    success_rate: float
    formed_rate: float
    collisions: int
    steps_ratio: float | None
    travel_ratio: float | None
    mean_steps: float | None
    safety_interventions: float
    wall_s: float
    min_separation_m: float | None = None
    """Closest approach of two centres along the commanded moves (below 2R: a collision)."""
    misses: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.misses


def _nan_none(x: float) -> float | None:
    return None if isinstance(x, float) and math.isnan(x) else x


def judge(success: float, collisions: int, steps: float | None, travel: float | None
          ) -> list[str]:
    """The goals a figure set misses (empty: every goal met)."""
    misses = []
    if success < GOAL_SUCCESS:
        misses.append("success")
    if collisions > 0:
        misses.append("collisions")
    if steps is None or steps > GOAL_STEPS:
        misses.append("steps")
    if travel is None or travel > GOAL_TRAVEL:
        misses.append("travel")
    return misses


def run_case(config: str, brain: Brain, orca: bool, pattern: str, label: str, n: int,
             episodes: int, seed: int) -> Case:
    r: EvalResult = evaluate_brain(brain, pattern, n, episodes, seed=seed,
                                   safety=OrcaParams() if orca else None, progress=False,
                                   label=label)
    steps, travel = _nan_none(r.steps_ratio), _nan_none(r.travel_ratio)
    return Case(config, label, n, episodes, seed, r.success_rate, r.formed_rate, r.collisions,
                steps, travel, _nan_none(r.mean_steps), r.safety_interventions, r.wall_s,
                _nan_none(float(getattr(r, "min_separation_m", math.nan))),
                judge(r.success_rate, r.collisions, steps, travel))


def summarise(cases: list[Case]) -> list[dict[str, Any]]:
    """Per brain, pooled over its cases."""
    out = []
    for config, *_ in CONFIGS:
        mine = [c for c in cases if c.config == config]
        if not mine:
            continue
        eps = sum(c.episodes for c in mine)
        formed = [(c.formed_rate * c.episodes, c) for c in mine if c.steps_ratio is not None]
        n_formed = sum(f for f, _ in formed)
        success = sum(c.success_rate * c.episodes for c in mine) / eps
        collisions = sum(c.collisions for c in mine)
        steps = (sum(f * c.steps_ratio for f, c in formed if c.steps_ratio is not None)
                 / n_formed) if n_formed else None
        travel = (sum(f * c.travel_ratio for f, c in formed if c.travel_ratio is not None)
                  / n_formed) if n_formed else None
        out.append({
            "config": config, "cases": len(mine), "cases_passed": sum(c.passed for c in mine),
            "episodes": eps, "success_rate": success, "collisions": collisions,
            "steps_ratio": steps, "travel_ratio": travel,
            "worst_steps_ratio": max((c.steps_ratio for c in mine if c.steps_ratio is not None),
                                     default=None),
            "worst_travel_ratio": max((c.travel_ratio for c in mine
                                       if c.travel_ratio is not None), default=None),
            "lowest_success_rate": min(c.success_rate for c in mine),
            "min_separation_m": min((c.min_separation_m for c in mine
                                     if c.min_separation_m is not None), default=None),
            "wall_s": sum(c.wall_s for c in mine),
            "misses": judge(success, collisions, steps, travel),
        })
    return out


# ------------------------------------------------------------------- part 2


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def children_of(pid: int) -> list[int]:
    out: list[int] = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out += [int(x) for x in f.read().split()]
    except FileNotFoundError:
        pass
    return out


def robot_pids(launcher: int) -> dict[int, int]:
    """Robot id -> PID of the launcher's robot processes (from their command lines)."""
    out: dict[int, int] = {}
    for pid in children_of(launcher):
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"robot" in argv and b"--id" in argv:
            out[int(argv[argv.index(b"--id") + 1])] = pid
    return out


class StepWatcher:
    """A Zenoh peer on the swarm that follows the highest step of the world's poses."""

    def __init__(self, swarm: str, port: int) -> None:
        from runtime.net.session import open_session
        from runtime.wire import keys

        self.session = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"],
                                    listen=["tcp/127.0.0.1:0"])
        self.step = -1
        self.lock = threading.Lock()
        self.sub = self.session.declare_subscriber(keys.all_poses(swarm), self._on_pose)

    def _on_pose(self, sample: Any) -> None:
        from runtime.wire.messages import MessageError, decode_pose

        try:
            p = decode_pose(sample.payload.to_bytes())
        except MessageError:
            return
        with self.lock:
            self.step = max(self.step, p.step)

    def close(self) -> None:
        try:
            self.sub.undeclare()  # type: ignore[no-untyped-call]
            self.session.close()  # type: ignore[no-untyped-call]
        except Exception:
            pass


def dropout_run(brain_ref: str, out_dir: Path, robots: int, kill: tuple[int, ...],
                kill_step: int, seed: int, timeout_s: float = 240.0) -> dict[str, Any]:
    """Launch world + robots, kill ``kill`` by PID at ``kill_step``, analyse the MCAP."""
    from sim_bridge.log.report import report_log

    star = write_pattern(out_dir / "patterns" / f"n{robots}", "star", robots)
    log = out_dir / "dropout.mcap"
    for stale in (log, log.with_suffix(".robots.log")):
        stale.unlink(missing_ok=True)
    port, swarm = free_port(), f"gbench-{os.getpid()}"
    cmd = [sys.executable, "-m", "patternrl.cli", "launch", "--robots", str(robots),
           "--patterns", f"heart,{star}", "--brains", brain_ref, "--record", str(log),
           "--seed", str(seed), "--swarm", swarm, "--zenoh-port", str(port), "--no-plot",
           "--json", "--insecure"]  # the step watcher joins on open TCP
    t0 = time.monotonic()
    launcher = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                stdin=subprocess.DEVNULL, start_new_session=True,
                                env=dict(os.environ, PYTHONUNBUFFERED="1"))
    killed: dict[int, int] = {}
    watcher: StepWatcher | None = None
    step_at_kill = -1
    try:
        deadline = time.monotonic() + 60.0
        while watcher is None:  # the launcher's world listens once it has started
            try:
                watcher = StepWatcher(swarm, port)
            except Exception:
                if time.monotonic() > deadline or launcher.poll() is not None:
                    raise RuntimeError("the launcher's world never came up") from None
                time.sleep(0.2)
        deadline = time.monotonic() + timeout_s
        while launcher.poll() is None and time.monotonic() < deadline:
            with watcher.lock:
                step = watcher.step
            if step >= kill_step:
                pids = robot_pids(launcher.pid)
                for rid in kill:
                    if rid in pids:
                        os.kill(pids[rid], signal.SIGKILL)
                        killed[rid] = pids[rid]
                step_at_kill = step
                break
            time.sleep(0.005)
        out, err = launcher.communicate(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        launcher.send_signal(signal.SIGINT)  # it stops its robots and finishes the log
        out, err = launcher.communicate(timeout=30)
    finally:
        if watcher is not None:
            watcher.close()
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
    wall = time.monotonic() - t0
    rep = report_log(log)
    events = _events(log)
    leaves = [e for e in events if e.get("kind") == "leave"]
    resizes = [{"step": e["step"], "pattern": e["name"], "n": e["n"]} for e in events
               if e.get("kind") == "pattern" and e.get("reason") == "resize"]
    swaps = [e for e in events if e.get("kind") == "brain_swap"]
    phases = []
    for ph in rep.phases:
        n_end = ph.n_robots - len(ph.lost) + len(ph.joined)
        phases.append({
            "pattern": ph.pattern, "robots_at_start": ph.n_robots, "robots_at_end": n_end,
            "lost": ph.lost, "formed": ph.formed, "steps": ph.steps,
            "start_step": ph.start_step, "end_step": ph.end_step,
            "lower_bound_steps": ph.lower_bound_steps, "steps_ratio": ph.steps_ratio,
            "travel_ratio": ph.travel_ratio, "collisions": ph.collisions,
            "min_separation_m": ph.min_separation_m, "final_error_m": ph.final_error_m,
            "deadline_misses": ph.deadline_misses, "brains": ph.brains,
            "swaps_accepted": ph.swaps_accepted, "mismatches": ph.mismatches,
        })
    try:
        launch_json = json.loads(out.decode().strip().splitlines()[-1])
    except (ValueError, IndexError):
        launch_json = None
    return {
        "log": str(log), "robots": robots, "killed": sorted(killed), "kill_pids": killed,
        "watcher_step_at_kill": step_at_kill,
        "leave_events": [{"robot": e["robot"], "step": e["step"], "n_live": e["n_live"]}
                         for e in leaves],
        "resizes": resizes,
        "swaps": {"sent": len(swaps),
                  "changed_brain": sum(1 for e in swaps if e.get("accepted")
                                       and e.get("old_brain_id") != e.get("brain_id"))},
        "outcome": rep.outcome, "finished": rep.finished, "phases": phases,
        "all_formed": bool(phases) and all(p["formed"] for p in phases),
        "mid_formation": bool(phases and leaves) and all(
            phases[0]["start_step"] <= e["step"] < phases[0]["end_step"] for e in leaves),
        "exit_code": launcher.returncode, "wall_s": round(wall, 1),
        "launcher_stderr_tail": err.decode(errors="replace").strip().splitlines()[-6:],
        "launcher_result": launch_json,
    }


def _events(log: Path) -> list[dict[str, Any]]:
    from sim_bridge.log.reader import read_log

    return list(read_log(log).events)


# ------------------------------------------------------------------- output


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _x(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f}x"


def _table(head: list[str], rows: list[list[str]], left: set[int]) -> str:
    w = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(head)]

    def fmt(cells: list[str]) -> str:
        return "  ".join(c.ljust(w[i]) if i in left else c.rjust(w[i])
                         for i, c in enumerate(cells)).rstrip()

    return "\n".join([fmt(head), fmt(["-" * x for x in w]), *(fmt(r) for r in rows)])


def format_cases(cases: list[Case]) -> str:
    head = ["brain", "pattern", "n", "episodes", "success", "collisions", "steps", "travel",
            "mean steps", "min sep m", "filter changed", "goals"]
    rows = [[c.config, c.pattern, str(c.n), str(c.episodes), _pct(c.success_rate),
             str(c.collisions), _x(c.steps_ratio), _x(c.travel_ratio),
             "-" if c.mean_steps is None else f"{c.mean_steps:.1f}",
             "-" if c.min_separation_m is None else f"{c.min_separation_m:.3f}",
             _pct(c.safety_interventions),
             "pass" if c.passed else "miss: " + ", ".join(c.misses)] for c in cases]
    return _table(head, rows, {0, 1, 11})


def format_summary(summary: list[dict[str, Any]]) -> str:
    head = ["brain", "cases passed", "episodes", "success", "lowest", "collisions",
            "min sep m", "steps", "worst", "travel", "worst", "goals"]
    rows = [[s["config"], f"{s['cases_passed']}/{s['cases']}", str(s["episodes"]),
             _pct(s["success_rate"]), _pct(s["lowest_success_rate"]), str(s["collisions"]),
             "-" if s["min_separation_m"] is None else f"{s['min_separation_m']:.3f}",
             _x(s["steps_ratio"]), _x(s["worst_steps_ratio"]), _x(s["travel_ratio"]),
             _x(s["worst_travel_ratio"]),
             "pass" if not s["misses"] else "miss: " + ", ".join(s["misses"])]
            for s in summary]
    return _table(head, rows, {0, 11})


def format_dropout(d: dict[str, Any]) -> str:
    lines = [f"dropout: {d['robots']} robot processes, killed {d['killed']} by PID "
             f"(SIGKILL) when the world was at step {d['watcher_step_at_kill']}; "
             f"the world logged "
             + ", ".join(f"robot {e['robot']} leaving at step {e['step']} ({e['n_live']} live)"
                         for e in d["leave_events"])
             + "; the world re-published "
             + (", ".join(f"{r['pattern']} for {r['n']} robots at step {r['step']}"
                          for r in d["resizes"]) or "no resized pattern")
             + f"; brain swaps that changed a robot's brain: {d['swaps']['changed_brain']}"]
    head = ["pattern", "robots", "lost", "formed", "steps", "lb", "x lb", "collisions",
            "min sep m", "final err m", "misses", "brains (commands)", "swaps"]
    rows = []
    for p in d["phases"]:
        rows.append([p["pattern"], f"{p['robots_at_start']}->{p['robots_at_end']}",
                     ",".join(map(str, p["lost"])) or "-", "yes" if p["formed"] else "NO",
                     str(p["steps"]), str(p["lower_bound_steps"]),
                     "-" if p["steps_ratio"] is None else f"{p['steps_ratio']:.2f}",
                     str(p["collisions"]),
                     "-" if p["min_separation_m"] is None else f"{p['min_separation_m']:.3f}",
                     "-" if p["final_error_m"] is None else f"{p['final_error_m']:.4f}",
                     str(p["deadline_misses"]),
                     ", ".join(f"{b[:8]} x{k}" for b, k in sorted(p["brains"].items())),
                     str(p["swaps_accepted"])])
    lines.append(_table(head, rows, {0, 1, 2, 3, 11}))
    verdict = ("the robots left formed every pattern" if d["all_formed"] else "NOT formed")
    verdict += (", the robots were lost before the first pattern formed" if d["mid_formation"]
                else ", the robots were NOT lost mid-formation")
    lines.append(f"{verdict}; log {d['log']} ({'finished' if d['finished'] else 'cut short'}, "
                 f"outcome {d['outcome']}), launcher exit {d['exit_code']}, {d['wall_s']} s")
    return "\n".join(lines)


# ------------------------------------------------------------------- main


def say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--brain", default=str(ROOT / "exports" / "general.onnx"),
                    help="the general brain (default exports/general.onnx)")
    ap.add_argument("--episodes", type=int, default=20, help="episodes per case (default 20)")
    ap.add_argument("--episodes-50", type=int, default=10,
                    help="episodes per case with 50 robots (default 10: lower bounds cost more)")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED,
                    help=f"base seed; a team of n uses seed + n (default {DEFAULT_SEED})")
    ap.add_argument("--patterns", default=",".join(BUILTINS + HANDMADE))
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--configs", default=",".join(c for c, *_ in CONFIGS))
    ap.add_argument("--quick", action="store_true",
                    help="circle, cross, star, spiral; 7 and 13 robots; 4 episodes")
    ap.add_argument("--no-dropout", action="store_true", help="skip the dropout run")
    ap.add_argument("--dropout-only", action="store_true", help="only the dropout run")
    ap.add_argument("--kill-step", type=int, default=15,
                    help="the world step at which 2 of the 12 robots are killed (default 15)")
    ap.add_argument("--out-dir", type=Path, default=ROOT / "runs" / "general_brain",
                    help="pattern files and the dropout log (default runs/general_brain)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--save", type=Path, default=None, metavar="OUT.json",
                    help="also write the JSON object there")
    args = ap.parse_args(argv)
    if args.quick:  # smaller defaults; what is given explicitly stays
        for name, full, quick in [("patterns", ",".join(BUILTINS + HANDMADE),
                                   "circle,cross,star,spiral"),
                                  ("sizes", ",".join(map(str, SIZES)), "7,13"),
                                  ("episodes", 20, 4), ("episodes_50", 10, 2)]:
            if getattr(args, name) == full:
                setattr(args, name, quick)
    brain_path = Path(args.brain)
    if not brain_path.is_file():
        print(f"general_brain: no brain at {brain_path} (scripts/train_shipped.sh any makes it)",
              file=sys.stderr)
        return 2
    general = load_brain(str(brain_path))
    rule = load_brain(RULE_ASSIGN)
    manifest = getattr(general, "manifest", None)
    training = dict(manifest.training) if manifest is not None else {}
    trained = {k: training.get(k) for k in ("algorithm", "patterns", "episodes", "wall_time_s",
                                            "seed", "init")}
    trained["n_robots"] = manifest.n_robots if manifest is not None else None
    patterns = [p for p in args.patterns.split(",") if p]
    sizes = [int(s) for s in args.sizes.split(",") if s]
    wanted = set(args.configs.split(","))
    args.out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    cases: list[Case] = []
    if not args.dropout_only:
        say(f"brain {brain_path} ({general.brain_id[:12]}), trained on {trained}")
        for n in sizes:
            eps = args.episodes_50 if n >= 50 else args.episodes
            for name in patterns:
                ref = pattern_ref(name, n, args.out_dir)
                for config, is_general, orca in CONFIGS:
                    if config not in wanted:
                        continue
                    c = run_case(config, general if is_general else rule, orca, ref, name, n,
                                 eps, args.seed + n)
                    cases.append(c)
                    say(f"{config:<13} {name:<9} n={n:<3} success {_pct(c.success_rate):>8}  "
                        f"collisions {c.collisions:>3}  steps {_x(c.steps_ratio):>7}  "
                        f"travel {_x(c.travel_ratio):>7}  {c.wall_s:6.1f} s")
    summary = summarise(cases)
    dropout = None
    if not args.no_dropout:
        say("dropout run: 12 robot processes, 2 killed mid-formation ...")
        dropout = dropout_run(str(brain_path), args.out_dir, 12, (3, 8), args.kill_step,
                              seed=args.seed)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    out: dict[str, Any] = {
        "brain": str(brain_path), "brain_id": general.brain_id, "trained": trained,
        "patterns": patterns, "sizes": sizes, "episodes": args.episodes,
        "episodes_50": args.episodes_50, "seed": args.seed,
        "seeding": "a team of n: episode e is the first episode of env e of "
                   "BatchWorld(seed + n), the same for every brain and pattern",
        "goals": {"success_rate": GOAL_SUCCESS, "collisions": 0, "steps_ratio": GOAL_STEPS,
                  "travel_ratio": GOAL_TRAVEL},
        "summary": summary, "cases": [c.__dict__ | {"pass": c.passed} for c in cases],
        "dropout": dropout, "wall_s": round(time.monotonic() - t0, 1),
        "cpus": os.cpu_count(), "load_1min": round(load, 2), "python": platform.python_version(),
    }
    if args.save is not None:
        args.save.write_text(json.dumps(out, indent=2))
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"general brain {brain_path.name} ({general.brain_id[:12]}); trained on "
          f"{trained.get('patterns')} with n = {trained.get('n_robots')}"
          + (f" (fine-tuned from {trained.get('init')})" if trained.get("init") else ""))
    if cases:
        print(f"unseen patterns {', '.join(patterns)}; teams of {', '.join(map(str, sizes))}; "
              f"{args.episodes} episodes per case ({args.episodes_50} with 50 robots), seeds "
              f"{args.seed} + n, the same for every brain")
        print(f"goals: success >= {GOAL_SUCCESS:.0%}, 0 collisions, steps <= {GOAL_STEPS:.2f}x, "
              f"travel <= {GOAL_TRAVEL:.2f}x the lower bounds\n")
        print(format_summary(summary))
        print()
        print(format_cases(cases))
    if dropout is not None:
        print()
        print(format_dropout(dropout))
    print(f"\n{out['wall_s']} s; {os.cpu_count()} CPUs, 1-min load average {load:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
