"""Test support shared by every test folder and the benchmarks (``tests/`` is on ``sys.path``).

The package's top level holds the light helpers; heavier ones are imported by module:
``support.brains`` (ONNX test brains) and ``support.stub_world`` (the world's side of the wire,
and robot processes to drive).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
"""The repository root."""
ROBOT_SILENCE_EXIT_S = "8"
"""A test robot's ``--exit-after-silence-s``: longer than the world's wait for a step that
brings news (``SimConfig.first_step_deadline_ms``, 5 s: its first steps wait that long for the
slowest robot, who may be late on a busy machine); a shorter one lets every other robot leave
while the world still waits, and the run ends with no robots."""

from support.episodes import assert_same_episodes  # noqa: E402
from support.forgery import forge_and_fence, forged_command, forged_keys  # noqa: E402
from support.net import Seen, free_port, stop_processes, wait_for  # noqa: E402


def load_benchmark(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` imported as a module (``t_<name>``), for its functions."""
    spec = importlib.util.spec_from_file_location(f"t_{name}", ROOT / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


__all__ = [
    "ROBOT_SILENCE_EXIT_S",
    "ROOT",
    "Seen",
    "assert_same_episodes",
    "forge_and_fence",
    "forged_command",
    "forged_keys",
    "free_port",
    "load_benchmark",
    "stop_processes",
    "wait_for",
]
