"""The report as text: the terminal tables of ``patternrl replay``.

:func:`format_report` one run (its facts, one row per phase, travel per robot,
agreement with the world's own figures); :func:`format_compare` two runs side by
side; :func:`table` the aligned columns both use (and the counterfactual's).
"""

from __future__ import annotations

from sim_bridge.log.report import PhaseReport, RunReport


def _f(x: float | None, nd: int = 2) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def _ids(xs: list[int]) -> str:
    return ",".join(map(str, xs)) if xs else "-"


def _short_brain(b: str) -> str:
    return b if b.startswith("rule:") or len(b) <= 12 else b[:8]


def table(header: list[str], rows: list[list[str]], right: set[int]) -> list[str]:
    """Aligned text columns: a header, a rule, the rows; columns in ``right`` right-aligned."""
    width = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
             for i, h in enumerate(header)]

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(width[i]) if i in right else c.ljust(width[i])
                         for i, c in enumerate(cells)).rstrip()

    return [line(header), line(["-" * x for x in width]), *(line(r) for r in rows)]


def recovery_line(r: RunReport) -> str:
    rec = r.recovery
    steps = (f"steps {r.first_step}-{r.last_step}" if r.first_step is not None else "no steps")
    if rec.corrupted:
        return (f"log CORRUPTED (damaged bytes inside the file): read {rec.messages} messages, "
                f"{rec.corrupt_chunks} damaged chunks skipped, {r.steps_recorded} steps "
                f"({steps}); {rec.error}")
    if rec.finished:
        return f"log finished: {rec.messages} messages, {r.steps_recorded} steps ({steps})"
    return (f"log NOT finished (writer killed?): recovered {rec.messages} messages in "
            f"{rec.chunks} chunks, {r.steps_recorded} steps ({steps}), "
            f"{rec.bytes_read} of {rec.file_bytes} bytes; {rec.error}")


def _stale(ph: PhaseReport) -> str:
    """Stale commands applied and how old: ``12 (1:10 2:2)``."""
    if not ph.stale_commands:
        return "0"
    ages = " ".join(f"{a}:{c}" for a, c in sorted(ph.command_ages.items()))
    return f"{ph.stale_commands} ({ages})"


def _held(ph: PhaseReport) -> str:
    """Steps still formed of those the world watched after the first passage: ``yes 19/20``,
    ``NO 8/20``; ``-`` where there was no window (not formed, or none asked)."""
    if ph.held_steps is None or not ph.hold_steps or not ph.formed:
        return "-"
    return f"{'yes' if ph.held else 'NO'} {ph.held_steps}/{ph.hold_steps}"


def format_report(r: RunReport) -> str:
    """The terminal report: run facts, one row per phase, travel per robot."""
    out = [f"{r.path}: {r.mode}, {len(r.robots)} robots, {len(r.phases)} phases, "
           f"outcome {r.outcome}, {r.wall_s:.1f} s of wall time",
           recovery_line(r)]
    if r.malformed:
        out.append(f"malformed messages: {r.malformed}")
    for what, n in r.skipped.items():
        out.append(f"skipped {n} {what}")
    if not r.phases:
        out.append("no pattern phase in the log")
        return "\n".join(out + _estimation(r))
    hold = any(ph.held_steps is not None for ph in r.phases)  # a world that watched holds
    header = ["#", "pattern", "n", "formed", *(["held"] if hold else []), "steps", "lb",
              "x lb", "travel m", "lb m", "x lb", "coll", "min sep m", "final err m", "misses",
              "stale (ages)", "guard", "swaps", "joined", "lost", "brains"]
    rows = []
    for ph in r.phases:
        formed = "yes" if ph.formed else ("no" if ph.complete else "cut")
        rows.append([
            str(ph.index), ph.pattern, str(ph.n_robots), formed,
            *([_held(ph)] if hold else []), str(ph.steps),
            "-" if ph.lower_bound_steps is None else str(ph.lower_bound_steps),
            _f(ph.steps_ratio), _f(ph.travel_m), _f(ph.lower_bound_travel_m), _f(ph.travel_ratio),
            str(ph.collisions), _f(ph.min_separation_m, 3), _f(ph.final_error_m, 4),
            str(ph.deadline_misses), _stale(ph), str(ph.guard_scaled),
            f"{ph.swaps_accepted}" + (f" ({ph.swaps_refused} refused)" if ph.swaps_refused else ""),
            _ids(ph.joined), _ids(ph.lost),
            ",".join(_short_brain(b) for b in sorted(ph.brains)) or "-",
        ])
    right = {0, 2, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15}
    out += ["", *table(header, rows, {k + 1 if hold and k >= 4 else k for k in right})]
    ids = sorted({rid for ph in r.phases for rid in ph.travel_per_robot_m})
    if ids:
        header = ["robot", *[f"{ph.index}:{ph.pattern}" for ph in r.phases], "total m"]
        rows = []
        for rid in ids:
            per = [ph.travel_per_robot_m.get(rid) for ph in r.phases]
            rows.append([str(rid), *[_f(v) for v in per], _f(sum(v for v in per if v))])
        out += ["", "travel per robot (m)",
                *table(header, rows, set(range(len(header))))]
    out += _estimation(r)
    notes = [f"phase {ph.index}: differs from the world's phase_end in {', '.join(ph.mismatches)}"
             for ph in r.phases if ph.mismatches]
    checked = [ph for ph in r.phases if ph.world is not None]
    if checked and not notes:
        notes.append(f"recomputed figures agree with the world's phase_end ({len(checked)} "
                     f"phase{'s' if len(checked) > 1 else ''})")
    return "\n".join([*out, "", *notes]) if notes else "\n".join(out)


def _estimation(r: RunReport) -> list[str]:
    """The robots' estimation error (their views against the world's poses); none without."""
    est = r.estimation
    if est is None:
        return []
    rows = [[str(rid), str(s.views), str(s.peers), _f(s.mean_m, 3), _f(s.p95_m, 3),
             _f(s.max_m, 3)] for rid, s in sorted(est.per_robot.items())]
    o = est.overall
    rows.append(["all", str(o.views), str(o.peers), _f(o.mean_m, 3), _f(o.p95_m, 3),
                 _f(o.max_m, 3)])
    return ["", "estimation error (m): each peer as the robot perceived it vs the world's "
                "pose of the same step",
            *table(["robot", "views", "peers", "mean", "p95", "max"], rows, {1, 2, 3, 4, 5})]


def format_compare(a: RunReport, b: RunReport) -> str:
    """Two runs side by side, phase by phase."""
    out = [f"a: {a.path} ({a.outcome}, {'finished' if a.finished else 'cut short'})",
           f"b: {b.path} ({b.outcome}, {'finished' if b.finished else 'cut short'})", ""]
    header = ["#", "pattern", "formed a|b", "steps a", "steps b", "x lb a", "x lb b",
              "travel a", "travel b", "x lb a", "x lb b", "coll a|b", "min sep a", "min sep b",
              "misses a|b"]
    rows = []
    for k in range(max(len(a.phases), len(b.phases))):
        pa = a.phases[k] if k < len(a.phases) else None
        pb = b.phases[k] if k < len(b.phases) else None
        name = pa.pattern if pa else pb.pattern if pb else "?"
        if pa and pb and pa.pattern != pb.pattern:
            name = f"{pa.pattern}|{pb.pattern}"

        def g(p: PhaseReport | None, attr: str, nd: int = 2) -> str:
            if p is None:
                return "-"
            v = getattr(p, attr)
            return str(v) if isinstance(v, int) and not isinstance(v, bool) else _f(v, nd)

        def fm(p: PhaseReport | None) -> str:
            return "-" if p is None else "yes" if p.formed else "no"

        rows.append([str(k), name, f"{fm(pa)}|{fm(pb)}", g(pa, "steps"), g(pb, "steps"),
                     g(pa, "steps_ratio"), g(pb, "steps_ratio"), g(pa, "travel_m"),
                     g(pb, "travel_m"), g(pa, "travel_ratio"), g(pb, "travel_ratio"),
                     f"{g(pa, 'collisions')}|{g(pb, 'collisions')}",
                     g(pa, "min_separation_m", 3), g(pb, "min_separation_m", 3),
                     f"{g(pa, 'deadline_misses')}|{g(pb, 'deadline_misses')}"])
    out += table(header, rows, {0, *range(3, 15)})

    def tot(r: RunReport) -> tuple[int, float]:
        return sum(p.steps for p in r.phases), sum(p.travel_m for p in r.phases)

    (sa, ta), (sb, tb) = tot(a), tot(b)
    out += ["", f"total: steps {sa} vs {sb} (b/a {_f(sb / sa if sa else None)}), "
                f"travel {ta:.2f} m vs {tb:.2f} m (b/a {_f(tb / ta if ta else None)})"]
    return "\n".join(out)
