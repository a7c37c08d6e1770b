"""What happened in a run, recomputed from its log: :func:`analyse` -> :class:`RunReport`.

Nothing here trusts the world's own verdicts: every figure of the report is
recomputed from the recorded poses (:class:`sim_bridge.log.reader.LogData`), per
phase (:mod:`sim_bridge.log.phases`), with the formation geometry the world and
the robots use (:mod:`runtime.decision.formation`). The world's ``phase_end`` figures are
kept beside them only to be compared (``world`` and ``mismatches`` in each phase).

============================  ===============================================
figure                        computed from the recorded poses as
============================  ===============================================
steps (formed)                first step ``s >= start`` at which every robot
                              is within the pattern's ``formed_tol_m`` of its
                              slot under the centred optimal assignment
                              (the first passage); steps = s - start. Not
                              formed: the phase's recorded length
held steps                    when the world watched the formation after the
                              first passage (``hold_steps`` > 0 on its
                              ``phase_end``): the steps after it, up to the
                              phase's end, at which the team was formed
lower bounds                  :func:`runtime.decision.formation.lower_bounds` of the
                              poses at the phase's first step
travel per robot              sum of ||p(s+1) - p(s)|| over the phase's steps
                              where the robot is present at both
collisions                    robot pairs whose discs overlap at any time of
                              a step (swept test, straight-line motion), each
                              counted when it starts overlapping
min separation                smallest centre distance after any step
final error                   formation error at the phase's last step (the
                              first passage, for a formed phase)
============================  ===============================================

Travel and final error stop at the first passage; collisions, separation, commands and the
step series run to the phase's end, the hold window included.

Estimation error (when the log holds views: robots under imperfect sensing): each peer's
perceived position against the world's pose of that peer at the view's step, per robot and
overall (mean, p95, max), :mod:`sim_bridge.log.views`.

From the log's records, not the poses: deadline misses, brain swaps, robots
joined and lost (:mod:`sim_bridge.log.phases`), the brains that decided (the
``brain_id`` of every recorded command) and the safety filter's interventions
(``safety_changed`` of the commands).

Known difference: the world counts the travel of a robot during the step in
which it leaves, but the log has no pose of it after that step, so that last
step of a leaving robot is not in the recomputed travel.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from runtime.decision.formation import (
    assign_slots_batch,
    collision_pairs,
    lower_bounds,
    min_separation,
    slot_distances,
)
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import WorldConfig, holds
from sim_bridge.log.file import Recovery
from sim_bridge.log.phases import PhaseLog, PhasePattern, phases_of
from sim_bridge.log.reader import LogData, as_int, read_log
from sim_bridge.log.views import Estimation, estimation_error

_BATCH_ROWS: Final = 128
"""Steps measured in one batch: keeps the (rows, n, n, 2) temporaries of the geometry small
(in cache: a batch of 128 is faster than one of 400)."""


@dataclass
class PhaseReport:
    """One pattern phase, recomputed from the log (see the module docstring)."""

    index: int
    pattern: str
    n_robots: int
    start_step: int
    end_step: int
    complete: bool
    """The phase ended in the log (formed, gave up, or the next phase began)."""
    formed: bool
    steps: int
    lower_bound_steps: int | None
    lower_bound_travel_m: float | None
    travel_m: float
    travel_per_robot_m: dict[int, float]
    collisions: int
    min_separation_m: float | None
    final_error_m: float | None
    deadline_misses: int
    commands_missing: int
    stale_commands: int
    """Deadline misses on which the robot moved on an older command (the world's events)."""
    command_ages: dict[int, int]
    """Age in steps -> stale commands applied that old (age 0, the fresh ones, left out)."""
    guard_scaled: int
    """Commands the world's guard slowed down or stopped."""
    safety_interventions: int
    brains: dict[str, int]
    """brain id -> commands it decided in this phase"""
    swaps_accepted: int
    """Robots that took a new brain (``brain_swap`` accepted, old brain != new brain)."""
    swaps_refused: int
    swaps_unchanged: int
    """Swaps answered "already running": the robot had that brain."""
    swapped_to: list[str]
    joined: list[int]
    lost: list[int]
    world: dict[str, Any] | None
    """The world's own ``phase_end`` figures, for comparison."""
    mismatches: list[str]
    """Figures where the recomputation and the world's ``phase_end`` disagree."""
    hold_steps: int = 0
    """Steps the world watched after the first passage (its ``phase_end``; 0: none, or a
    log from before the world watched)."""
    held_steps: int | None = None
    """Of those, the steps at which the team was still formed; None without a hold window."""
    held: bool | None = None
    """Formed and held (:func:`runtime.world_config.holds`); None without a window."""

    @property
    def steps_ratio(self) -> float | None:
        lb = self.lower_bound_steps
        return self.steps / lb if lb else None

    @property
    def travel_ratio(self) -> float | None:
        lb = self.lower_bound_travel_m
        return self.travel_m / lb if lb else None


@dataclass
class StepSeries:
    """One phase, per recorded step from its start to its end: (S,) arrays for the error plot.

    A phase's last step is also the next phase's first (measured against each one's
    pattern), so it appears in both.
    """

    phase: int
    step: IntArray
    time_s: Array
    formation_error_m: Array
    min_separation_m: Array


@dataclass
class RunReport:
    """A whole log: how much was read, the run's facts and every phase."""

    path: str
    recovery: Recovery
    finished: bool
    messages: int
    steps_recorded: int
    first_step: int | None
    last_step: int | None
    wall_s: float
    robots: list[int]
    mode: str
    outcome: str
    malformed: int
    topics: dict[str, int]
    phases: list[PhaseReport]
    series: list[StepSeries]
    world: WorldConfig
    phase_patterns: list[list[PhasePattern]] = field(default_factory=list)
    skipped: dict[str, int] = field(default_factory=dict)
    """what the reader skipped as no part of the run -> how many"""
    """Each phase's patterns (its first and its resizes), for pictures; not in the JSON."""
    timing: dict[str, float] = field(default_factory=dict)
    """Seconds spent on the phases: ``phases_s`` in all, ``lower_bounds_s`` of it (not in JSON)."""
    estimation: Estimation | None = None
    """The robots' estimation error, from the log's views; None without views."""

    def pattern_at(self, phase: int, step: int) -> Array | None:
        """The pattern in force in ``phase`` at ``step``."""
        if not 0 <= phase < len(self.phase_patterns) or not self.phase_patterns[phase]:
            return None
        pats = self.phase_patterns[phase]
        k = max(0, int(np.searchsorted([p.step for p in pats], step, side="right")) - 1)
        return pats[k].points

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (``--json``)."""
        phases = []
        for ph in self.phases:
            d = asdict(ph)
            d["travel_per_robot_m"] = {str(k): v for k, v in ph.travel_per_robot_m.items()}
            d["steps_ratio"] = _r(ph.steps_ratio, 4)
            d["travel_ratio"] = _r(ph.travel_ratio, 4)
            if d["world"] is not None:
                d["world"] = {k: v for k, v in d["world"].items()
                              if k not in ("kind", "time_s", "brain_ids")}
            phases.append(d)
        rec = asdict(self.recovery)
        return {
            "path": self.path, "finished": self.finished, "messages": self.messages,
            "recovery": rec, "steps_recorded": self.steps_recorded,
            "first_step": self.first_step, "last_step": self.last_step,
            "wall_s": round(self.wall_s, 3), "robots": self.robots, "mode": self.mode,
            "outcome": self.outcome, "malformed": self.malformed, "topics": self.topics,
            "skipped": self.skipped, "world": asdict(self.world), "phases": phases,
            "estimation": None if self.estimation is None else self.estimation.to_dict(),
        }


def _r(x: float | None, nd: int = 6) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def _geometry(xy: Array, present: BoolArray, pat_idx: IntArray, ph: PhaseLog
              ) -> tuple[Array, Array, Array]:
    """(formation error, farthest robot from its slot, min separation) per row, metres.

    ``xy`` (T, m, 2) with NaN for absent robots; rows are measured in batches of
    the same robots present and the same pattern in force. Error and distance are
    NaN where the team and the pattern differ in size; the separation is inf where
    fewer than two robots are present.
    """
    T = len(xy)
    err, far, sep = np.full(T, np.nan), np.full(T, np.nan), np.full(T, np.inf)
    change = (pat_idx[1:] != pat_idx[:-1]) | (present[1:] != present[:-1]).any(axis=1)
    bounds = [0, *(np.nonzero(change)[0] + 1).tolist(), T]
    batches = [(k, min(k + _BATCH_ROWS, b)) for a, b in itertools.pairwise(bounds)
               for k in range(a, b, _BATCH_ROWS)]
    for k, j in batches:
        cols = np.nonzero(present[k])[0]
        P = xy[k:j][:, cols]
        if len(cols) >= 2:
            sep[k:j] = min_separation(P)
        C = ph.patterns[int(pat_idx[k])].points
        if len(cols) == len(C) and len(C) >= 1:
            d = slot_distances(P, C, assign_slots_batch(P, C))
            err[k:j] = np.sqrt(np.mean(d * d, axis=-1))  # formation error: RMS slot distance
            far[k:j] = d.max(axis=-1)
    return err, far, sep


def _collisions(xy: Array, ids: IntArray, sep: Array, world: WorldConfig) -> int:
    """Pairs that start overlapping during a step, over consecutive rows of xy (T, m, 2).

    The swept test (:func:`runtime.decision.formation.collision_pairs`) runs only on steps
    where two discs could meet: the closest pair at either end within 2R plus the
    largest move of that step (twice, for two robots closing in).
    """
    if len(xy) < 2:
        return 0
    hop = np.linalg.norm(np.diff(xy, axis=0), axis=-1)
    reach = 2.0 * np.nanmax(np.where(np.isnan(hop), 0.0, hop), axis=1)
    near = np.minimum(sep[:-1], sep[1:]) < world.min_separation_m + reach
    count = 0
    prev: set[tuple[int, int]] = set()
    prev_t = -2
    for t in np.nonzero(near)[0].tolist():
        pairs = {(int(ids[i]), int(ids[j])) for i, j in collision_pairs(xy[t], xy[t + 1], world)}
        if not pairs:
            continue
        if t != prev_t + 1:
            prev = set()
        count += len(pairs - prev)
        prev, prev_t = pairs, t
    return count


def _travel(xy: Array, present: BoolArray, ids: IntArray) -> dict[int, float]:
    """Metres per robot over consecutive rows where the robot is present at both."""
    seen = np.nonzero(present.any(axis=0))[0]
    if len(xy) < 2:
        return {int(ids[c]): 0.0 for c in seen}
    per = np.nansum(np.linalg.norm(np.diff(xy, axis=0), axis=-1), axis=0)
    return {int(ids[c]): round(float(per[c]), 6) for c in seen}


def _mismatches(we: dict[str, Any], figures: list[tuple[str, Any, float]]) -> list[str]:
    """Names of ``figures`` (name, recomputed value, relative tolerance) the world disagrees on."""
    out: list[str] = []
    for name, mine, tol_rel in figures:
        theirs = we.get(name)
        if theirs is None:
            continue
        if isinstance(theirs, float) or tol_rel:
            if mine is None or abs(float(mine) - float(theirs)) > tol_rel * max(
                    1.0, abs(float(theirs))):
                out.append(name)
        elif mine != theirs:
            out.append(name)
    return out


def _phase_report(data: LogData, ph: PhaseLog, end_step: int, complete: bool,
                  timing: dict[str, float]) -> tuple[PhaseReport, StepSeries]:
    fr, w = data.frames, data.world
    rows = fr.rows(ph.start_step, end_step)
    steps = fr.steps[rows]
    pat_idx = ph.pattern_rows(steps)
    err, far, all_seps = _geometry(fr.xy[rows], fr.present[rows], pat_idx, ph)
    tol = np.asarray([p.formed_tol_m for p in ph.patterns])[pat_idx]
    is_formed = far <= tol
    formed_rows = np.nonzero(is_formed)[0]
    formed = len(formed_rows) > 0
    last = int(formed_rows[0]) if formed else len(rows) - 1  # the first passage
    first_end = int(steps[last]) if len(rows) else ph.start_step
    n_steps = first_end - ph.start_step
    we = ph.world_end
    hold = as_int(we.get("hold_steps")) if we is not None else 0
    # the phase's last row: the first passage, or the end of the world's hold window
    tail = len(rows) - 1 if formed and hold > 0 else last
    end = int(steps[tail]) if len(rows) else ph.start_step
    held_steps = int(is_formed[last + 1 : tail + 1].sum()) if hold > 0 and formed else (
        0 if hold > 0 else None)
    span = rows[: last + 1]
    xy = fr.xy[span]
    travel = _travel(xy, fr.present[span], fr.ids) if len(xy) else {}
    # collisions, counted when a pair starts overlapping (as the world counts them)
    collisions = _collisions(fr.xy[rows[: tail + 1]], fr.ids, all_seps[: tail + 1], w)
    seps = all_seps[1 : tail + 1]
    min_sep = float(seps.min()) if len(seps) and np.isfinite(seps.min()) else None
    # lower bounds from the poses at the phase's first step
    lb_steps: int | None = None
    lb_travel: float | None = None
    n0 = 0
    if len(rows) and steps[0] == ph.start_step:
        cols = np.nonzero(fr.present[rows[0]])[0]
        n0 = len(cols)
        C0 = ph.patterns[0].points
        if n0 == len(C0) and n0 >= 2:
            t_lb = time.perf_counter()
            lbt, lbs = lower_bounds(fr.xy[rows[0]][cols], C0, w.v_max_mps, w.dt_s)
            timing["lower_bounds_s"] = timing.get("lower_bounds_s", 0.0) + (
                time.perf_counter() - t_lb)
            lb_steps, lb_travel = int(lbs), round(float(lbt), 6)
    elif len(ph.patterns[0].points):
        n0 = len(ph.patterns[0].points)
    # commands in [start, end): brains, interventions, missing ones
    cm = data.commands
    sel = (cm.step >= ph.start_step) & (cm.step < end)
    brains = cm.brain_counts(sel)
    interventions = int(cm.safety_changed[sel].sum())
    got = cm.step[sel] * (1 << 24) + cm.robot_id[sel]
    decided = rows[:tail]  # the steps [start, end) whose poses the robots answered
    rr, cc = np.nonzero(fr.present[decided])
    want = fr.steps[decided][rr] * (1 << 24) + fr.ids[cc]
    missing = int((~np.isin(want, got)).sum())
    # the world's view, for comparison
    mism = [] if we is None else _mismatches(we, [
        ("formed", formed, 0.0), ("steps", n_steps, 0.0),
        ("lower_bound_steps", lb_steps, 0.0), ("lower_bound_travel_m", lb_travel, 1e-5),
        ("travel_m", round(sum(travel.values()), 6), 1e-4), ("collisions", collisions, 0.0),
        ("min_separation_m", min_sep if min_sep is not None else -1.0, 1e-5),
        ("deadline_misses", ph.deadline_misses, 0.0),
        *([("held_steps", held_steps, 0.0)] if hold > 0 else [])])
    series = StepSeries(ph.index, steps[: tail + 1], steps[: tail + 1].astype(np.float64) * w.dt_s,
                        err[: tail + 1],
                        np.where(np.isfinite(all_seps), all_seps, np.nan)[: tail + 1])
    accepted = [s for s in ph.swaps if s.get("accepted") and (
        "old_brain_id" not in s or s.get("old_brain_id") != s.get("brain_id"))]
    unchanged = sum(1 for s in ph.swaps if s.get("accepted")) - len(accepted)
    return PhaseReport(
        index=ph.index, pattern=ph.name, n_robots=n0, start_step=ph.start_step, end_step=end,
        complete=complete or formed, formed=formed, steps=n_steps, lower_bound_steps=lb_steps,
        lower_bound_travel_m=lb_travel, travel_m=round(sum(travel.values()), 6),
        travel_per_robot_m=travel, collisions=collisions,
        min_separation_m=_r(min_sep), final_error_m=_r(float(err[last])) if len(rows) else None,
        deadline_misses=ph.deadline_misses, commands_missing=missing,
        stale_commands=len(ph.stale_ages),
        command_ages={int(a): int(c) for a, c in zip(*np.unique(
            np.asarray(ph.stale_ages, np.int64), return_counts=True), strict=True)},
        guard_scaled=ph.guard_scaled,
        safety_interventions=interventions, brains=brains,
        swaps_accepted=len(accepted), swaps_refused=len(ph.swaps) - len(accepted) - unchanged,
        swaps_unchanged=unchanged,
        swapped_to=sorted({str(s.get("brain", "")) for s in accepted}),
        joined=ph.joined, lost=ph.lost,
        world=dict(we) if we is not None else None, mismatches=mism,
        hold_steps=hold, held_steps=held_steps,
        held=None if held_steps is None else holds(formed, held_steps, hold),
    ), series


def analyse(data: LogData) -> RunReport:
    """The report of a decoded log (see the module docstring for every figure)."""
    fr = data.frames
    phases = phases_of(data)
    run_end = data.events_of("run_end")
    last_step = int(fr.steps[-1]) if len(fr.steps) else None
    S = len(fr.steps)
    reports = []
    series = []
    timing: dict[str, float] = {"lower_bounds_s": 0.0}
    t0 = time.perf_counter()
    for k, ph in enumerate(phases):
        if ph.end_step is not None:
            end, complete = ph.end_step, True
        elif k + 1 < len(phases):
            end, complete = phases[k + 1].start_step, True
        else:
            end = as_int(run_end[0].get("steps"), last_step or 0) if run_end else (last_step or 0)
            complete = bool(run_end)
        rep, ser = _phase_report(data, ph, max(end, ph.start_step), complete, timing)
        reports.append(rep)
        series.append(ser)
    start = data.events_of("run_start")
    mode = str(start[0].get("mode", "?")) if start else "?"
    if run_end:
        outcome = str(run_end[0].get("outcome", "?"))
    else:
        outcome = "cut short" if not data.recovery.finished else "no run_end"
    world_malformed = as_int(run_end[0].get("malformed")) if run_end else len(
        data.events_of("malformed"))
    wall = run_end[0].get("wall_s") if run_end else None
    wall_s = (float(wall) if isinstance(wall, (int, float)) and math.isfinite(wall)
              else (data.last_log_ns - data.first_log_ns) / 1e9)
    return RunReport(
        path=data.path, recovery=data.recovery, finished=data.recovery.finished,
        messages=data.recovery.messages, steps_recorded=S,
        first_step=int(fr.steps[0]) if S else None, last_step=last_step,
        wall_s=wall_s, robots=[int(i) for i in fr.ids], skipped=data.skipped,
        mode=mode, outcome=outcome, malformed=data.malformed + world_malformed,
        topics=data.topics, phases=reports,
        series=series, world=data.world, phase_patterns=[ph.patterns for ph in phases],
        timing={**timing, "phases_s": time.perf_counter() - t0},
        estimation=estimation_error(data.views, fr),
    )


def report_log(path: str | Path) -> RunReport:
    """Read and analyse one log."""
    return analyse(read_log(path))
