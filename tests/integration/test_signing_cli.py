"""``patternrl brain keygen/sign/verify`` as a process, and what signing costs a robot's import."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from support import ROOT
from support.brains import copy_shipped_brain


def _cli(*argv: str, env_home: Path) -> subprocess.CompletedProcess[str]:
    import os

    env = dict(os.environ, PATTERNRL_HOME=str(env_home))
    return subprocess.run([sys.executable, "-m", "patternrl.cli", "brain", *argv], cwd=ROOT,
                          capture_output=True, text=True, timeout=120, env=env)


def test_brain_command_keygen_sign_verify(tmp_path: Path) -> None:
    home = tmp_path / "home"
    brain = copy_shipped_brain(tmp_path, "circle-10-general")
    r = _cli("verify", str(brain), "--json", env_home=home)
    assert r.returncode == 0 and json.loads(r.stdout)["reason"] == "signed by release"
    r = _cli("keygen", env_home=home)
    assert r.returncode == 0 and (home / "brain-key.pub").is_file(), r.stderr
    assert (home / "brain-key").stat().st_mode & 0o077 == 0
    r = _cli("keygen", env_home=home)
    assert r.returncode == 2 and "already exists" in r.stderr and "Traceback" not in r.stderr
    r = _cli("sign", str(brain), env_home=home)  # with the user's own key
    assert r.returncode == 0, r.stderr
    r = _cli("verify", str(brain), env_home=home)
    assert r.returncode == 0 and "own key" in r.stdout
    r = _cli("verify", str(brain), env_home=tmp_path / "elsewhere")  # another user
    assert r.returncode == 1 and "untrusted key" in r.stdout
    r = _cli("sign", "rule:assign", env_home=home)
    assert r.returncode == 2 and "needs no signature" in r.stderr
    r = _cli("verify", str(brain), "--trust", str(tmp_path / "nope.pub"), env_home=home)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no such file" in r.stderr
    r = _cli("sign", str(brain), "--key", str(brain), env_home=home)
    assert r.returncode == 2 and "not an unencrypted private key" in r.stderr


def test_signing_costs_the_robot_little_to_import() -> None:
    code = (
        "import sys, time\nt = time.perf_counter()\n"
        "from runtime.brain import signing\n"
        "print(time.perf_counter() - t, 'torch' in sys.modules)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[1] == "False"
