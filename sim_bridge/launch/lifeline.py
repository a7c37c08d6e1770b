"""The launcher's lifeline: whatever way ``patternrl launch`` ends, its children end with it.

:class:`Lifeline` starts a small reaper process (this module run as a script) in
a process group of its own, and keeps the only write end of a pipe whose read
end the reaper holds. Every child of the launcher (robots, router) is started
in the reaper's process group (``process_group=lifeline.group``), from the
fork on, so no child is ever outside it. When the pipe reads end of file --
the launcher closed it at the end of a run, or died, even by SIGKILL, since
the kernel closes a dead process's files -- the reaper sends SIGTERM to its
group, SIGKILL to what is left after a grace period, removes the directories
it made for the launcher (the run's keys, with the swarm authority's key) and
exits.

The group is not the terminal's foreground group, so a Ctrl-C still reaches
the launcher only, which stops its children itself (by PID) before closing
the lifeline. Keys the user gave (``--tls-dir``) are never the reaper's: it
removes only the directories it made itself (:meth:`Lifeline.make_dir`).

Linux only (process groups, ``/proc``), like the rest of the launcher.
"""

from __future__ import annotations

import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from runtime.errors import InputError

GRACE_S = 3.0
"""The reaper: SIGKILL what is left of the group this long after SIGTERM."""
START_TIMEOUT_S = 10.0
MAKE_DIR = b"d"
"""The one request on the pipe: make a private temporary directory, print its path."""
DIR_PREFIX = "patternrl-keys-"


class Lifeline:
    """The reaper process and the pipe's write end; :meth:`close` at the end of the run."""

    def __init__(self) -> None:
        r, w = os.pipe()  # both close on exec: no child but the reaper holds an end
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "sim_bridge.launch.lifeline", str(r)],
                pass_fds=(r,), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                process_group=0, cwd=os.getcwd())
        except BaseException:
            os.close(w)
            raise
        finally:
            os.close(r)
        self._w: int | None = w

    @property
    def group(self) -> int:
        """The process group every child of the launcher joins."""
        return self.proc.pid

    def make_dir(self) -> Path:
        """A private temporary directory the reaper removes when the launcher is gone."""
        assert self._w is not None and self.proc.stdout is not None
        os.write(self._w, MAKE_DIR)
        ready, _, _ = select.select([self.proc.stdout], [], [], START_TIMEOUT_S)
        line = self.proc.stdout.readline().decode(errors="replace").strip() if ready else ""
        if not line or not Path(line).is_dir():
            raise InputError("the launcher's reaper did not make the run's keys directory")
        return Path(line)

    def close(self, timeout_s: float = GRACE_S + 5.0) -> None:
        """Let the reaper go (it stops what is left of the group) and wait for it."""
        w, self._w = self._w, None
        if w is None:
            return
        os.close(w)
        try:
            self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()

    def __enter__(self) -> Lifeline:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ------------------------------------------------------------------------ the reaper


def _members(group: int) -> list[int]:
    """The live (not zombie) processes of a process group, this process left out."""
    me, found = os.getpid(), []
    for name in os.listdir("/proc"):
        if not name.isdigit() or int(name) == me:
            continue
        try:
            stat = (Path("/proc") / name / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rfind(")") + 2:].split()  # after "pid (comm) "
        if len(fields) > 2 and fields[0] != "Z" and int(fields[2]) == group:
            found.append(int(name))
    return found


def _stop_group(group: int, grace_s: float) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the group's SIGTERM is for the others
    try:
        os.killpg(group, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + grace_s
    while _members(group) and time.monotonic() < deadline:
        time.sleep(0.05)
    for pid in _members(group):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def reap(fd: int, grace_s: float = GRACE_S) -> int:
    """Serve ``make_dir`` requests until end of file on ``fd``, then stop the group and
    remove the directories made."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher answers Ctrl-C, not the reaper
    made: list[str] = []
    try:
        while True:
            try:
                data = os.read(fd, 64)
            except InterruptedError:
                continue
            if not data:
                break
            for _ in range(data.count(MAKE_DIR)):
                made.append(tempfile.mkdtemp(prefix=DIR_PREFIX))
                print(made[-1], flush=True)
    finally:
        _stop_group(os.getpgrp(), grace_s)
        for d in made:
            shutil.rmtree(d, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(reap(int(sys.argv[1])))
