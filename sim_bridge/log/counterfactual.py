"""What another brain would have done: run it on every recorded step, compare commands.

Another brain, run at every recorded step exactly as a robot runs it: one
:class:`runtime.decision.controller.Controller` per robot (shared assignment with
hysteresis, the brain's observation builder, clamp, the ORCA filter unless
``safety`` is False) fed the recorded poses of that step (robots sorted by id)
and the pattern in force when those poses were published (the last pattern
message recorded before the step's first pose: the world publishes a new
pattern before the poses of its first step). Deviation = ||v_other - v_recorded||
in m/s per (robot, step) with a recorded command. In realtime logs the robots
decided at their own pace on slightly different frames; there the deviation
includes that timing.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from runtime.types import Array
from runtime.wire.messages import PatternMsg
from runtime.world_config import WorldConfig
from sim_bridge.log.phases import phases_of
from sim_bridge.log.reader import LogData
from sim_bridge.log.report_text import table


@dataclass
class Deviation:
    """Deviation of another brain's commands from the recorded ones (m/s)."""

    steps: int = 0
    mean_mps: float = 0.0
    max_mps: float = 0.0
    errors: int = 0
    """Decisions where the other brain could not act (held still)."""
    safety_interventions: int = 0


@dataclass
class CounterfactualReport:
    brain: str
    safety: bool
    realtime: bool
    per_phase: list[tuple[int, str, Deviation]]
    per_robot: dict[tuple[int, int], Deviation]
    """(phase index, robot id) -> deviation"""
    overall: Deviation

    def to_dict(self) -> dict[str, Any]:
        return {
            "brain": self.brain, "safety": self.safety, "realtime": self.realtime,
            "overall": asdict(self.overall),
            "phases": [{"index": i, "pattern": name, **asdict(d),
                        "robots": {str(rid): asdict(dv) for (pi, rid), dv in
                                   sorted(self.per_robot.items()) if pi == i}}
                       for i, name, d in self.per_phase],
        }


def _fit_pattern(msg: PatternMsg, n: int, world: WorldConfig) -> Array | None:
    """The pattern a robot uses for a team of n
    (:func:`runtime.decision.team_pattern.fit_pattern`)."""
    from runtime.decision.patterns import PatternError
    from runtime.decision.team_pattern import fit_pattern

    try:
        return fit_pattern(msg.name, np.asarray(msg.points, dtype=np.float64), n, world)
    except PatternError:
        return None


def _summarise(dev: list[float], errors: int, interventions: int) -> Deviation:
    if not dev:
        return Deviation(0, 0.0, 0.0, errors, interventions)
    a = np.asarray(dev)
    return Deviation(len(a), round(float(a.mean()), 9), round(float(a.max()), 9), errors,
                     interventions)


def counterfactual(data: LogData, brain_ref: str, safety: bool = True) -> CounterfactualReport:
    """Run ``brain_ref`` on every recorded step as each robot would; compare with the log.

    Raises :class:`runtime.brain.brain.BrainError` for a brain that cannot be loaded.
    """
    from runtime.brain.brain import load_brain
    from runtime.decision.controller import Controller
    from runtime.decision.patterns import PatternError, make_pattern
    from runtime.decision.safety import OrcaParams

    w = data.world
    brain = load_brain(brain_ref, w)
    params = OrcaParams() if safety else None
    fixed: Array | None = None
    m = brain.manifest
    if m is not None and brain.spec.name == "paper" and m.pattern:
        try:
            fixed = make_pattern(m.pattern, m.n_robots or brain.spec.n_robots, w)
        except PatternError:
            fixed = None
    fr, cm = data.frames, data.commands
    recorded: dict[tuple[int, int], tuple[float, float]] = {}
    for rid, step, (vx, vy) in zip(cm.robot_id.tolist(), cm.step.tolist(), cm.v.tolist(),
                                   strict=True):
        recorded.setdefault((step, rid), (vx, vy))
    version_phase: dict[int, int] = {}
    phase_logs = phases_of(data)
    for pl in phase_logs:
        for p in pl.patterns:
            version_phase[p.version] = pl.index
    marks = data.patterns
    mark_at = np.asarray([mk.msg_index for mk in marks], np.int64)
    ctrl: dict[int, Controller] = {}
    team: dict[int, list[int]] = {}
    fitted: dict[tuple[int, int], Array | None] = {}
    dev: dict[tuple[int, int], list[float]] = defaultdict(list)
    errs: Counter[tuple[int, int]] = Counter()
    inter: Counter[tuple[int, int]] = Counter()
    for row in range(len(fr.steps)):
        step = int(fr.steps[row])
        k = int(np.searchsorted(mark_at, fr.first_msg[row], side="right")) - 1
        if k < 0:
            continue  # no pattern yet: robots hold still, nothing to compare
        msg = marks[k].msg
        phase = version_phase.get(msg.version, -1)
        cols = np.nonzero(fr.present[row])[0]
        ids = [int(fr.ids[c]) for c in cols]
        pos = fr.xy[row][cols]
        n = len(ids)
        if fixed is not None:
            pattern = fixed if len(fixed) == n else None
        else:
            key = (msg.version, n)
            if key not in fitted:
                fitted[key] = _fit_pattern(msg, n, w)
            pattern = fitted[key]
        for i, rid in enumerate(ids):
            c = ctrl.get(rid)
            if c is None:
                c = ctrl[rid] = Controller(brain, w, params)
            if team.get(rid) != ids:
                c.reset()
                team[rid] = ids
            if pattern is None:
                vx = vy = 0.0
                errs[(phase, rid)] += 1
            else:
                d = c.decide(i, pos, pattern, step)
                vx, vy = d.velocity
                if d.error:
                    errs[(phase, rid)] += 1
                if d.safety_changed:
                    inter[(phase, rid)] += 1
            rv = recorded.get((step, rid))
            if rv is not None:
                dev[(phase, rid)].append(math.hypot(vx - rv[0], vy - rv[1]))
    names = {pl.index: pl.name for pl in phase_logs}
    per_robot = {key: _summarise(v, errs[key], inter[key]) for key, v in dev.items()}
    per_phase = []
    for pi in sorted({key[0] for key in dev}):
        allv = [x for key, v in dev.items() if key[0] == pi for x in v]
        per_phase.append((pi, names.get(pi, "(none)"), _summarise(
            allv, sum(e for key, e in errs.items() if key[0] == pi),
            sum(e for key, e in inter.items() if key[0] == pi))))
    overall = _summarise([x for v in dev.values() for x in v], sum(errs.values()),
                         sum(inter.values()))
    realtime = any(e.get("mode") == "realtime" for e in data.events_of("run_start"))
    return CounterfactualReport(brain.brain_id if brain_ref.startswith("rule:") else
                                f"{Path(brain_ref).name} ({brain.brain_id[:8]})", safety,
                                realtime, per_phase, per_robot, overall)


def format_counterfactual(cf: CounterfactualReport) -> str:
    out = [f"counterfactual: {cf.brain}, safety filter {'on' if cf.safety else 'off'}: "
           f"deviation from the recorded commands over {cf.overall.steps} decisions: "
           f"mean {cf.overall.mean_mps:.4f} m/s, max {cf.overall.max_mps:.4f} m/s"]
    if cf.realtime:
        out.append("(realtime log: the robots decided at their own pace; deviations include it)")
    header = ["#", "pattern", "robot", "decisions", "mean m/s", "max m/s", "held", "filtered"]
    rows = []
    for pi, name, d in cf.per_phase:
        rows.append([str(pi) if pi >= 0 else "-", name, "all", str(d.steps),
                     f"{d.mean_mps:.4f}", f"{d.max_mps:.4f}", str(d.errors),
                     str(d.safety_interventions)])
        for (ppi, rid), dv in sorted(cf.per_robot.items()):
            if ppi == pi:
                rows.append(["", "", str(rid), str(dv.steps), f"{dv.mean_mps:.4f}",
                             f"{dv.max_mps:.4f}", str(dv.errors), str(dv.safety_interventions)])
    return "\n".join([*out, "", *table(header, rows, {0, 2, 3, 4, 5, 6, 7})])
