"""The identities of one ``patternrl launch`` run: made for the run, or the user's, or none.

By default the launcher makes a fresh swarm authority and one identity per
member in a private temporary directory (removed when the run ends, and by the
launcher's reaper, :mod:`sim_bridge.launch.lifeline`, if the launcher dies), so the
demo runs with mutual TLS and access control with nothing to set up; its
``operator`` identity is printed, for ``patternrl swap --identity`` during the
run. ``--tls-dir DIR`` uses keys made by ``patternrl keys create`` instead;
``--insecure`` runs open TCP on loopback.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from runtime.errors import InputError
from runtime.net.identity import OPERATOR, WORLD, IdentityError, find_identity
from sim_bridge.launch.swarm_keys import create_swarm_keys


@dataclass
class RunKeys:
    """Where the run's identities are (``dir`` None: open TCP)."""

    dir: Path | None
    note: str
    _made: Path | None = field(default=None, repr=False)

    @property
    def scheme(self) -> str:
        return "tcp" if self.dir is None else "tls"

    def tool_flags(self, swarm: str, port: int) -> str:
        """The flags that reach this run from ``patternrl record`` or ``swap``, ready to paste."""
        who = "--insecure" if self.dir is None else f"--tls-dir {self.dir}"
        return f"--swarm {swarm} --zenoh-port {port} {who}"

    def world_args(self, args: argparse.Namespace) -> argparse.Namespace:
        """The launcher's options with the world's identity in them."""
        out = argparse.Namespace(**vars(args))
        if self.dir is not None:
            out.identity, out.tls_dir, out.identity_as = None, str(self.dir), WORLD
        return out

    def close(self) -> None:
        """Remove keys made for this run (never the user's own)."""
        if self._made is not None:
            shutil.rmtree(self._made, ignore_errors=True)
            self._made = None


def _temporary_dir() -> Path:
    return Path(tempfile.mkdtemp(prefix="patternrl-keys-"))


def run_keys(args: argparse.Namespace, swarm: str,
             make_dir: Callable[[], Path] = _temporary_dir) -> RunKeys:
    """The run's identities from ``--insecure`` / ``--tls-dir``; InputError on a bad mix.

    ``make_dir``: makes the private directory of keys made for the run (the launcher's
    :meth:`sim_bridge.launch.lifeline.Lifeline.make_dir`)."""
    if getattr(args, "identity", None) is not None or getattr(args, "identity_as", None):
        raise InputError("launch speaks as every member of its swarm: give --tls-dir DIR "
                         "(from 'patternrl keys create'), not --identity/--as")
    tls_dir = getattr(args, "tls_dir", None)
    if getattr(args, "insecure", False):
        if tls_dir is not None:
            raise InputError("--insecure runs without identities: drop --tls-dir")
        return RunKeys(None, ", open TCP (--insecure)")
    if tls_dir is not None:
        try:
            world = find_identity(None, tls_dir, WORLD, "world", None, swarm)
        except IdentityError as e:
            raise InputError(f"--tls-dir: {e} (launch --swarm must be the keys' swarm)") from None
        if world.robots < args.robots:
            raise InputError(f"--tls-dir {tls_dir} has identities for {world.robots} robots, "
                             f"not {args.robots}")
        return RunKeys(Path(tls_dir), f", mutual TLS, keys {tls_dir}")
    tmp = make_dir()
    try:
        made = create_swarm_keys(tmp, swarm, max(int(args.robots), 1))
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return RunKeys(made.out, f", mutual TLS; operator identity {made.out / OPERATOR}", tmp)
