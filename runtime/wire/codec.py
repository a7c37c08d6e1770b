"""The building blocks of the wire codecs in :mod:`runtime.wire.messages`.

The 2-byte header every payload starts with (tag, format version), field checks
shared by encoders and decoders and a bounds-checked payload reader. Every failure
is a :class:`MessageError` with a one-line reason; the messages' fields are laid out
in :mod:`runtime.wire.fields`, the messages themselves live in :mod:`runtime.wire.messages`.
"""

from __future__ import annotations

import json
import math
import struct
from enum import IntEnum
from typing import Any, Final, TypeAlias

Buffer: TypeAlias = bytes | bytearray | memoryview
"""What decoders accept: any contiguous bytes-like payload."""

U32: Final = (1 << 32) - 1
U64: Final = (1 << 64) - 1


class MessageError(ValueError):
    """A payload that is not a valid message, or a message that cannot be encoded."""


class Tag(IntEnum):
    """First byte of every payload: which message follows."""

    POSE = 1
    COMMAND = 2
    STATUS = 3
    PATTERN = 4
    BRAIN = 5
    POSES = 6
    VIEW = 7
    SLOTS = 8


VERSION: Final = 1
"""Format version of every message this build writes, but those in :data:`VERSIONS`."""
COMMAND_VERSION: Final = 2
"""Command format version this build writes: version 2 added the brain's own velocity."""
VERSIONS: Final[dict[int, int]] = {Tag.COMMAND: COMMAND_VERSION}
"""Tag -> the format version this build writes, where it is not :data:`VERSION`."""
READS: Final[dict[int, tuple[int, ...]]] = {Tag.COMMAND: (1, COMMAND_VERSION)}
"""Tag -> every format version this build decodes, where more than the one it writes."""


def reads(tag: int) -> tuple[int, ...]:
    """The format versions of ``tag`` this build decodes (the newest last)."""
    return READS.get(tag) or (VERSIONS.get(tag, VERSION),)


def tag_name(tag: int) -> str:
    try:
        return Tag(tag).name.lower()
    except ValueError:
        return "unknown"


def check_header(buf: Buffer, tag: Tag) -> int:
    """The format version of ``buf``; MessageError unless it starts with ``tag`` and a
    version this build reads (:func:`reads`)."""
    what = tag.name.lower()
    if len(buf) < 2:
        raise MessageError(f"truncated {what}: {len(buf)} bytes, no room for the 2-byte header")
    got = buf[0]
    if got != tag:
        raise MessageError(f"expected {what} (tag {int(tag)}), got {tag_name(got)} (tag {got})")
    ok = reads(tag)
    if buf[1] not in ok:
        known = " or ".join(map(str, ok))
        raise MessageError(f"unsupported {what} version {buf[1]} (this build reads {known})")
    return int(buf[1])


HEADER: Final = struct.Struct("<BB")
LEN32: Final = struct.Struct("<I")


def as_view(payload: object, what: str) -> memoryview:
    try:
        view = memoryview(payload)  # type: ignore[arg-type]
        return view if view.format == "B" and view.ndim == 1 else view.cast("B")
    except (TypeError, ValueError) as e:
        raise MessageError(
            f"{what} payload must be bytes-like, got {type(payload).__name__}"
        ) from e


def finite(what: str, name: str, value: float) -> float:
    if not math.isfinite(value):
        raise MessageError(f"{what}.{name} must be finite, got {value!r}")
    return value


def uint(what: str, name: str, value: object, limit: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise MessageError(f"{what}.{name} must be an int, got {type(value).__name__}")
    if not 0 <= value <= limit:
        raise MessageError(f"{what}.{name} must be in [0, {limit}], got {value}")
    return value


def utf8(what: str, name: str, value: object, max_bytes: int, max_chars: int = -1) -> bytes:
    if not isinstance(value, str):
        raise MessageError(f"{what}.{name} must be a str, got {type(value).__name__}")
    if 0 <= max_chars < len(value):
        raise MessageError(f"{what}.{name} is {len(value)} chars, at most {max_chars} allowed")
    try:
        raw = value.encode("utf-8")
    except UnicodeEncodeError as e:
        raise MessageError(f"{what}.{name} is not encodable as utf-8: {e.reason}") from None
    if len(raw) > max_bytes:
        raise MessageError(f"{what}.{name} is {len(raw)} bytes, at most {max_bytes} allowed")
    return raw


def read_text(what: str, name: str, raw: Buffer, max_chars: int = -1) -> str:
    try:
        value = bytes(raw).decode("utf-8")
    except UnicodeDecodeError as e:
        raise MessageError(f"{what}.{name} is not valid utf-8: {e.reason}") from None
    if 0 <= max_chars < len(value):
        raise MessageError(f"{what}.{name} is {len(value)} chars, at most {max_chars} allowed")
    return value


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise MessageError("JSON repeats a key")
    return out


def _no_constant(token: str) -> object:
    raise MessageError(f"JSON holds non-finite number {token}")


def json_object(what: str, text: str) -> dict[str, Any]:
    """``text`` as a JSON object: MessageError for bad JSON, repeated keys, NaN or Infinity."""
    try:
        body = json.loads(text, object_pairs_hook=_no_duplicates, parse_constant=_no_constant)
    except MessageError as e:
        raise MessageError(f"{what} {e}") from None
    except (ValueError, RecursionError) as e:
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise MessageError(f"{what} is not valid JSON: {reason}") from None
    if not isinstance(body, dict):
        raise MessageError(f"{what} JSON must be an object, got {type(body).__name__}")
    return body


class Reader:
    """Walks a payload from ``start``, turning every shortfall into MessageError."""

    __slots__ = ("_pos", "_view", "_what")

    def __init__(self, view: memoryview, what: str, start: int) -> None:
        self._view = view
        self._what = what
        self._pos = start

    def unpack(self, fmt: struct.Struct, name: str) -> tuple[Any, ...]:
        end = self._pos + fmt.size
        if end > len(self._view):
            raise MessageError(
                f"truncated {self._what}: {len(self._view)} bytes, {name} needs {end}"
            )
        out = fmt.unpack_from(self._view, self._pos)
        self._pos = end
        return out

    def take(self, n: int, name: str) -> memoryview:
        end = self._pos + n
        if end > len(self._view):
            raise MessageError(
                f"truncated {self._what}: {name} claims {n} bytes, "
                f"only {len(self._view) - self._pos} left"
            )
        out = self._view[self._pos : end]
        self._pos = end
        return out

    def finish(self) -> None:
        extra = len(self._view) - self._pos
        if extra:
            raise MessageError(f"{extra} trailing bytes after {self._what}")

