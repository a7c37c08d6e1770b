"""The robot's decision, compiled: :mod:`runtime._kernel` (C), when it is built.

One robot's decision at N = 10 spent ~55 us in Python around a 13 us brain
(``benchmarks/runtime_latency.py``), and inside a 100-process swarm, with cold
caches, several times that. The C kernel does the per-robot arithmetic that
was Python over neighbours: the plan's frame and steps left
(:class:`runtime.rules.PlanFrame`), the neighbour order and the observation row
(:func:`runtime.observation.neighbour_order`, :func:`general_row`, the plan's
pace), and the ORCA filter on the nearest neighbours
(:func:`runtime.decision._near_in_order`, :func:`runtime.safety.orca_velocity`).
The assignment stays scipy's solver and the brain stays onnxruntime.

Why C and not numba: numba in a robot process costs ~135 MB more resident
memory (~75 MB of it private: the PSS budget is 60 MB a robot) and 0.5 s at
start even with its cache (measured here); the C extension is 40 KB and
loads in microseconds. It is built by ``pip install`` (``setup.py``) when a C
compiler is present, and optional: without it every decision runs the Python
reference, the same numbers more slowly.

The kernel performs the reference's IEEE operations in the same order
(compiled without fused multiply-add); the one difference is ``hypot``, C's
instead of CPython's, both correctly rounded but for rare last-bit cases.
Tests hold the two paths equal (``tests/unit/test_kernel.py``).

``PATTERNRL_KERNEL=0`` in the environment turns the kernel off (the Python
reference runs); :data:`KERNEL` is the module in use, or None.
"""

from __future__ import annotations

import os
from types import ModuleType
from typing import Final

__all__ = ["KERNEL", "VERSION", "kernel_status", "use_kernel"]

VERSION: Final = 2
"""The kernel's interface version; a build of another version is not used."""


def _load() -> tuple[ModuleType | None, str]:
    if os.environ.get("PATTERNRL_KERNEL", "1") == "0":
        return None, "off (PATTERNRL_KERNEL=0)"
    try:
        from runtime import _kernel  # type: ignore[attr-defined]
    except ImportError:
        return None, "not built (no C compiler at install): decisions in Python"
    got = getattr(_kernel, "VERSION", None)
    if got != VERSION:
        return None, f"stale build (version {got}, want {VERSION}): re-run scripts/setup.sh"
    return _kernel, "compiled"


_LOADED = _load()
KERNEL: Final[ModuleType | None] = _LOADED[0]
_STATUS: Final[str] = _LOADED[1]


def kernel_status() -> str:
    """One line: is the decision compiled, and if not, why."""
    return _STATUS


def use_kernel(compiled: bool | None) -> ModuleType | None:
    """The kernel a decision maker uses: None (the default) the built one if any, True the
    built one or an error, False none (the Python reference)."""
    if compiled is False:
        return None
    if compiled and KERNEL is None:
        raise RuntimeError(f"the compiled decision kernel is not available: {_STATUS}")
    return KERNEL
