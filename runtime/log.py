"""One line per event on stderr, for the robot process and what it holds."""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Final, TextIO

__all__ = ["MAX_LINE", "Log", "one_line"]

MAX_LINE: Final = 400


def one_line(text: str, limit: int = MAX_LINE) -> str:
    """``text`` on one line (every run of whitespace one space), cut at ``limit`` characters."""
    line = " ".join(str(text).split())
    return line[:limit]


class Log:
    """One line per event on stderr; text by default, JSON with ``--json-logs``.

    Text: ``<name>: <event>[: <msg>] [k=v ...]``; JSON: one object with ``t``
    (Unix time, s), ``level``, ``src``, ``event``, ``msg`` and the fields.
    Safe to call from several threads.
    """

    LEVELS: Final[Mapping[str, int]] = MappingProxyType(
        {"debug": 10, "info": 20, "warning": 30, "error": 40}
    )

    def __init__(
        self, name: str, json_lines: bool, level: str = "info", stream: TextIO | None = None
    ) -> None:
        self.name = name
        self.json_lines = json_lines
        self.level = self.LEVELS[level]
        self.stream = stream if stream is not None else sys.stderr
        self._lock = threading.Lock()

    def __call__(self, level: str, event: str, msg: str = "", **fields: Any) -> None:
        if self.LEVELS[level] < self.level:
            return
        if self.json_lines:
            rec: dict[str, Any] = {
                "t": round(time.time(), 6),
                "level": level,
                "src": self.name,
                "event": event,
            }
            if msg:
                rec["msg"] = msg
            rec.update(fields)
            line = json.dumps(rec, default=str, separators=(",", ":"))
        else:
            extra = " ".join(f"{k}={v}" for k, v in fields.items())
            line = (
                f"{self.name}: {event}"
                + (f": {msg}" if msg else "")
                + (f" [{extra}]" if extra else "")
            )
        with self._lock:
            try:
                self.stream.write(line + "\n")
                self.stream.flush()
            except (OSError, ValueError):
                pass
