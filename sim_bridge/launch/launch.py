"""``patternrl launch``: the demo. A world and one robot process per robot, on loopback.

What it does:

1. picks the brains: ``--brains auto`` (default) runs the general brain
   ``exports/general.onnx`` when it is there: one brain for every pattern and
   team size, so no swap at pattern changes, and robots that leave or join are
   followed (the world resizes the pattern). Without it (or with
   ``--brain-kind paper``), ``exports/`` when it has a brain for every pattern of
   ``--patterns`` (of the ``--brain-kind`` preferred), else ``rule:assign``.
   ``--brains DIR`` (e.g. ``--brains exports --brain-kind paper``: the paper
   brains, one per pattern), ``--brains FILE.onnx`` or ``--brains rule:assign``
   choose explicitly. The first line and the table say which brain ran each pattern;
2. makes the run's keys (a swarm authority and one identity per member, in a
   private temporary directory removed at the end: :mod:`sim_bridge.launch.launch_keys`;
   ``--tls-dir DIR`` uses keys of ``patternrl keys create``, ``--insecure`` runs
   open TCP) and wires the run by ``--topology``: ``peer`` (up to 20 robots,
   the default there) opens the world's Zenoh session as a peer listening with
   mutual TLS on a free loopback port, and the robots, peers too, connect to it
   and then to each other (a link per pair: one hop, fastest in lockstep);
   ``router`` (the default above 20 robots) starts the swarm's Zenoh router
   (``patternrl router``, :mod:`sim_bridge.launch.router`, the ``router`` identity) on
   that port and makes the world and every robot its clients (a link per
   process: 101 links for 100 robots against 7,819 for the mesh). It starts
   ``--robots`` robot processes (``patternrl robot``, each with its own
   identity), each with the first pattern's brain; at every pattern change the
   world swaps in the next pattern's brain where it differs (paper brains);
3. runs the world in this process (:class:`sim_bridge.world.sim_world.SimWorld`), recording the
   MCAP log (``--record``, refused if it exists unless ``--force``; without it
   ``runs/demo.mcap``, the demo's own log, overwritten each run), serving it live
   to Foxglove with ``--foxglove`` (:mod:`sim_bridge.live.foxglove_live`) and showing a
   progress line (pattern, step, formation error, robots alive) when stdout is a
   terminal; the robots' own log lines go to ``<log stem>.robots.log``;
4. stops every robot by its PID (SIGTERM, then SIGKILL after a grace period),
   finishes the log, prints a table per pattern (steps to form and its lower
   bound, travel and its lower bound, collisions, min separation, deadline
   misses; with ``--hold-steps N`` a ``held`` column, the steps of the N watched after
   the first passage on which the team was still formed) and draws the trajectory figure
   ``<log stem>.png`` beside the log.

Ctrl-C (or SIGTERM) at any point: the world stops after its current step, every
robot is stopped by PID, the log is finished and the table shows what was done.
However the launcher ends, even killed with SIGKILL, its lifeline
(:mod:`sim_bridge.launch.lifeline`) stops every robot and the router within
seconds and removes the run's keys; the robots also run with
``--exit-after-silence-s``.

Exit codes: 0 only when every pattern formed (and, with ``--hold-steps``, held: formed on
90 % of the steps watched, :data:`runtime.world_config.HOLD_SHARE`); 1 otherwise (or a robot
failed to start); 2 on bad input; 130 when interrupted.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path
from types import FrameType
from typing import IO, Any

from runtime import heap
from runtime.brain.signing import run_operator_key
from runtime.conditions import Conditions
from runtime.decision.agreement import DEFAULT_AGREE
from runtime.decision.patterns import PatternError, make_pattern, pattern_label
from runtime.decision.safety import pattern_guard_note
from runtime.errors import InputError
from runtime.net.session import (
    add_zenoh_arguments,
    config_from_args,
    open_config,
    world_port,
)
from runtime.robot.cli import RobotConfig
from sim_bridge.launch.launch_keys import RunKeys, run_keys
from sim_bridge.launch.lifeline import Lifeline
from sim_bridge.launch.router import RouterProcess
from sim_bridge.live.foxglove_live import FoxgloveLive, parse_address
from sim_bridge.log.recorder import Recorder, check_output
from sim_bridge.world.brain_choice import BrainChoice, pick_brains
from sim_bridge.world.run_results import PhaseResult, Progress, RunResult, result_dict
from sim_bridge.world.sim import WORLD_SWITCH_INTERVAL_S, add_world_arguments, start_live
from sim_bridge.world.sim import config_from_args as world_config_from_args
from sim_bridge.world.sim_world import SimWorld
from sim_bridge.world.world_log import Say

STOP_GRACE_S = 3.0
TOPOLOGIES = ("auto", "router", "peer")
PEER_MAX_ROBOTS = 20
"""``--topology auto``: the peer mesh up to this many robots, a router above (README "Scale")."""
ROBOT_SILENCE_EXIT_S = 20.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--swarm", default=None, help="swarm name (default launch-<pid>)")
    add_world_arguments(p, "the MCAP log (default runs/demo.mcap); the figure and the robots' "
                           "log go beside it")
    p.add_argument("--brains", default="auto",
                   help="auto (exports/general.onnx for every pattern; without it exports/ if "
                        "it has a brain for every pattern, else rule:assign), a directory of "
                        "brains (with --brain-kind paper: the paper brains), a brain file "
                        "(.onnx), or rule:assign")
    p.add_argument("--safety", choices=("orca", "off"), default="orca",
                   help="the robots' safety filter (default orca)")
    p.add_argument("--start-timeout-s", type=float, default=60.0,
                   help="give up if the robots are not all alive by then (default 60)")
    p.add_argument("--zenoh-port", type=int, default=None,
                   help="the world's loopback port (default: a free one), e.g. to watch the run")
    p.add_argument("--topology", choices=TOPOLOGIES, default="auto",
                   help=f"router: one Zenoh router process, the world and every robot its "
                        f"clients, a link each; peer: the world listens and every process is a "
                        f"peer, linked to every other (a link per pair, one hop less); auto "
                        f"(default): peer up to {PEER_MAX_ROBOTS} robots, router above")
    p.add_argument("--no-plot", action="store_true", help="skip the trajectory figure")
    p.add_argument("--no-record", action="store_true",
                   help="run without the MCAP log (and so without its figure and replay); the "
                        "robots' log and the run's keys still go beside the --record path")
    p.add_argument("-v", "--verbose", action="store_true", help="every world message")
    add_zenoh_arguments(p)  # the world's session; --tls-dir: keys of 'patternrl keys create'


# ------------------------------------------------------------------------ robots


def free_port(preferred: int = 0) -> int:
    """A TCP port free on loopback right now: ``preferred`` if it is free, else any."""
    for port in (preferred, 0) if preferred else (0,):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(s.getsockname()[1])
    raise OSError("no free TCP port on 127.0.0.1")


def start_timeout_s(args: argparse.Namespace) -> float:
    """How long the world waits for its robots (``--start-timeout-s``)."""
    return float(getattr(args, "start_timeout_s", 60.0))


def topology_of(args: argparse.Namespace) -> str:
    """``router`` or ``peer``: ``--topology``, with ``auto`` decided by ``--robots``."""
    topology = getattr(args, "topology", "peer")
    if topology == "auto":
        return "router" if int(args.robots) > PEER_MAX_ROBOTS else "peer"
    return str(topology)


class Robots:
    """The robot processes: started together, stopped by PID, never left behind."""

    def __init__(self) -> None:
        self.procs: dict[int, subprocess.Popen[bytes]] = {}
        self._log: IO[bytes] | None = None

    def start(self, n: int, swarm: str, port: int, brain: str, args: argparse.Namespace,
              log_path: Path, keys_dir: Path | None = None, group: int | None = None) -> None:
        """``keys_dir``: the swarm's keys (robot i speaks as keys_dir/robot-i); None: open TCP.
        ``group``: the process group of the launcher's lifeline; None: a session each."""
        self._log = open(log_path, "ab")  # closed in stop()
        for rid in range(n):
            cmd = [sys.executable, "-m", "patternrl.cli", "robot", "--swarm", swarm,
                   "--id", str(rid), "--brain", brain, "--mode", args.mode,
                   "--zenoh-port", str(port), "--safety", args.safety,
                   "--exit-after-silence-s", str(ROBOT_SILENCE_EXIT_S),
                   # the world is first heard once every robot is up: wait that long
                   "--world-timeout-s", f"{start_timeout_s(args) + ROBOT_SILENCE_EXIT_S:g}"]
            if topology_of(args) == "router":  # the router's port is `port`
                cmd += ["--zenoh-mode", "client"]
            cmd += ["--insecure"] if keys_dir is None else ["--tls-dir", str(keys_dir)]
            for key in getattr(args, "trust", []):  # the run's operator key
                cmd += ["--trust", key]
            cond = getattr(args, "conditions", "perfect")
            if cond != "perfect":  # each robot senses under them, seeded apart
                cmd += ["--conditions", cond, "--sensing-seed", str(args.seed)]
            if getattr(args, "estimator", False):
                cmd += ["--estimator"]
            if cond != "perfect":  # what the robots tell each other (the same default)
                cmd += ["--agree", getattr(args, "agree", DEFAULT_AGREE)]
            if getattr(args, "ros2", False):  # the robot drives ROS 2 base robot_<id>
                cmd += ["--ros2", f"robot_{rid}"]
            elif args.mode == "realtime":
                cmd += ["--rate-hz", str(args.rate_hz)]
            else:  # a robot waits for every pose of a step about as long as the world waits
                # for its command: on a busy machine it still decides on complete steps,
                # so a lockstep run stays reproducible
                wait_s = 0.8 * args.step_deadline_ms / 1000.0
                cmd += ["--lockstep-deadline-s", f"{wait_s:g}"]
                if wait_s >= RobotConfig.watchdog_s:  # the watchdog must outwait the deadline
                    cmd += ["--watchdog-s", f"{2.0 * wait_s:g}"]
            # Not the launcher's process group: a Ctrl-C reaches the launcher only, which
            # then stops each robot by PID after finishing the log.
            group_kw: dict[str, Any] = ({"start_new_session": True} if group is None
                                        else {"process_group": group})
            self.procs[rid] = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=self._log, stderr=self._log,
                cwd=os.getcwd(), **group_kw)

    def failed(self) -> list[tuple[int, int]]:
        """(robot, exit code) of robots that exited with an error."""
        return [(r, p.returncode) for r, p in self.procs.items()
                if p.poll() is not None and p.returncode not in (0, -signal.SIGTERM)]

    def stop(self, grace_s: float = STOP_GRACE_S) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                try:
                    p.send_signal(signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace_s
        for p in self.procs.values():
            try:
                p.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        if self._log is not None:
            self._log.close()
            self._log = None


# ------------------------------------------------------------------------ output


class ProgressLine:
    """One line rewritten in place on a terminal; silent otherwise."""

    def __init__(self, stream: IO[str], period_s: float = 0.1) -> None:
        self.stream = stream
        self.tty = stream.isatty()
        self.period_s = period_s
        self._last = 0.0
        self._shown = False

    def update(self, p: Progress) -> None:
        if not self.tty:
            return
        now = time.monotonic()
        if now - self._last < self.period_s:
            return
        self._last = now
        line = (f"[{p.phase + 1}/{p.n_phases}] {p.pattern:<10} step {p.phase_step:>4} "
                f"(total {p.step:>5})  error {p.formation_error_m:7.3f} m  "
                f"robots alive {p.n_live:>3}  deadline misses {p.deadline_misses}")
        self.stream.write("\r\x1b[2K" + line)
        self.stream.flush()
        self._shown = True

    def clear(self) -> None:
        if self.tty and self._shown:
            self.stream.write("\r\x1b[2K")
            self.stream.flush()
            self._shown = False


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if b > 0 else "-"


def format_table(phases: list[PhaseResult]) -> str:
    """The per-pattern table of the demo."""
    hold = any(p.hold_steps for p in phases)  # the held column, with --hold-steps only
    head = ("pattern", "brain", "formed", *(("held",) if hold else ()), "steps", "bound",
            "ratio", "travel m", "bound m", "ratio", "collisions", "min sep m",
            "deadline misses")
    rows = []
    for p in phases:
        held = (f"{'yes' if p.held else 'NO'} {p.held_steps}/{p.hold_steps}" if p.formed
                else "-")
        rows.append((p.pattern, p.brain, "yes" if p.formed else "NO",
                     *((held,) if hold else ()), str(p.steps),
                     str(p.lower_bound_steps), _ratio(p.steps, p.lower_bound_steps),
                     f"{p.travel_m:.2f}", f"{p.lower_bound_travel_m:.2f}",
                     _ratio(p.travel_m, p.lower_bound_travel_m), str(p.collisions),
                     f"{p.min_separation_m:.3f}", str(p.deadline_misses)))
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
              for i, h in enumerate(head)]
    left = {0, 1, 2, 3} if hold else {0, 1, 2}

    def fmt(cells: tuple[str, ...]) -> str:
        return "  ".join(c.ljust(w) if i in left else c.rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True)))

    lines = [fmt(head), fmt(tuple("-" * w for w in widths))]
    lines += [fmt(r) for r in rows]
    return "\n".join(lines)


def draw_figure(record: Path, n_robots: int, patterns: list[str], say: Say) -> Path | None:
    """The trajectory figure beside the log; None (and a line) when it cannot be drawn."""
    from sim_bridge.log.plots import draw_log

    try:
        names = ", ".join(map(pattern_label, patterns))
        return draw_log(record, title=f"{n_robots} robots: {names}")
    except Exception as e:  # a figure is a by-product: never lose the table for it
        say(f"could not draw the figure: {e}", False)
        return None


def print_report(res: RunResult, as_json: bool, brains: dict[str, BrainChoice],
                 record: Path | None, robots_log: Path, png: Path | None, failed_start: bool,
                 out: IO[str]) -> None:
    """The table and the verdict line, or the one JSON line (``record`` None: no log)."""
    if as_json:
        d: dict[str, Any] = result_dict(res)
        d.update(figure=str(png) if png else None, robots_log=str(robots_log),
                 brains={k: asdict(v) for k, v in brains.items()})
        print(json.dumps(d), file=out)
        return
    if res.phases:
        print(format_table(res.phases), file=out)
    tail = ((f"log {record}" if record is not None else "no log")
            + (f", figure {png}" if png else "") + f", robots {robots_log}")
    done = "every pattern formed" if res.all_formed else "NOT every pattern formed"
    if res.all_formed and res.hold_steps:
        done = "every pattern formed and held" if res.all_held else "NOT every pattern held"
    verdict = {"done": done, "interrupted": "interrupted", "no robots": "no robots"}[res.outcome]
    if failed_start:
        verdict = "robots failed to start"
    print(f"{verdict}: {res.steps} steps in {res.wall_s:.1f} s; {tail}", file=out)


# ------------------------------------------------------------------------ run


def guard_notes(patterns: list[str], robots: int, conditions: Conditions) -> list[str]:
    """One line per note of :func:`runtime.decision.safety.pattern_guard_note`, naming the
    patterns it is about (a pattern the robots cannot fit is theirs to report)."""
    about: dict[str, list[str]] = {}
    for p in dict.fromkeys(patterns):
        try:
            note = pattern_guard_note(make_pattern(p, robots), conditions)
        except PatternError:
            continue
        if note is not None:
            about.setdefault(note, []).append(pattern_label(p))
    return [f"note: {', '.join(names)}: {note}" for note, names in about.items()]


def run(args: argparse.Namespace) -> int:
    swarm = args.swarm or f"launch-{os.getpid()}"
    args.swarm = swarm
    args.wait_robots_s = args.start_timeout_s
    patterns = [p.strip() for p in str(args.patterns).split(",") if p.strip()]
    try:
        brains, brains_line = pick_brains(args.brains, patterns, args.robots, args.brain_kind)
        cfg = world_config_from_args(args, brains)
        notes = [] if args.safety == "off" else guard_notes(cfg.patterns, args.robots,
                                                            cfg.conditions)
        if args.record is not None and not args.no_record:  # refused if it exists (not the demo's)
            check_output(args.record, args.force)
        if args.foxglove is not None:
            parse_address(args.foxglove)
    except InputError as e:
        print(f"patternrl launch: error: {e}", file=sys.stderr)
        return 2
    record: Path = args.record or Path("runs") / "demo.mcap"
    try:
        check_output(record, True)
    except InputError as e:
        print(f"patternrl launch: error: {e}", file=sys.stderr)
        return 2
    record.parent.mkdir(parents=True, exist_ok=True)
    robots_log = record.with_suffix(".robots.log")
    try:  # a per-run operator key the robots trust: sign a brain with it to swap it in
        args.trust = [f"{run_operator_key(record.with_suffix('.keys'))}.pub"]
    except InputError as e:
        print(f"patternrl launch: error: {e}", file=sys.stderr)
        return 2
    # the swarm's own port when free, so `patternrl swap --swarm S` finds the run unaided
    port = args.zenoh_port or free_port(world_port(swarm))
    out, err = sys.stdout, sys.stderr
    progress = ProgressLine(out)
    verbose = bool(args.verbose)

    def say(msg: str, detail: bool = False) -> None:
        if detail and not verbose:
            return
        progress.clear()
        print(msg, file=err, flush=True)

    def launch(lifeline: Lifeline) -> int:
        try:
            creds: RunKeys = run_keys(args, swarm, lifeline.make_dir)
        except InputError as e:
            print(f"patternrl launch: error: {e}", file=sys.stderr)
            return 2
        router: RouterProcess | None = None
        try:
            args.zenoh_port = port
            wargs = creds.world_args(args)
            if topology_of(args) == "router":
                if args.connect or args.listen or args.zenoh_config or args.zenoh_mode:
                    raise InputError("-m/-e/-l/-c set up the world's own session: they go with "
                                     f"--topology peer (auto: router above {PEER_MAX_ROBOTS} "
                                     "robots)")
                router = RouterProcess(swarm, port, creds.dir, robots_log,
                                       group=lifeline.group)
                router.start()
                wargs.zenoh_mode, wargs.connect, wargs.listen = "client", [router.endpoint], []
            session = open_config(config_from_args(wargs, "world", swarm))
        except InputError as e:  # ZenohSetupError too
            if router is not None:
                router.stop()
            creds.close()
            print(f"patternrl launch: error: {e}", file=sys.stderr)
            return 2
        live: FoxgloveLive | None = None
        try:
            live = start_live(args.foxglove, say)
            # writing off the world's path; the live view alone without a file
            rec: Recorder | None = (Recorder(None if args.no_record else record, live=live,
                                             threaded=True)
                                    if live is not None or not args.no_record else None)
        except InputError as e:
            if live is not None:
                live.close()
            session.close()  # type: ignore[no-untyped-call]
            if router is not None:
                router.stop()
            creds.close()
            print(f"patternrl launch: error: {e}", file=sys.stderr)
            return 2
        sys.setswitchinterval(WORLD_SWITCH_INTERVAL_S)
        world = SimWorld(cfg, session, rec, on_progress=progress.update, log=say)
        heap.settle()
        robots = Robots()
        interrupted = threading.Event()

        def on_signal(signum: int, _frame: FrameType | None) -> None:
            interrupted.set()
            world.stop()

        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        watcher_stop = threading.Event()

        def watch() -> None:  # a robot that dies at start would leave the world waiting
            while not watcher_stop.wait(0.2):
                bad = robots.failed()
                if bad and world.step == 0:
                    say("robot(s) failed to start: "
                        + ", ".join(f"{r} (exit {c})" for r, c in bad) + f"; see {robots_log}")
                    world.stop()
                    return

        first = brains[patterns[0]].ref
        hub = "router" if router is not None else "world, peers"
        say(f"{brains_line}; {args.robots} robots, {args.mode}, swarm {swarm} "
            f"(zenoh {hub} {creds.scheme}/127.0.0.1:{port}{creds.note}), "
            + ("no log" if args.no_record else f"log {record}"))
        say(f"reach this swarm (patternrl record, swap) with: {creds.tool_flags(swarm, port)}")
        for note in notes:
            say(note)
        res: RunResult | None = None
        try:
            world.open()  # listening before the robots come: their first status says their brain
            robots.start(args.robots, swarm, port, first, args, robots_log, creds.dir,
                         lifeline.group)
            watcher = threading.Thread(target=watch, name="robot-watch", daemon=True)
            watcher.start()
            res = world.run()
        finally:
            watcher_stop.set()
            progress.clear()
            robots.stop()
            if rec is not None:
                rec.close()
            if live is not None:
                live.close()
            session.close()  # type: ignore[no-untyped-call]
            if router is not None:  # last: the world's final messages go through it
                router.stop()
            creds.close()
            for s, h in old.items():
                signal.signal(s, h)
        assert res is not None  # world.run() returned (it raises only on a bug)
        png = (None if args.no_plot or args.no_record or not res.phases
               else draw_figure(record, args.robots, patterns, say))
        failed_start = bool(robots.failed()) and res.steps == 0
        print_report(res, args.json, brains, None if args.no_record else record, robots_log,
                     png, failed_start, out)
        if failed_start:
            return 1
        if interrupted.is_set() or res.outcome == "interrupted":
            return 130
        return 0 if res.all_held else 1

    # every child joins the lifeline's process group: whatever way this process ends,
    # they end with it, and the keys made for the run go
    with Lifeline() as lifeline:
        return launch(lifeline)
