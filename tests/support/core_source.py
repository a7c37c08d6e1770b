"""The decision core run uncompiled, from its source, whatever is compiled beside it: the
reference the compiled core is checked against."""

from __future__ import annotations

import functools
import importlib.util
import sys
from types import ModuleType, SimpleNamespace

from support import ROOT

CORE = ROOT / "runtime" / "core"


def _from_source(name: str, module_name: str) -> ModuleType:
    """``runtime/core/<name>.py`` executed as Python, whatever is compiled beside it."""
    spec = importlib.util.spec_from_file_location(module_name, CORE / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@functools.cache
def python_core() -> SimpleNamespace:
    """``neighbours``, ``general_row``, ``orca_lp`` and ``orca`` run uncompiled, from their
    source.

    The row builder and the filter import ``nearest`` from ``runtime.core.neighbours``, the
    filter its linear programs from ``runtime.core.orca_lp``; while they load, those names
    point at the uncompiled modules, so the four run as Python together. The compiled
    modules are put back afterwards.
    """
    import runtime.core.neighbours
    import runtime.core.orca_lp  # noqa: F401 - the modules to put back

    keys = ("runtime.core.neighbours", "runtime.core.orca_lp")
    compiled = {key: sys.modules[key] for key in keys}
    neighbours = _from_source("neighbours", keys[0])
    orca_lp = _from_source("orca_lp", keys[1])
    sys.modules[keys[0]], sys.modules[keys[1]] = neighbours, orca_lp
    try:
        general_row = _from_source("general_row", "runtime_core_general_row_source")
        orca = _from_source("orca", "runtime_core_orca_source")
    finally:
        sys.modules.update(compiled)
    for mod in (neighbours, general_row, orca_lp, orca):
        assert not mod.cython.compiled
    assert general_row.nearest is neighbours.nearest and orca.nearest is neighbours.nearest
    assert orca.LinearProgram is orca_lp.LinearProgram and orca.clamp is orca_lp.clamp
    return SimpleNamespace(neighbours=neighbours, general_row=general_row, orca_lp=orca_lp,
                           orca=orca)


@functools.cache
def python_assignment() -> SimpleNamespace:
    """``lsap`` and ``assignment`` run uncompiled, from their source.

    The assignment imports ``solve`` from ``runtime.core.lsap``; while it loads, that
    name points at the uncompiled solver, so the two run as Python together. The
    compiled module is put back afterwards.
    """
    import runtime.core.lsap  # noqa: F401 - the module to put back

    key = "runtime.core.lsap"
    compiled = sys.modules[key]
    lsap = _from_source("lsap", key)
    sys.modules[key] = lsap
    try:
        assignment = _from_source("assignment", "runtime_core_assignment_source")
    finally:
        sys.modules[key] = compiled
    for mod in (lsap, assignment):
        assert not mod.cython.compiled
    assert assignment.solve is lsap.solve
    return SimpleNamespace(lsap=lsap, assignment=assignment)
