"""Brain swaps between phases: each pattern's chosen brain put into the robots that lack it.

At every pattern change the world reads the pattern's :class:`BrainChoice` and
sends it, through the runtime's swap mechanism (:func:`runtime.brain.swap.swap_brain`),
to every live robot whose last word named another brain; every answer is logged
(``brain_swap`` events). At the end of the phase, :func:`phase_brain_label`
says which brain ran it.
"""

from __future__ import annotations

from collections.abc import Iterable

from runtime.brain.brain import BrainError
from sim_bridge.world.brain_choice import BrainChoice
from sim_bridge.world.world_link import WorldLink
from sim_bridge.world.world_log import WorldLog

DISCOVER_S = 2.0
"""How long a swap listens for robots before sending."""


def swap_brain_in(choice: BrainChoice, pattern: str, ids: Iterable[int], link: WorldLink,
                  log: WorldLog, timeout_s: float) -> None:
    """Put ``choice`` into every robot of ``ids`` that runs another brain."""
    known = link.brains()
    targets = {r for r in ids if known.get(r, "") != choice.brain_id[:64]}
    if not targets:
        return
    from runtime.brain.swap import read_brain, swap_brain  # onnxruntime: only when a swap is due

    try:
        manifest_json, onnx_bytes, _ = read_brain(choice.ref)
    except BrainError as e:
        log.say(f"cannot read brain {choice.ref}: {e}")
        log.event("brain_swap", robot=None, brain=choice.label, accepted=False,
                  reason=str(e)[:200])
        return
    log.say(f"swapping {choice.label} into {len(targets)} robot(s) for {pattern}", True)
    answers = swap_brain(link.session, link.swarm, manifest_json, onnx_bytes,
                         robots=targets, timeout_s=timeout_s, discover_s=DISCOVER_S)
    for rid, a in sorted(answers.items()):
        reason = a.reason if a.answered else "no answer in time"
        log.event("brain_swap", robot=rid, brain=choice.label, brain_id=choice.brain_id,
                  old_brain_id=a.old_brain, accepted=a.accepted and a.answered, reason=reason)
        if a.accepted and a.answered:
            link.set_brain(rid, a.new_brain)
        else:
            log.say(f"robot {rid} did not take {choice.label}: {reason}")


def phase_brain_label(choice: BrainChoice | None, seen: list[str]) -> str:
    """What the table says ran a phase: the choice, or the brain ids the robots named."""
    if choice is None:  # say what the robots ran
        return ", ".join(b if b.startswith("rule:") else b[:8] for b in seen) or "unknown"
    if any(b != choice.brain_id[:64] for b in seen):
        return f"{choice.label} (not in every robot)"
    return choice.label
