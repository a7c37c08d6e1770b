"""Keys made in a checkout stay out of git: ``patternrl keys create`` leaves nothing untracked."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
@pytest.mark.parametrize("out", ["keys/demo", "swarm-keys"])
def test_keys_create_leaves_no_private_key_untracked(tmp_path: Path, out: str) -> None:
    repo = tmp_path / "checkout"
    repo.mkdir()
    shutil.copy(ROOT / ".gitignore", repo / ".gitignore")
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    r = subprocess.run(
        [sys.executable, "-m", "patternrl.cli", "keys", "create", "--swarm", "s1",
         "--robots", "2", "--out", out],
        cwd=repo, capture_output=True, text=True,
    )
    assert r.returncode == 0, r.stderr
    made = sorted(p.relative_to(repo).as_posix() for p in (repo / out).rglob("*") if p.is_file())
    assert any(p.endswith("ca.key") for p in made) and any(p.endswith("key.pem") for p in made)
    status = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all"],
        cwd=repo, capture_output=True, text=True, check=True,
    ).stdout.splitlines()
    private = [line for line in status if line.endswith((".key", "key.pem"))]
    assert private == [], status
