"""How many robot processes one machine runs in real time: the whole swarm, measured.

Part 1, **realtime** (10 Hz) with N = 10, 25, 50, 100 robots, each N run two ways:

* ``launch``: **what users run**, ``patternrl launch --robots N --patterns circle --mode
  realtime --record RUN.mcap`` as a process of its own with the launcher's defaults: mutual
  TLS with a key per process, Zenoh access control, the swarm's router above 20 robots,
  the MCAP log recorded with its Foxglove scene every step, the general brain. Its figures
  come from its ``--json`` line and its log (the world's ``run_end``: CPU of its stepping
  thread); CPU per robot-step is every process of the run (the launcher, its world and
  every child it waited for: robots, router) from the pattern's start (start-up left out);
* ``open``: the same swarm open and unrecorded, as the figures before this one: the world
  in this process (no recorder, no scene), open TCP on loopback, ``patternrl robot``
  processes (ORCA on). Its CPU per robot-step is the robots' alone, start-up left out.

Reported per run:

* steps/s achieved against the 10 Hz target (steps / wall time of the phase);
* in time: the share of robot-steps decided in time (a command for the step before its
  deadline); stale: moved on an older command (``--max-command-age-steps``); held: no
  command young enough, held still; the oldest command applied; commands the world's
  guard slowed; the world's overruns (steps whose tick had passed before their poses went
  out);
* pose -> command p50 / p99 (ms, ``open`` only): from the world starting to publish a
  step's poses to each command's arrival, over the commands that made their step;
* CPU per robot per step (ms) and the world's CPU per step (ms, its stepping thread);
* PSS per robot (MB, ``open`` only, /proc/<pid>/smaps_rollup: shared libraries counted
  once across the processes that share them) and RSS, median over the robots, read mid-run;
  start-up: seconds from starting the processes to the first step (all N alive);
* formed or not, steps against the lower bound, collisions (the world's swept check).

Part 2, **lockstep** with N = 10 and 20 robot processes: steps/s and pose -> command
p50 / p99 (the world waits for every command or the deadline).

Topology (``--topology``, default ``auto`` as ``patternrl launch``: peer up to 20
robots, router above): ``router``
starts the swarm's Zenoh router (``patternrl router``, a process of its own) and
the world and every robot are its clients, a link each; ``peer`` is the mesh
(the world listens, every robot a peer that connects to it and then to every
other). Beside each run: TCP links between the run's processes (read mid-run
from /proc: both ends counted once), threads per robot process (median), and
the router's CPU per step. Open TCP on loopback (``--insecure``) throughout, as
the figures before; the TLS cost is the launcher's.

Part 3, **one decision** (assignment + observation + brain + ORCA, the robot's
:class:`runtime.decision.controller.Controller`) at N = 10, 50, 100 with the general brain, beside
onnxruntime alone (the same brain's ``act`` on one observation, called after each decision
of the same run): p50 and p99 in microseconds, with the machine's load average printed
beside them (run once on an idle machine and once busy to see both).

    .venv/bin/python benchmarks/swarm_scale.py [--json] [--quick] [--sizes 10,25,50,100]
        [--configs launch,open] [--seed 0] [--topology router|peer] [--lockstep 10,20]
        [--no-decision]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from sim_scale import _cpu_seconds  # noqa: E402 -- one /proc reader for both benchmarks

from runtime.brain.brain import Brain, load_brain  # noqa: E402 -- after the path set-up above
from runtime.decision.safety import OrcaParams  # noqa: E402
from runtime.world_config import DEFAULT_WORLD  # noqa: E402

W = DEFAULT_WORLD
BRAIN = ROOT / "exports" / "general.onnx"


def _mem_mb(pid: int) -> tuple[float, float]:
    """(PSS, RSS) of a process in MB from /proc/<pid>/smaps_rollup; (nan, nan) if unreadable."""
    out = {"Pss:": float("nan"), "Rss:": float("nan")}
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                parts = line.split()
                if parts and parts[0] in out:
                    out[parts[0]] = int(parts[1]) / 1024.0
    except OSError:
        pass
    return out["Pss:"], out["Rss:"]


def _threads(pid: int) -> int:
    """Threads of a process (/proc/<pid>/status), 0 if unreadable."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("Threads:"):
                    return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return 0


def _tcp_links(pids: list[int]) -> int:
    """Established TCP connections among ``pids`` (a link between two of them counts once)."""
    inodes: set[str] = set()
    for pid in pids:
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                try:
                    target = os.readlink(f"/proc/{pid}/fd/{fd}")
                except OSError:
                    continue
                if target.startswith("socket:["):
                    inodes.add(target[8:-1])
        except OSError:
            continue
    ends = 0
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table) as f:
                next(f)
                for line in f:
                    cols = line.split()
                    if cols[3] == "01" and cols[9] in inodes:  # 01: ESTABLISHED
                        ends += 1
        except OSError:
            continue
    return ends // 2


def _pct(a: list[float], q: float) -> float | None:
    return round(float(np.percentile(a, q)), 3) if a else None


def run_swarm(n: int, mode: str, max_steps: int, brain: str, seed: int = 0,
              topology: str = "auto") -> dict[str, Any]:
    """A world in this process and ``n`` robot processes; one circle (or ``max_steps``)."""
    from runtime.net.session import open_session
    from sim_bridge.launch.launch import PEER_MAX_ROBOTS, Robots, free_port
    from sim_bridge.launch.router import RouterProcess
    from sim_bridge.world.sim_world import SimConfig, SimWorld

    if topology == "auto":
        topology = "router" if n > PEER_MAX_ROBOTS else "peer"
    swarm, port = f"bench-{mode}-{n}-{os.getpid()}", free_port()
    cfg = SimConfig(swarm=swarm, robots=n, patterns=["circle"], mode=mode, seed=seed,
                    max_steps=max_steps, wait_robots_s=600.0, first_step_deadline_ms=10_000.0)
    log = Path(os.environ.get("TMPDIR", "/tmp")) / f"{swarm}.robots.log"
    router: RouterProcess | None = None
    if topology == "router":
        router = RouterProcess(swarm, port, None, log)
        router.start()
        session = open_session("client", connect=[router.endpoint], listen=[])
    else:
        session = open_session("peer", connect=[], listen=[f"tcp/127.0.0.1:{port}"])
    world = SimWorld(cfg, session, None, log=lambda msg, detail: None)
    robots = Robots()
    at: dict[str, Any] = {}

    def on_progress(p: Any) -> None:
        if p.step == 1:
            at["t1"] = time.monotonic()
            at["cpu1"] = {r: _cpu_seconds(q.pid) for r, q in robots.procs.items()}
            at["router_cpu1"] = _cpu_seconds(router.pid) if router and router.pid else 0.0
        if p.step == min(20, max_steps // 2):
            mem = [_mem_mb(q.pid) for q in robots.procs.values()]
            at["pss"] = [m[0] for m in mem]
            at["rss"] = [m[1] for m in mem]
            pids = [q.pid for q in robots.procs.values()] + [os.getpid()]
            if router is not None and router.pid is not None:
                pids.append(router.pid)
            at["links"] = _tcp_links(pids)
            at["threads"] = [_threads(q.pid) for q in robots.procs.values()]

    world.on_progress = on_progress
    args = argparse.Namespace(mode=mode, safety="orca", rate_hz=1.0 / W.dt_s,
                              step_deadline_ms=cfg.step_deadline_ms, topology=topology)
    t0 = time.monotonic()
    try:
        robots.start(n, swarm, port, brain, args, log)
        res = world.run()
        cpu_end = {r: _cpu_seconds(q.pid) for r, q in robots.procs.items()}
        router_cpu = (_cpu_seconds(router.pid) - at.get("router_cpu1", 0.0)
                      if router is not None and router.pid is not None else None)
    finally:
        robots.stop()
        session.close()  # type: ignore[no-untyped-call]
        if router is not None:
            router.stop()
        log.unlink(missing_ok=True)
    (ph,) = res.phases
    steps = ph.steps
    cpu = sum(cpu_end[r] - at["cpu1"].get(r, 0.0) for r in cpu_end)
    lat = res.latencies_ms[n:]  # the first step waits for start-up
    return {
        "config": "open", "seed": seed,
        "n": n, "mode": mode, "topology": topology, "steps": steps, "formed": ph.formed,
        "lower_bound_steps": ph.lower_bound_steps, "collisions": ph.collisions,
        "min_separation_m": ph.min_separation_m,
        "steps_per_s": round(steps / ph.wall_s, 2) if ph.wall_s > 0 else None,
        **_timeliness(ph.deadline_misses, ph.stale_commands, ph.held_still, n, steps),
        "command_age_max": ph.command_age_max, "guard_scaled": ph.guard_scaled,
        "late_commands": ph.late_commands, "world_overruns": world.overruns,
        "latency_ms_p50": _pct(lat, 50), "latency_ms_p99": _pct(lat, 99),
        "cpu_ms_per_robot_step": round(cpu * 1000.0 / max(1, n * (steps - 1)), 3),
        "world_cpu_ms_per_step": round(world.stepping_cpu_s * 1000.0 / max(1, steps), 3),
        "pss_mb_median": _pct(at.get("pss", []), 50),
        "rss_mb_median": _pct(at.get("rss", []), 50),
        "start_s": round(at["t1"] - t0, 2) if "t1" in at else None,
        "tcp_links": at.get("links"),
        "threads_per_robot": _pct(at.get("threads", []), 50),
        "router_cpu_ms_per_step": (round(router_cpu * 1000.0 / max(1, steps - 1), 3)
                                   if router_cpu is not None else None),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def _tree_cpu_s(pid: int) -> float:
    """CPU seconds (user + system, with waited-for children) of ``pid`` and its descendants."""
    kids: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            kids.setdefault(ppid, []).append(int(d))
    total, todo = 0.0, [pid]
    tick = os.sysconf("SC_CLK_TCK")
    while todo:
        p = todo.pop()
        todo += kids.get(p, [])
        try:
            with open(f"/proc/{p}/stat") as f:
                cols = f.read().rsplit(")", 1)[1].split()
            total += sum(int(c) for c in cols[11:15]) / tick  # utime stime cutime cstime
        except (OSError, ValueError, IndexError):
            continue
    return total


def _timeliness(misses: int, stale: int, held: int, n: int, steps: int) -> dict[str, float]:
    rs = max(1, n * steps)
    return {"late_share": round(misses / rs, 4), "in_time_share": round(1 - misses / rs, 4),
            "stale_share": round(stale / rs, 4), "held_share": round(held / rs, 4)}


LAUNCH_CONFIGS = {
    "launch": (),
    "launch-insecure": ("--insecure",),
    "launch-unrecorded": ("--no-record",),
    "launch-bare": ("--insecure", "--no-record"),
}
"""``patternrl launch`` as users run it (``launch``: mutual TLS, the log and its scene), and
with TLS off, the log off, or both: the launcher's own options, one feature at a time."""


def run_launch(n: int, max_steps: int, seed: int = 0, config: str = "launch") -> dict[str, Any]:
    """``patternrl launch`` with its defaults (TLS, router above 20, the log and its scene),
    or ``config``'s options off, realtime, one circle (or ``max_steps``); figures from its
    JSON line and (recorded) its log."""
    from sim_bridge.log.reader import read_log

    tmp = Path(tempfile.mkdtemp(prefix="swarm-scale-"))
    rec = tmp / "run.mcap"
    recorded = "--no-record" not in LAUNCH_CONFIGS[config]
    cmd = [sys.executable, "-c", "from patternrl.cli import main; raise SystemExit(main())",
           "launch", "--robots", str(n), "--patterns", "circle", "--mode", "realtime",
           "--seed", str(seed), "--max-steps", str(max_steps),
           "--record", str(rec),
           "--json", "--no-plot", "--start-timeout-s", "300", "--verbose",
           *LAUNCH_CONFIGS[config]]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    at_start: list[float] = []  # CPU of the run's processes when the pattern began
    try:
        out_file = open(tmp / "stdout", "w+")  # read back below
        proc = subprocess.Popen(cmd, stdout=out_file, stderr=subprocess.PIPE, text=True,
                                cwd=ROOT)
        assert proc.stderr is not None
        err: list[str] = []
        for line in proc.stderr:  # the world says when the pattern begins: start-up is over
            err.append(line)
            if not at_start and "pattern 1/" in line:
                at_start.append(_tree_cpu_s(proc.pid))
        code = proc.wait(timeout=600 + 2 * max_steps)
        out_file.seek(0)
        stdout = out_file.read()
        out_file.close()
        wall = time.monotonic() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        lines = [ln for ln in stdout.splitlines() if ln.startswith("{")]
        if not lines:
            raise RuntimeError(f"launch gave no result (exit {code}): {''.join(err)[-1500:]}")
        res = json.loads(lines[-1])
        ages: list[int] = []
        if recorded:
            run = read_log(rec)
            ages = [int(a) for e in run.events_of("stale_command") for a in e.get("ages", [])]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    (ph,) = res["phases"]
    steps = ph["steps"]
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    cpu -= at_start[0] if at_start else 0.0
    end = res.get("world_cpu") or {}
    per_step = 1000.0 / max(1, end.get("steps", 0))
    split = {k: round(v * per_step, 3) for k, v in end.get("stepping_cpu_split_s", {}).items()}
    process = end.get("process_cpu_s", 0.0) * per_step
    stepping = end.get("stepping_cpu_s", 0.0) * per_step
    writer = end.get("writer_cpu_s", 0.0) * per_step
    return {
        "config": config, "seed": seed, "n": n, "mode": "realtime",
        "topology": "router" if n > 20 else "peer", "steps": steps, "formed": ph["formed"],
        "lower_bound_steps": ph["lower_bound_steps"], "collisions": ph["collisions"],
        "min_separation_m": ph["min_separation_m"],
        "steps_per_s": round(steps / ph["wall_s"], 2) if ph["wall_s"] > 0 else None,
        **_timeliness(ph["deadline_misses"], ph.get("stale_commands", 0),
                      ph.get("held_still", ph["deadline_misses"]), n, steps),
        "command_age_max": ph.get("command_age_max", 0),
        "guard_scaled": ph.get("guard_scaled", 0), "late_commands": ph["late_commands"],
        "stale_ages": {int(a): int(c) for a, c in zip(*np.unique(ages, return_counts=True),
                                                       strict=True)},
        "world_overruns": end.get("overruns"),
        "latency_ms_p50": None, "latency_ms_p99": None,
        "cpu_ms_per_robot_step": round(cpu * 1000.0 / max(1, n * steps), 3),
        "world_cpu_ms_per_step": round(stepping, 3) if end else None,
        "world_split_ms_per_step": split,
        "world_writer_ms_per_step": round(writer, 3),
        "world_process_ms_per_step": round(process, 3),
        "world_other_threads_ms_per_step": round(max(0.0, process - stepping - writer), 3),
        "pss_mb_median": None, "rss_mb_median": None, "start_s": None,
        "wall_s": round(wall, 1), "tcp_links": None, "threads_per_robot": None,
        "router_cpu_ms_per_step": None, "exit": code,
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def decision_figures(brain: Brain, n: int, samples: int) -> dict[str, Any]:
    """One decision at team size n (runtime_latency's loop) beside onnxruntime alone."""
    from runtime_latency import decision_latency  # benchmarks/runtime_latency.py

    d = decision_latency(brain, n, samples, OrcaParams())  # onnxruntime alone interleaved
    ort_p50, ort_p99 = d["onnxruntime_alone_p50_us"], d["onnxruntime_alone_p99_us"]
    return {"n": n, "decision_us_p50": round(d["p50_us"], 1),
            "decision_us_p99": round(d["p99_us"], 1),
            "quietest_round_p99_us": round(d["best_round_p99_us"], 1),
            "onnxruntime_us_p50": round(ort_p50, 1),
            "onnxruntime_us_p99": round(ort_p99, 1),
            "ratio_p50": round(d["p50_us"] / ort_p50, 2),
            "load_average_1min": round(os.getloadavg()[0], 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print JSON only")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: realtime 10 and 25 robots, 80 steps, fewer samples")
    ap.add_argument("--sizes", default=None, help="realtime robot counts (default 10,25,50,100)")
    ap.add_argument("--lockstep", default="10,20", help="lockstep robot counts (default 10,20)")
    ap.add_argument("--max-steps", type=int, default=300,
                    help="step limit of a run (default 300; --quick 80)")
    ap.add_argument("--brain", default=str(BRAIN), help="the robots' brain (default general)")
    ap.add_argument("--topology", choices=("auto", "router", "peer"), default="auto",
                    help="router: a Zenoh router, every process its client; peer: the peer "
                         "mesh; auto (default, as launch): peer up to 20 robots, router above")
    ap.add_argument("--configs", default="launch,open",
                    help="realtime runs per size: launch (patternrl launch's defaults: TLS, "
                         "router, log, scene), launch-insecure (TLS off), launch-unrecorded "
                         "(--no-record), launch-bare (both off), open (the world in this "
                         "process, open, unrecorded); default launch,open")
    ap.add_argument("--seed", type=int, default=0, help="seed of the start positions")
    ap.add_argument("--no-decision", action="store_true",
                    help="skip part 3 (one decision beside onnxruntime)")
    args = ap.parse_args()
    sizes = [int(x) for x in (args.sizes or ("10,25" if args.quick else "10,25,50,100"))
             .split(",") if x]
    lock = [int(x) for x in args.lockstep.split(",") if x]
    max_steps = 80 if args.quick else args.max_steps
    samples = 2000 if args.quick else 20000
    load0 = os.getloadavg()[0]
    brain = load_brain(args.brain, W, None)
    decisions = ([] if args.no_decision
                 else [decision_figures(brain, n, samples) for n in (10, 50, 100)])
    configs = [c for c in args.configs.split(",") if c]
    unknown = sorted(set(configs) - set(LAUNCH_CONFIGS) - {"open"})
    if unknown:
        ap.error(f"unknown --configs {','.join(unknown)}: choose from "
                 f"{', '.join([*LAUNCH_CONFIGS, 'open'])}")
    realtime = []
    for n in sizes:
        for c in configs:
            if c in LAUNCH_CONFIGS:
                realtime.append(run_launch(n, max_steps, args.seed, c))
        if "open" in configs:
            realtime.append(run_swarm(n, "realtime", max_steps, args.brain, args.seed,
                                      topology=args.topology))
    lockstep = [run_swarm(n, "lockstep", max_steps, args.brain, args.seed,
                          topology=args.topology) for n in lock]
    out = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "platform": platform.platform(), "load_average_1min_start": round(load0, 2),
                    "load_average_1min_end": round(os.getloadavg()[0], 2)},
        "brain": Path(args.brain).name, "topology": args.topology, "realtime": realtime,
        "lockstep": lockstep,
        "decision": decisions,
    }
    if args.json:
        print(json.dumps(out))
        return 0
    m = out["machine"]
    print(f"machine: {m['cpus']} cpus, python {m['python']}; 1-min load average "
          f"{m['load_average_1min_start']} at the start, {m['load_average_1min_end']} at the end")
    print(f"\nrealtime, 10 Hz target, one circle (or {max_steps} steps), seed {args.seed}; "
          "launch: patternrl launch's defaults (mutual TLS, router above 20, log + scene); "
          "open: open TCP, no log, no scene")
    head = (f"{'config':<17} {'robots':>6} {'steps/s':>7} {'in time':>7} {'stale':>6} "
            f"{'held':>6} {'age':>3} {'guard':>5} {'formed':>6} {'steps':>5} {'lb':>4} "
            f"{'x lb':>5} {'coll':>4} {'cpu ms/robot/step':>17} {'world ms/step':>13} "
            f"{'p50 ms':>7} {'p99 ms':>7} {'PSS MB':>6} {'start s':>7} {'load':>5} topology")
    print(head)
    for r in [*realtime, None, *lockstep]:
        if r is None:
            print("\nlockstep (the world waits for every command, deadline 250 ms)")
            print(head)
            continue
        ratio = r["steps"] / r["lower_bound_steps"] if r["lower_bound_steps"] else float("nan")
        print(f"{r['config']:<17} {r['n']:>6} {r['steps_per_s']!s:>7} "
              f"{100 * r['in_time_share']:>6.1f}% {100 * r['stale_share']:>5.1f}% "
              f"{100 * r['held_share']:>5.1f}% {r['command_age_max']:>3} {r['guard_scaled']:>5} "
              f"{'yes' if r['formed'] else 'no':>6} {r['steps']:>5} "
              f"{r['lower_bound_steps']:>4} {ratio:>5.2f} {r['collisions']:>4} "
              f"{r['cpu_ms_per_robot_step']:>17.3f} {r['world_cpu_ms_per_step']!s:>13} "
              f"{r['latency_ms_p50']!s:>7} {r['latency_ms_p99']!s:>7} "
              f"{r['pss_mb_median']!s:>6} {r['start_s']!s:>7} "
              f"{r['load_average_1min']:>5} {r['topology']}")
    split = [r for r in realtime if r.get("world_split_ms_per_step")]
    if split:
        print("\nthe world's CPU per step (ms): its stepping thread by section, the log's writer "
              "thread, the rest of its process (Zenoh's I/O and TLS)")
        names = list(split[0]["world_split_ms_per_step"])
        print(f"{'config':<17} {'robots':>6} " + " ".join(f"{k:>8}" for k in names)
              + f" {'stepping':>8} {'writer':>8} {'other':>8} {'process':>8}")
        for r in split:
            print(f"{r['config']:<17} {r['n']:>6} "
                  + " ".join(f"{r['world_split_ms_per_step'].get(k, 0.0):>8.2f}" for k in names)
                  + f" {r['world_cpu_ms_per_step']:>8.2f} {r['world_writer_ms_per_step']:>8.2f}"
                  f" {r['world_other_threads_ms_per_step']:>8.2f}"
                  f" {r['world_process_ms_per_step']:>8.2f}")
    if not decisions:
        return 0
    print("\none decision (Controller.decide, general brain, ORCA on) beside onnxruntime alone")
    print(f"{'N':>4} {'p50 us':>7} {'p99 us':>7} {'quiet p99':>9} {'ort p50':>7} "
          f"{'ort p99':>7} {'p50 ratio':>9} {'load':>5}")
    for d in decisions:
        print(f"{d['n']:>4} {d['decision_us_p50']:>7} {d['decision_us_p99']:>7} "
              f"{d['quietest_round_p99_us']:>9} {d['onnxruntime_us_p50']:>7} "
              f"{d['onnxruntime_us_p99']:>7} {d['ratio_p50']:>8}x {d['load_average_1min']:>5}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
