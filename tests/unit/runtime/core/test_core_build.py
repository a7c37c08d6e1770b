"""The decision's math runs compiled where it was installed, and never from a stale build."""

from __future__ import annotations

from runtime.core import MODULES, compiled_modules, kernel_status, stale_modules


def test_every_module_of_the_decision_is_compiled_and_current() -> None:
    """The install (scripts/setup.sh) compiles runtime/core; a build older than its source
    would shadow it with old code, so the status line names it."""
    assert set(compiled_modules()) == set(MODULES)
    assert stale_modules() == []
    assert all(compiled_modules().values()), kernel_status()
    assert kernel_status() == "compiled"
