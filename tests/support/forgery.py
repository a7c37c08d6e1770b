"""Forged messages: what a robot has no right to publish, and a fence after them."""

from __future__ import annotations

from typing import Any

from support.net import Seen, wait_for


def forged_command(robot_id: int, step: int, brain: str = "forged") -> bytes:
    """A well-formed command payload of robot ``robot_id`` (the attacks' forgeries and fences)."""
    from runtime.wire.messages import Command, encode_command

    return encode_command(Command(robot_id, step, 1.0, 0.0, brain, False, 0.0, 0.0))


def forged_keys(swarm: str) -> tuple[str, ...]:
    """What robot 1 has no right to publish: robot 2's keys, the brain and the patterns."""
    from runtime.wire import keys

    return (keys.cmd_key(swarm, 2), keys.status_key(swarm, 2), keys.pose_key(swarm, 2),
            keys.slots_key(swarm, 2), keys.brain_key(swarm), keys.pattern_key(swarm),
            keys.operator_pattern_key(swarm))


def forge_and_fence(attacker: Any, seen: Seen, swarm: str, token_ids: tuple[int, ...]
                    ) -> list[object]:
    """Robot 1 forges everything it has no right to (:func:`forged_keys`, three steps each,
    liveliness tokens of ``token_ids``), then publishes its own command and token.

    Messages of one link arrive in order, so once ``seen`` has the fence it has had every
    forgery that was ever going to arrive. Returns the tokens (keep them alive).
    """
    from runtime.wire import keys

    for step in range(3):
        for key in forged_keys(swarm):
            attacker.put(key, forged_command(2, step))
    tokens = [attacker.liveliness().declare_token(keys.alive_key(swarm, i))
              for i in (*token_ids, 1)]
    fence = forged_command(1, 999, "fence")
    attacker.put(keys.cmd_key(swarm, 1), fence)
    wait_for(lambda: seen.has(keys.cmd_key(swarm, 1), fence), 20, "robot 1's own command")
    wait_for(lambda: "1" in seen.alive, 20, "robot 1's own liveliness token")
    return tokens
