"""A Zenoh router in its own process: ``python zenoh_router.py IDENTITY_DIR ENDPOINT...``.

Stands in for ``zenohd`` (not needed installed): router mode, the router's
identity (mutual TLS and the swarm's access rules, enforced on what it relays),
listening on the endpoints given. Prints ``ready`` once listening; runs until
SIGTERM or SIGINT.
"""

from __future__ import annotations

import signal
import sys
import threading

from runtime.net.identity import load_identity
from runtime.net.session import make_config, open_config


def main(argv: list[str]) -> int:
    ident, listen = load_identity(argv[0]), argv[1:]
    stop = threading.Event()
    for s in (signal.SIGTERM, signal.SIGINT):
        signal.signal(s, lambda *_: stop.set())
    with open_config(make_config("router", [], listen, identity=ident)):
        print("ready", flush=True)
        stop.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
