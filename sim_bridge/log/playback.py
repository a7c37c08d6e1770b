"""Play a log back onto Zenoh: every recorded wire message, on its key, with its timing.

What ``ros2 bag play`` does for a bag, for this project's MCAP logs. The channels
of the project's keys (poses, commands, statuses, views, patterns, brains) hold every
field of the Zenoh messages (protobuf; :mod:`sim_bridge.log.schemas`), so
play-back encodes each one back into its wire payload (old logs, ``patternrl-wire``,
hold the payloads byte for byte, foreign keys included) and puts it on its key, in file
order, each at its recorded ``log_time`` relative to the first message played,
divided by ``rate``. The ``/world/*`` JSON topics are the world's own notes, not
Zenoh traffic, and are not played, nor are Foxglove's views (``/tf``,
``/robot/<id>/pose``) and ``/log/other``.

* ``topics``: which channels to play: key expressions (``*`` one chunk, ``**``
  any, matched against the recorded key and the key it is played on) or kinds
  (``pose``, ``cmd``, ``status``, ``view``, ``pattern``, ``brain``: the key's last chunk).
* ``start_s``: skip the first seconds of the log (from its first message).
* ``swarm``: republish under another swarm name (``patternrl/<old>/...`` ->
  ``patternrl/<swarm>/...``, :func:`runtime.wire.keys.with_swarm`), so a live swarm is
  not disturbed; a recorded key that is not one of the project's keys cannot be
  moved to another swarm and is not played then.
* ``loops``: play the log this many times (0: until stopped).
* ``wait_subscribers_s``: before the first message, wait up to this long until
  some subscriber matches one of the keys (Zenoh drops what nobody hears).

Stopping: setting ``stop`` (the CLI's SIGINT/SIGTERM handler does) ends the
play-back between two messages, at once, even in a long pause.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from runtime.wire import keys
from sim_bridge.log import schemas as pb
from sim_bridge.log.file import LogError, Recovery, iter_messages
from sim_bridge.log.layout import WIRE_ENCODING, channel_kind

KINDS = (keys.POSE, keys.CMD, keys.STATUS, keys.PATTERN, keys.OPERATOR_PATTERN, keys.BRAIN,
         keys.VIEW)


@dataclass
class Recording:
    """The messages to play, loaded before playing so reading never delays a message."""

    times_ns: list[int]
    key_index: list[int]
    payloads: list[bytes]
    keys: list[str]
    """key expressions played on (after any swarm rename)"""
    source_swarms: list[str]
    recovery: Recovery


@dataclass
class PlayResult:
    messages: int
    loops: int
    seconds: float
    interrupted: bool
    matched: bool
    """Whether a subscriber matched before the first message (when waiting was asked)."""


def _topic_filter(topics: Sequence[str] | None) -> Callable[[str, str], bool]:
    """A predicate (recorded key, played key) -> play it; LogError for a bad filter."""
    if not topics:
        return lambda _a, _b: True
    import zenoh

    exprs: list[Any] = []
    kinds: set[str] = set()
    for t in topics:
        if "/" in t:
            try:
                exprs.append(zenoh.KeyExpr(t))
            except Exception as e:  # zenoh.ZError
                raise LogError(f"--topics {t!r} is not a key expression: {e}") from None
        elif t in KINDS:
            kinds.add(t)
        else:
            raise LogError(f"--topics {t!r}: not a key expression nor one of {', '.join(KINDS)}")

    def keep(recorded: str, played: str) -> bool:
        parsed = keys.parse_key(recorded)
        if parsed is not None and parsed.kind in kinds:
            return True
        for e in exprs:
            for k in (recorded, played):
                try:
                    if e.intersects(zenoh.KeyExpr(k)):
                        return True
                except Exception:  # a recorded key that is no valid key expression
                    continue
        return False

    return keep


def _rename(topic: str, swarm: str | None) -> tuple[str, str | None]:
    """(swarm the key belongs to or "", the key to play on or None: not playable in ``swarm``)."""
    k = keys.parse_key(topic)
    if k is None:
        return "", topic if swarm is None else None
    return k.swarm, topic if swarm is None else keys.with_swarm(topic, swarm)


def load_recording(
    path: str | Path,
    topics: Sequence[str] | None = None,
    start_s: float = 0.0,
    swarm: str | None = None,
) -> Recording:
    """The wire messages of a log selected for play-back (LogError for bad input)."""
    if swarm is not None:
        try:
            keys.validate_swarm(swarm)
        except ValueError as e:
            raise LogError(str(e)) from None
    if not start_s >= 0.0:
        raise LogError(f"--start must be >= 0 seconds, got {start_s}")
    keep = _topic_filter(topics)
    rec = Recovery()
    times: list[int] = []
    index: list[int] = []
    payloads: list[bytes] = []
    key_of: dict[int, int] = {}  # channel id -> index in played keys, -1 to skip
    played: list[str] = []
    swarms: set[str] = set()
    t_first: int | None = None
    t_from = 0
    for ch, lt, _pt, _seq, data in iter_messages(path, rec):
        if t_first is None:
            t_first = lt
            t_from = lt + int(start_s * 1e9)
        k = key_of.get(ch.id)
        if k is None:
            k = -1
            if ch.message_encoding == WIRE_ENCODING or channel_kind(
                    ch.topic, ch.message_encoding, ch.schema_name)[0]:
                old, new = _rename(ch.topic, swarm)
                if new is not None and keep(ch.topic, new):
                    if old:
                        swarms.add(old)
                    if new in played:
                        k = played.index(new)
                    else:
                        played.append(new)
                        k = len(played) - 1
            key_of[ch.id] = k
        if k < 0 or (start_s > 0 and lt < t_from):
            continue
        if ch.message_encoding != WIRE_ENCODING:
            try:
                data = pb.to_wire(ch.schema_name, data)
            except (ValueError, TypeError):  # does not encode back (another writer's)
                continue
        times.append(lt)
        index.append(k)
        payloads.append(data)
    return Recording(times, index, payloads, played, sorted(swarms), rec)


def play(
    session: Any,
    rec: Recording,
    rate: float = 1.0,
    loops: int = 1,
    stop: threading.Event | None = None,
    wait_subscribers_s: float = 0.0,
    log: Callable[[str], None] | None = None,
    linger_s: float = 0.5,
) -> PlayResult:
    """Put every message of ``rec`` on ``session`` with its recorded timing / ``rate``.

    ``loops`` 0 plays until ``stop`` is set. Messages are put in file order; a
    message whose time has passed (a slow machine) goes out at once, so order
    is always kept. Publishers block rather than drop when the transport queue is
    full (a fast ``rate``), and after the last message the session is given
    ``linger_s`` (cut short by ``stop``) to deliver what is still queued before
    the caller closes it.
    """
    import zenoh

    if not (rate > 0.0):
        raise ValueError(f"rate must be > 0, got {rate}")
    stop = stop if stop is not None else threading.Event()
    pubs = [session.declare_publisher(k, express=True,
                                      congestion_control=zenoh.CongestionControl.BLOCK,
                                      reliability=zenoh.Reliability.RELIABLE)
            for k in rec.keys]
    matched = True
    try:
        if wait_subscribers_s > 0 and pubs:
            deadline = time.monotonic() + wait_subscribers_s
            matched = False
            while not stop.is_set():
                if any(p.matching_status.matching for p in pubs):
                    matched = True
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    if log is not None:
                        log(f"no subscriber matched after {wait_subscribers_s:g} s: playing anyway")
                    break
                stop.wait(min(left, 0.01))
        n = len(rec.payloads)
        sent = done = 0
        t_start = time.monotonic()
        interrupted = stop.is_set()
        times, index, payloads = rec.times_ns, rec.key_index, rec.payloads
        while n and not interrupted and (loops == 0 or done < loops):
            t_wall0 = time.monotonic()
            t_log0 = times[0]
            scale = 1.0 / (rate * 1e9)
            for j in range(n):
                wait = t_wall0 + (times[j] - t_log0) * scale - time.monotonic()
                if (wait > 0 and stop.wait(wait)) or stop.is_set():
                    interrupted = True
                    break
                pubs[index[j]].put(payloads[j])
                sent += 1
            else:
                done += 1
        seconds = time.monotonic() - t_start
        if sent and not interrupted:
            stop.wait(linger_s)
        return PlayResult(sent, done, seconds, interrupted, matched)
    finally:
        for p in pubs:
            try:
                p.undeclare()
            except Exception:  # the session is already closed
                pass
