"""``patternrl replay``: report, draw, play back, re-run or repair an MCAP log.

::

    patternrl replay run.mcap                       per-phase report (table)
    patternrl replay run.mcap --json                the same as JSON
    patternrl replay a.mcap b.mcap                  two runs side by side
    patternrl replay run.mcap --plot traj.png --error-plot err.png --animate run.gif
    patternrl replay run.mcap --brain other.onnx    what would another brain have done?
    patternrl replay run.mcap --play --rate 2 --swarm viewer
    patternrl replay cut.mcap --repair fixed.mcap   a killed writer's log, finished
    patternrl replay run.mcap --to-rosbag2 run_bag  the run as a rosbag2 folder (ROS 2 types)

Every figure comes from the log alone (:mod:`sim_bridge.log.report` says how each
is computed); a log cut short is read up to its last complete chunk and the
report says how much was recovered. Pictures: ``--plot`` the paths (the paper's
Fig. 6 style, :mod:`sim_bridge.log.plots`), ``--error-plot`` formation error and
minimum separation over time with the pattern changes marked, ``--animate`` a
GIF of the run (``.mp4`` when ffmpeg is installed). Play-back
(:mod:`sim_bridge.log.playback`) republishes the recorded wire messages with their
recorded timing; it takes the world's place, so by default it listens on the
swarm's world endpoint, where robots and viewers connect.

Exit codes: 0 done; 1 the log is corrupted (damaged bytes inside it, not merely cut
short: reported, what could be read is still analysed); 2 bad input (missing file,
not an MCAP log, bad option, unusable brain), one line on stderr; 130 play-back
stopped by Ctrl-C. Old logs (``patternrl-wire`` channels) are read like today's.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np

from runtime.errors import InputError
from sim_bridge.log.counterfactual import counterfactual, format_counterfactual
from sim_bridge.log.file import LogError, repair
from sim_bridge.log.reader import LogData, read_log
from sim_bridge.log.report import RunReport, analyse
from sim_bridge.log.report_text import format_compare, format_report, recovery_line

MAX_FRAMES_DEFAULT = 300


# ------------------------------------------------------------------------ pictures


def draw_paths(report: RunReport, data: LogData, out: Path) -> Path:
    """The paths, one panel per phase, drawn by :func:`sim_bridge.log.plots.draw_trajectories`."""
    from sim_bridge.log.plots import draw_trajectories, phase_tracks

    tracks = phase_tracks(report, data)
    title = f"{Path(report.path).name}" + ("" if report.finished else " (log cut short)")
    return draw_trajectories(tracks, out, title=title, world=data.world)


def draw_error_plot(report: RunReport, out: Path) -> Path:
    """Formation error (log scale) and minimum separation over time, pattern changes marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w = report.world
    fig, (ax_e, ax_s) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    cmap = plt.get_cmap("tab10")
    for ph, s in zip(report.phases, report.series, strict=True):
        if len(s.step) == 0:
            continue
        c = cmap(ph.index % 10)
        err = np.where(s.formation_error_m > 0, s.formation_error_m, np.nan)
        ax_e.plot(s.time_s, err, color=c, lw=1.3)
        ax_s.plot(s.time_s, s.min_separation_m, color=c, lw=1.3)
        t0 = ph.start_step * w.dt_s
        for ax in (ax_e, ax_s):
            ax.axvline(t0, color="0.5", lw=0.8, ls="--")
        ax_e.annotate(f"{ph.pattern}" + ("" if ph.formed else " (not formed)"), (t0, 1.0),
                      xycoords=("data", "axes fraction"), xytext=(3, -3),
                      textcoords="offset points", va="top", fontsize=8, color=c)
        if ph.formed:
            ax_e.plot(s.time_s[-1], s.formation_error_m[-1], "o", color=c, ms=4)
    ax_e.axhline(w.formed_tol_m, color="green", lw=0.8, ls=":", label="formed tolerance")
    ax_e.set_yscale("log")
    ax_e.set_ylabel("formation error (m)")
    ax_e.legend(fontsize=7, loc="lower left")
    ax_s.axhline(w.min_separation_m, color="red", lw=0.8, ls=":", label="2R (contact)")
    ax_s.set_ylabel("min separation (m)")
    ax_s.set_xlabel("simulated time (s)")
    ax_s.legend(fontsize=7, loc="lower left")
    for ax in (ax_e, ax_s):
        ax.grid(alpha=0.2)
    fig.suptitle(Path(report.path).name + ("" if report.finished else " (log cut short)"),
                 fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def draw_animation(report: RunReport, data: LogData, out: Path, fps: int = 10,
                   max_frames: int = MAX_FRAMES_DEFAULT) -> tuple[Path, int]:
    """The run as an animation: discs of radius R, the targets in force, short trails.

    GIF through Pillow; ``.mp4`` through ffmpeg when it is installed. Long runs are
    subsampled to at most ``max_frames`` frames. Returns (path, frames).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import animation
    from matplotlib.patches import Circle

    from runtime.decision.formation import centred

    fr, w = data.frames, data.world
    if len(fr.steps) == 0:
        raise InputError("the log has no poses to animate")
    suffix = out.suffix.lower()
    if suffix == ".mp4":
        if not animation.FFMpegWriter.isAvailable():
            raise InputError("--animate .mp4 needs ffmpeg, which is not installed; use .gif")
        writer: Any = animation.FFMpegWriter(fps=fps)
    elif suffix == ".gif":
        writer = animation.PillowWriter(fps=fps)
    else:
        raise InputError(f"--animate {out}: write a .gif (or .mp4 with ffmpeg)")
    stride = max(1, math.ceil(len(fr.steps) / max_frames))
    rows = list(range(0, len(fr.steps), stride))
    if rows[-1] != len(fr.steps) - 1:
        rows.append(len(fr.steps) - 1)
    # each row's phase (a phase's last step is its own, not the next one's first)
    phase_of: dict[int, int] = {}
    for k, ph in enumerate(report.phases):
        for r in fr.rows(ph.start_step, ph.end_step).tolist():
            phase_of.setdefault(r, k)
    valid = fr.xy[~np.isnan(fr.xy).any(axis=-1)]
    lo, hi = valid.min(axis=0) - 3 * w.radius_m, valid.max(axis=0) + 3 * w.radius_m
    mid, half = (lo + hi) / 2, float((hi - lo).max()) / 2
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_aspect("equal")
    ax.grid(alpha=0.15)
    cmap = plt.get_cmap("tab10")
    discs = []
    trails = []
    for rid in fr.ids.tolist():
        col = cmap(rid % 10)
        d = Circle((0.0, 0.0), w.radius_m, facecolor=(*col[:3], 0.5), edgecolor=col, lw=1.2)
        ax.add_patch(d)
        discs.append(d)
        (tr,) = ax.plot([], [], "-", color=col, lw=1.0, alpha=0.6)
        trails.append(tr)
    (tgt,) = ax.plot([], [], "x", color="0.35", ms=5, mew=1.2)
    title = ax.set_title("")
    trail_rows = max(1, round(2.0 / w.dt_s))  # two seconds of trail

    def frame(r: int) -> list[Any]:
        xy = fr.xy[r]
        for c, d in enumerate(discs):
            present = bool(fr.present[r, c])
            d.set_visible(present)
            if present:
                d.center = (float(xy[c, 0]), float(xy[c, 1]))
            seg = fr.xy[max(0, r - trail_rows) : r + 1, c]
            trails[c].set_data(seg[:, 0], seg[:, 1])
        k = phase_of.get(r, -1)
        pts = report.pattern_at(k, int(fr.steps[r]))
        here = xy[fr.present[r]]
        if pts is not None and len(pts) == len(here) and len(pts):
            t = centred(pts) + here.mean(axis=0)
            tgt.set_data(t[:, 0], t[:, 1])
        else:
            tgt.set_data([], [])
        title.set_text(f"step {int(fr.steps[r])}  t = {fr.steps[r] * w.dt_s:.1f} s  "
                       f"{report.phases[k].pattern if k >= 0 else ''}")
        return [*discs, *trails, tgt, title]

    anim = animation.FuncAnimation(fig, frame, frames=rows, blit=False)
    out.parent.mkdir(parents=True, exist_ok=True)
    anim.save(str(out), writer=writer, dpi=80)
    plt.close(fig)
    return out, len(rows)


# --------------------------------------------------------------------------- CLI


def add_arguments(p: argparse.ArgumentParser) -> None:
    from runtime.net.session import add_zenoh_arguments

    p.add_argument("logs", nargs="+", metavar="LOG.mcap",
                   help="one log to report on; two to compare side by side")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    g = p.add_argument_group("pictures")
    g.add_argument("--plot", type=Path, metavar="PNG",
                   help="trajectories, one panel per pattern (the paper's Fig. 6)")
    g.add_argument("--error-plot", type=Path, metavar="PNG",
                   help="formation error and min separation over time, pattern changes marked")
    g.add_argument("--animate", type=Path, metavar="GIF",
                   help="an animation of the run (.gif; .mp4 if ffmpeg is installed)")
    g.add_argument("--fps", type=int, default=10, help="animation frames per second (10)")
    g.add_argument("--max-frames", type=int, default=MAX_FRAMES_DEFAULT,
                   help=f"longer runs are subsampled to this many frames ({MAX_FRAMES_DEFAULT})")
    g = p.add_argument_group("counterfactual")
    g.add_argument("--brain", metavar="REF",
                   help="rule:assign or a .onnx brain: run it on every recorded step as each "
                        "robot would, report how its commands differ from the recorded ones")
    g.add_argument("--safety", choices=("orca", "off"), default="orca",
                   help="the safety filter for --brain, as the robots run it (default orca)")
    g = p.add_argument_group("ROS 2")
    g.add_argument("--to-rosbag2", type=Path, metavar="DIR",
                   help="write the run as a rosbag2 folder (MCAP storage): PoseStamped per "
                        "robot, Twist commands, PoseArray and MarkerArray per step (needs the "
                        "ros2 extra; sim_bridge/ros2/rosbag.py)")
    g = p.add_argument_group("damaged logs")
    g.add_argument("--repair", type=Path, metavar="OUT.mcap",
                   help="write every recovered message into a finished, indexed MCAP file")
    g = p.add_argument_group("play-back (republish on Zenoh, like ros2 bag play)")
    g.add_argument("--play", action="store_true",
                   help="republish the recorded wire messages with their recorded timing, in "
                        "the world's place: listens on the swarm's world endpoint (where robots "
                        "and viewers connect) unless --connect/--listen say otherwise")
    g.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1)")
    g.add_argument("--loop", type=int, nargs="?", const=0, default=1, metavar="N",
                   help="play N times; without N until Ctrl-C (default: once)")
    g.add_argument("--topics", nargs="+", metavar="T",
                   help="only these: key expressions (patternrl/demo/robot/*/pose) or kinds "
                        "(pose cmd status view pattern brain)")
    g.add_argument("--start", type=float, default=0.0, metavar="SECONDS",
                   help="skip the log's first SECONDS")
    g.add_argument("--swarm", default=None,
                   help="republish under this swarm name instead of the recorded one")
    g.add_argument("--wait-subscribers", type=float, default=0.0, metavar="SECONDS",
                   help="wait up to this long for a subscriber before playing (default 0)")
    add_zenoh_arguments(p)


def _err(msg: str) -> int:
    print(f"patternrl replay: error: {msg}", file=sys.stderr)
    return 2


def _check(args: argparse.Namespace) -> None:
    if len(args.logs) > 2:
        raise InputError(f"give one log, or two to compare; got {len(args.logs)}")
    if len(args.logs) == 2:
        extra = [o for o, v in (("--plot", args.plot), ("--error-plot", args.error_plot),
                                ("--animate", args.animate), ("--brain", args.brain),
                                ("--repair", args.repair), ("--play", args.play),
                                ("--to-rosbag2", args.to_rosbag2)) if v]
        if extra:
            raise InputError(f"{', '.join(extra)} take one log; two logs are compared only")
    if not (math.isfinite(args.rate) and args.rate > 0):
        raise InputError(f"--rate must be > 0, got {args.rate}")
    if args.loop < 0:
        raise InputError(f"--loop must be >= 0, got {args.loop}")
    if not (math.isfinite(args.start) and args.start >= 0):
        raise InputError(f"--start must be >= 0 seconds, got {args.start}")
    if args.fps < 1 or args.max_frames < 2:
        raise InputError("--fps must be >= 1 and --max-frames >= 2")
    if args.swarm is not None:
        from runtime.wire.keys import validate_swarm

        try:
            validate_swarm(args.swarm)
        except ValueError as e:
            raise InputError(str(e)) from None
    if args.topics:
        from sim_bridge.log.playback import _topic_filter

        try:
            _topic_filter(args.topics)
        except LogError as e:
            raise InputError(str(e)) from None
    play_only = [o for o, v in (("--rate", args.rate != 1.0), ("--loop", args.loop != 1),
                                ("--topics", args.topics), ("--start", args.start != 0.0),
                                ("--swarm", args.swarm)) if v]
    if play_only and not args.play:
        raise InputError(f"{', '.join(play_only)} need --play")


def run(args: argparse.Namespace) -> int:
    try:
        _check(args)
    except InputError as e:
        return _err(str(e))
    try:
        if len(args.logs) == 2:
            a, b = (analyse(read_log(p)) for p in args.logs)
            print(json.dumps({"a": a.to_dict(), "b": b.to_dict()}) if args.json
                  else format_compare(a, b))
            return 0
        return _run_one(args)
    except (LogError, InputError) as e:
        return _err(str(e))


def _run_one(args: argparse.Namespace) -> int:
    from runtime.brain.brain import BrainError

    path = Path(args.logs[0])
    data = read_log(path)
    report = analyse(data)
    out: dict[str, Any] = report.to_dict()
    lines: list[str] = []
    if args.repair is not None:
        rec = repair(path, args.repair)
        msg = (f"repaired copy {args.repair}: {rec.messages} messages, finished and indexed"
               + ("" if not rec.finished else " (the source was already finished)"))
        out["repair"] = {"path": str(args.repair), "messages": rec.messages}
        lines.append(msg)
    if args.brain is not None:
        try:
            cf = counterfactual(data, args.brain, safety=args.safety == "orca")
        except BrainError as e:
            raise InputError(f"--brain {args.brain}: {e}") from None
        out["counterfactual"] = cf.to_dict()
        lines += ["", format_counterfactual(cf)]
    if args.to_rosbag2 is not None:
        from sim_bridge.ros2.rosbag import write_rosbag2

        counts = write_rosbag2(data, args.to_rosbag2)
        out["rosbag2"] = {"path": str(args.to_rosbag2), "topics": counts}
        lines.append(f"wrote rosbag2 {args.to_rosbag2}: {sum(counts.values())} messages on "
                     f"{len(counts)} topics")
    pictures: dict[str, str] = {}
    if args.plot is not None:
        pictures["plot"] = str(draw_paths(report, data, args.plot))
    if args.error_plot is not None:
        pictures["error_plot"] = str(draw_error_plot(report, args.error_plot))
    if args.animate is not None:
        p, n = draw_animation(report, data, args.animate, args.fps, args.max_frames)
        pictures["animation"] = str(p)
        pictures["animation_frames"] = str(n)
    if pictures:
        out["pictures"] = pictures
        lines.append("")
        lines += [f"wrote {p}" for k, p in pictures.items() if k != "animation_frames"]
    quiet_play = args.play and not (args.json or args.brain or args.repair or pictures)
    if args.json:
        if not args.play:
            print(json.dumps(out))
    elif quiet_play:
        print(f"{path}: {recovery_line(report)}", file=sys.stderr)
    else:
        print(format_report(report))
        if lines:
            print("\n".join(lines))
    if not args.play:
        return 1 if data.recovery.corrupted else 0
    code = _play(args, path)
    if args.json:
        print(json.dumps(out))
    return code


def _play(args: argparse.Namespace, path: Path) -> int:
    from runtime.net.session import ZenohSetupError, open_session_from_args
    from sim_bridge.log.playback import load_recording, play

    recording = load_recording(path, args.topics, args.start, args.swarm)
    if not recording.payloads:
        raise InputError("nothing to play: no recorded wire message matches")
    swarm = args.swarm or (recording.source_swarms[0] if recording.source_swarms else "demo")
    try:
        session = open_session_from_args(args, "world", swarm)
    except ZenohSetupError as e:
        raise InputError(f"{e} (is a world of swarm '{swarm}' running? try --swarm)") from None
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    loops = "until Ctrl-C" if args.loop == 0 else f"{args.loop} time(s)"
    print(f"playing {len(recording.payloads)} messages on {len(recording.keys)} keys "
          f"(swarm {swarm}, rate {args.rate:g}, {loops})", file=sys.stderr, flush=True)
    try:
        res = play(session, recording, args.rate, args.loop, stop, args.wait_subscribers,
                   log=lambda m: print(f"patternrl replay: {m}", file=sys.stderr, flush=True))
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        session.close()  # type: ignore[no-untyped-call]
    verdict = "stopped" if res.interrupted else "done"
    print(f"{verdict}: played {res.messages} messages, {res.loops} full loop(s), "
          f"in {res.seconds:.2f} s", file=sys.stderr, flush=True)
    return 130 if res.interrupted else 0
