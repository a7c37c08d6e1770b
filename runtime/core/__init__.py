"""The decision's math, one source per concept, batched over (teams x robots).

Each module here is plain Python in Cython's pure-Python mode: the same file runs
as Python and is compiled at install (``setup.py``; a C compiler and Cython are
needed, and without them the robots and the trainer run this very source as
Python, the same numbers, slower). A robot asks for its own row, the training
world, ``eval`` and the benchmarks for a batch of teams: the batch functions loop
the per-robot (or per-team) function over (teams x robots) in the same file.

========================= ===============================================
module                    concept
========================= ===============================================
:mod:`.neighbours`        a robot's nearest others (ties by id), the one
                          neighbour choice of the row and the filter
:mod:`.orca_lp`           ORCA's linear programs and the speed clamp
:mod:`.orca`              the ORCA safety filter and its guard
:mod:`.general_row`       the general (and plan) observation row
:mod:`.lsap`              the minimum-cost assignment's solver (scipy's
                          shortest augmenting path, cold or warm)
:mod:`.assignment`        the shared slot assignment: cost, optimality
                          proof, hysteresis; per team and batched
:mod:`.plan_frame`        the synchronised plan's frame (smallest
                          enclosing circle, blend, steps left)
========================= ===============================================
"""

from __future__ import annotations

import importlib
from pathlib import Path

__all__ = ["MODULES", "compiled_modules", "kernel_status", "stale_modules"]

MODULES = ("neighbours", "orca_lp", "orca", "general_row", "lsap", "assignment",
           "plan_frame")
"""The compiled modules of this package (each also runs as Python)."""


def compiled_modules() -> dict[str, bool]:
    """Each module's name -> whether it runs compiled (False: as Python)."""
    out = {}
    for name in MODULES:
        mod = importlib.import_module(f"runtime.core.{name}")
        out[name] = not str(getattr(mod, "__file__", "")).endswith(".py")
    return out


def stale_modules() -> list[str]:
    """The compiled modules whose source changed after they were built: the build shadows
    the source, so a stale one would run old code (re-run scripts/setup.sh)."""
    here = Path(__file__).parent
    out = []
    for name in MODULES:
        mod = importlib.import_module(f"runtime.core.{name}")
        built = Path(str(getattr(mod, "__file__", "")))
        src = here / f"{name}.py"
        if built.suffix != ".py" and src.is_file() and src.stat().st_mtime > built.stat().st_mtime:
            out.append(name)
    return out


def kernel_status() -> str:
    """One line: is the decision compiled, and if not, which parts run as Python."""
    mods = compiled_modules()
    slow = [m for m, c in mods.items() if not c]
    stale = stale_modules()
    if stale:
        return f"compiled, but older than its source: {', '.join(stale)} (re-run scripts/setup.sh)"
    if not slow:
        return "compiled"
    return f"Python (not compiled: {', '.join(slow)}; re-run scripts/setup.sh with a C compiler)"
