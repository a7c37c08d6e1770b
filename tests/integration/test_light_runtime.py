"""The per-robot runtime stays light: importing all of runtime/ loads no heavy stack."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import runtime

HEAVY = ("torch", "pymunk", "mcap", "matplotlib", "onnx", "tqdm")


def test_runtime_imports_no_heavy_package() -> None:
    modules = [m.name for m in pkgutil.walk_packages(runtime.__path__, "runtime.")]
    assert "runtime.decision.formation" in modules and "runtime.decision.observation" in modules
    code = (
        "import importlib, sys\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        f"bad = [h for h in {HEAVY!r} if h in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"runtime loaded: {r.stdout.strip()}"
