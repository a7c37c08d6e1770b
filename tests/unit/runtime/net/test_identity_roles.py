"""Each role speaks with its own identity only: the check every command makes at start."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from runtime.net.identity import (
    IdentityError,
    certificate_name,
    check_role,
    find_identity,
    load_identity,
)
from sim_bridge.launch.swarm_keys import create_swarm_keys


@pytest.fixture(scope="module")
def keys_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("keys") / "swarm"
    create_swarm_keys(out, "s1", 3)
    return out


def test_the_role_is_the_certificates_common_name(keys_dir: Path) -> None:
    for name in ("world", "robot-2", "operator", "router"):
        assert certificate_name(keys_dir / name) == name


@pytest.mark.parametrize("name, role, robot_id", [
    ("world", "world", None), ("router", "router", None), ("operator", "tool", None),
    ("robot-1", "robot", 1), ("robot-1", "robot", None),
])
def test_the_right_identity_passes(keys_dir: Path, name: str, role: str,
                                   robot_id: int | None) -> None:
    check_role(load_identity(keys_dir / name), role, robot_id)  # type: ignore[arg-type]


@pytest.mark.parametrize("name, role, robot_id, match", [
    ("robot-1", "world", None, "identity robot-1 cannot act as the world"),
    ("operator", "world", None, "cannot act as the world"),
    ("router", "world", None, "cannot act as the world"),
    ("robot-1", "router", None, "identity robot-1 cannot act as the router"),
    ("world", "router", None, "cannot act as the router"),
    ("robot-1", "tool", None, "cannot act as an operator's tool"),
    ("world", "tool", None, "cannot act as an operator's tool"),
    ("world", "robot", 1, "cannot speak for robot 1"),
    ("robot-2", "robot", 1, "cannot speak for robot 1"),
    ("operator", "robot", None, "is not a robot's"),
])
def test_another_roles_identity_is_refused_in_one_line(keys_dir: Path, name: str, role: str,
                                                       robot_id: int | None,
                                                       match: str) -> None:
    with pytest.raises(IdentityError, match=match) as e:
        find_identity(str(keys_dir / name), None, None, role, robot_id,  # type: ignore[arg-type]
                      "s1")
    assert "\n" not in str(e.value)


def test_tls_dir_with_another_name_is_refused(keys_dir: Path) -> None:
    with pytest.raises(IdentityError, match="cannot act as the world"):
        find_identity(None, str(keys_dir), "robot-1", "world", None, "s1")


def test_identity_json_cannot_rename_a_certificate(keys_dir: Path, tmp_path: Path) -> None:
    """The access rules go by the certificate: a relabelled robot is still a robot."""
    d = tmp_path / "robot-1-as-world"
    shutil.copytree(keys_dir / "robot-1", d)
    meta = json.loads((d / "identity.json").read_text())
    (d / "identity.json").write_text(json.dumps({**meta, "name": "world"}))
    with pytest.raises(IdentityError, match=r"cert\.pem is 'robot-1' but identity\.json says"):
        find_identity(str(d), None, None, "world", None, "s1")
