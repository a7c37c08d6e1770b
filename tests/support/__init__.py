"""Test support shared by every test folder and the benchmarks (``tests/`` is on ``sys.path``).

The package's top level holds the light helpers; heavier ones are imported by module:
``support.brains`` (ONNX test brains) and ``support.stub_world`` (the world's side of the wire,
and robot processes to drive).
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
"""The repository root."""

from support.episodes import assert_same_episodes  # noqa: E402
from support.forgery import forge_and_fence, forged_command, forged_keys  # noqa: E402
from support.net import Seen, free_port, stop_processes, wait_for  # noqa: E402

__all__ = [
    "ROOT",
    "Seen",
    "assert_same_episodes",
    "forge_and_fence",
    "forged_command",
    "forged_keys",
    "free_port",
    "stop_processes",
    "wait_for",
]
