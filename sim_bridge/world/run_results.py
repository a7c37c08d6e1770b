"""What a run of the world returns: one :class:`PhaseResult` per pattern, the run's outcome.

A :class:`PhaseResult` is also the ``phase_end`` event on the log, field for field;
:func:`result_dict` is the ``--json`` line of ``patternrl sim`` and ``patternrl launch``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class PhaseResult:
    """How one pattern of the sequence went (also the ``phase_end`` event)."""

    index: int
    pattern: str
    n_robots: int
    formed: bool
    steps: int
    step_limit: int
    lower_bound_steps: int
    travel_m: float
    lower_bound_travel_m: float
    collisions: int
    contacts: int
    min_separation_m: float
    deadline_misses: int
    late_commands: int
    final_error_m: float
    brain: str
    brain_ids: list[str]
    joins: int
    leaves: int
    start_step: int
    end_step: int
    wall_s: float
    stale_commands: int = 0
    """Deadline misses on which the robot moved on an older command (<= the age bound)."""
    held_still: int = 0
    """Deadline misses on which the robot held still (no command within the age bound)."""
    command_age_max: int = 0
    """The oldest command applied (steps since its poses)."""
    guard_scaled: int = 0
    """Commands the world's guard slowed down or stopped (:mod:`sim_bridge.world.stale_guard`)."""
    hold_steps: int = 0
    """Steps the world went on after the first passage to watch the formation (``--hold-steps``;
    0: the phase ended at the first passage). ``steps``, ``travel_m`` and ``final_error_m``
    are the first passage's; collisions, contacts, separation and deadline figures, ``end_step``
    and ``wall_s`` include these steps."""
    held_steps: int = 0
    """Of those steps, the ones after which the team was still formed."""
    held: bool = False
    """Formed, and still formed on :data:`~runtime.world_config.HOLD_SHARE` of the hold steps
    or more (:func:`runtime.world_config.holds`); with ``hold_steps`` 0, the same as
    ``formed``."""

    def hold_text(self) -> str:
        """``held 19/20``, ``NOT held (8/20)``; empty without a hold window or a first passage."""
        if not self.hold_steps or not self.formed:
            return ""
        share = f"{self.held_steps}/{self.hold_steps}"
        return f"held {share}" if self.held else f"NOT held ({share})"


@dataclass
class RunResult:
    """A whole run: the phases, the outcome and the log path."""

    phases: list[PhaseResult]
    outcome: str
    """``done``, ``interrupted`` or ``no robots``."""
    steps: int
    wall_s: float
    record: str | None
    latencies_ms: list[float] = field(default_factory=list, repr=False)
    world_cpu: dict[str, Any] = field(default_factory=dict)
    """What the world's process spent while the patterns played: ``stepping_cpu_s`` (its
    stepping thread), ``stepping_cpu_split_s`` (that, by section), ``writer_cpu_s`` (the
    log's writer thread), ``process_cpu_s`` (every thread: Zenoh's I/O and TLS too),
    ``steps`` and ``overruns``."""

    @property
    def all_formed(self) -> bool:
        return self.outcome == "done" and all(p.formed for p in self.phases)

    @property
    def all_held(self) -> bool:
        """Every pattern formed and, where the world watched it after, held (the exit code's
        success; with ``hold_steps`` 0 the same as :attr:`all_formed`)."""
        return self.outcome == "done" and all(p.held for p in self.phases)

    @property
    def hold_steps(self) -> int:
        """The hold window the phases ran with (0: none)."""
        return max((p.hold_steps for p in self.phases), default=0)


@dataclass
class Progress:
    """What a progress line shows, after each step."""

    phase: int
    n_phases: int
    pattern: str
    step: int
    phase_step: int
    formation_error_m: float
    n_live: int
    deadline_misses: int


def result_dict(res: RunResult) -> dict[str, Any]:
    """The run as the ``--json`` line prints it."""
    return {"outcome": res.outcome, "all_formed": res.all_formed, "all_held": res.all_held,
            "steps": res.steps,
            "wall_s": res.wall_s, "record": res.record,
            "phases": [asdict(p) for p in res.phases], "world_cpu": res.world_cpu}
