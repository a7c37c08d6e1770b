"""The trajectory figure, in the style of the paper's Fig. 6.

One panel per pattern of a run: every robot's path drawn from a light to a
saturated tint of its colour (so the direction of travel reads at a glance),
its final position ringed with a disc of radius R, its start a small light dot,
and the target slots (the pattern placed on the team's final centroid) as grey
crosses. The panel title says whether the pattern formed, in how many steps,
and the lower bound.

Input is a list of :class:`PhaseTrack`, built from a log by
:func:`phase_tracks` from the report's phases (so ``patternrl launch`` and a
replay draw the same picture from the same MCAP, with the same figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from runtime.decision.formation import centred
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from sim_bridge.log.reader import LogData
from sim_bridge.log.report import RunReport


@dataclass
class PhaseTrack:
    """The paths of one pattern's phase.

    ``track`` is (T, n, 2) metres, one row per step from the phase's first pose to
    its last, one column per robot of ``ids`` (NaN where that robot was absent).
    ``targets`` is (m, 2): the pattern placed on the final centroid.
    """

    pattern: str
    formed: bool
    steps: int
    lower_bound_steps: int
    ids: list[int]
    track: Array
    targets: Array


def phase_tracks(report: RunReport, data: LogData) -> list[PhaseTrack]:
    """One :class:`PhaseTrack` per phase of ``report`` with recorded poses (``data``'s)."""
    fr = data.frames
    tracks = []
    for k, ph in enumerate(report.phases):
        rows = fr.rows(ph.start_step, ph.end_step)
        if len(rows) == 0:
            continue
        pts = report.pattern_at(k, ph.end_step)
        pts = pts if pts is not None else np.zeros((0, 2))
        cols = np.nonzero(fr.present[rows].any(axis=0))[0]
        track = fr.xy[rows][:, cols]
        final = track[-1][~np.isnan(track[-1]).any(axis=1)]
        targets = (centred(pts) + final.mean(axis=0)) if len(pts) == len(final) and len(
            pts) else np.empty((0, 2))
        tracks.append(PhaseTrack(ph.pattern, ph.formed, ph.steps, ph.lower_bound_steps or 0,
                                 [int(fr.ids[c]) for c in cols], track, targets))
    return tracks


def _tint(rgb: tuple[float, float, float], f: float) -> tuple[float, float, float]:
    """``rgb`` mixed with white: f = 0 is a light tint, f = 1 the full colour."""
    light = 0.18 + 0.82 * f
    return (1 - light + light * rgb[0], 1 - light + light * rgb[1], 1 - light + light * rgb[2])


def draw_trajectories(
    tracks: list[PhaseTrack],
    out: str | Path,
    title: str | None = None,
    world: WorldConfig = DEFAULT_WORLD,
) -> Path:
    """Draw one panel per phase into a PNG at ``out``; returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Circle

    n = max(len(tracks), 1)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.4 * rows), squeeze=False)
    cmap = plt.get_cmap("tab10")
    r = world.radius_m
    for ax in axes.flat[len(tracks):]:
        ax.axis("off")
    for ax, ph in zip(axes.flat, tracks, strict=False):
        T = len(ph.track)
        for k, rid in enumerate(ph.ids):
            xy = ph.track[:, k]
            ok = np.asarray(~np.isnan(xy).any(axis=1), dtype=bool)
            p = xy[ok]
            if len(p) == 0:
                continue
            c4 = cmap(rid % 10)
            rgb = (float(c4[0]), float(c4[1]), float(c4[2]))
            if len(p) > 1:
                segs = np.stack([p[:-1], p[1:]], axis=1)
                frac = np.linspace(0.0, 1.0, len(segs))
                lc = LineCollection(list(segs), colors=[_tint(rgb, float(f)) for f in frac],
                                    linewidths=1.6, capstyle="round", zorder=2)
                ax.add_collection(lc)
            ax.plot(*p[0], "o", ms=3, color=_tint(rgb, 0.0), zorder=3)
            present_at_end = bool(ok[-1]) if T else False
            ax.add_patch(Circle(tuple(p[-1]), r, fill=present_at_end, facecolor=(*rgb, 0.25),
                                edgecolor=rgb, linewidth=1.4, linestyle="-" if present_at_end
                                else ":", zorder=4))
        if len(ph.targets):
            ax.plot(ph.targets[:, 0], ph.targets[:, 1], "x", ms=5, mew=1.2, color="0.35",
                    zorder=5, label="targets")
        pts = ph.track[~np.isnan(ph.track).any(axis=-1)]
        if len(ph.targets):
            pts = np.vstack([pts, ph.targets])
        if len(pts):
            lo, hi = pts.min(axis=0) - 3 * r, pts.max(axis=0) + 3 * r
            mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 4 * r)
            ax.set_xlim(mid[0] - half, mid[0] + half)
            ax.set_ylim(mid[1] - half, mid[1] + half)
        ax.set_aspect("equal")
        verdict = f"formed in {ph.steps} steps" if ph.formed else f"not formed ({ph.steps} steps)"
        ax.set_title(f"{ph.pattern}: {verdict}\nlower bound {ph.lower_bound_steps} steps",
                     fontsize=10)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
        ax.grid(alpha=0.15)
    if title:
        fig.suptitle(title, fontsize=11, y=1.0)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.97) if title else None)
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return path


def draw_log(log: str | Path, out: str | Path | None = None, **kw: Any) -> Path:
    """Read an MCAP log and draw its trajectory figure (default: ``<log stem>.png`` beside it)."""
    from sim_bridge.log.reader import read_log
    from sim_bridge.log.report import analyse

    log = Path(log)
    data = read_log(log)
    tracks = phase_tracks(analyse(data), data)
    kw.setdefault("world", data.world)
    return draw_trajectories(tracks, out if out is not None else log.with_suffix(".png"), **kw)
