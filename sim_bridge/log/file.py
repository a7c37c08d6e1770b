"""The MCAP file of a log: its records, read fast and recovered when cut short; repair.

A small, fast MCAP reader for this project's logs: it walks the records of the
file, decompresses each chunk whole (zstd, lz4 or none), checks its CRC and
yields its messages. A log whose writer was killed ends inside a record: reading
stops after the last complete chunk and :class:`Recovery` says how much was
read, how far into the file, and whether the log was finished (footer present).
The same messages as mcap's own ``NonSeekingReader`` (tests compare them, whole
and cut at many offsets), several times faster: what lets a 10,000-step,
20-robot log be read and analysed at over 100 k messages/s
(``benchmarks/replay_speed.py``).

:func:`iter_messages` yields every message with its channel;
:func:`sim_bridge.log.reader.read_log` walks the same :func:`blocks` with its own
loop to decode a whole run column-wise. :func:`repair` writes every recovered
message (same channels, schemas, log and publish times, sequence numbers) into a
new, finished, indexed MCAP file.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from runtime.errors import InputError


class LogError(InputError):
    """A file that is not a readable MCAP log; the message is one line."""


MAGIC: Final = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
RECORD: Final = struct.Struct("<BQ")
"""Every record's head: opcode, length of the body that follows."""
MESSAGE: Final = struct.Struct("<HIQQ")
"""A message record's head: channel id, sequence, log time, publish time; the payload follows."""
_CHUNK: Final = struct.Struct("<QQQI")  # start time, end time, uncompressed size, crc
_U16: Final = struct.Struct("<H")
_U32: Final = struct.Struct("<I")
_U64: Final = struct.Struct("<Q")


@dataclass(frozen=True)
class ChannelInfo:
    """One MCAP channel with its schema (schema id 0: none)."""

    id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]
    schema_id: int
    schema_name: str
    schema_encoding: str
    schema_data: bytes


@dataclass
class Recovery:
    """How much of a log could be read.

    ``finished``: the writer wrote its footer (a complete, indexed log).
    ``bytes_read``: where the last whole record read ends; the rest of the file
    (``file_bytes - bytes_read``) was an incomplete record, lost. ``corrupted``:
    some of the file is damaged rather than missing (a writer never leaves that).
    """

    messages: int = 0
    chunks: int = 0
    corrupted: bool = False
    """bytes in the middle of the log do not read (a chunk's CRC, a broken record), as
    opposed to a log merely cut short at its end"""
    corrupt_chunks: int = 0
    """chunks skipped for bad CRC or data (the records after them were still read)"""
    bytes_read: int = 0
    file_bytes: int = 0
    finished: bool = False
    error: str = ""
    profile: str = ""
    library: str = ""


def _string(buf: bytes | memoryview, p: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, p)
    end = p + 4 + n
    if end > len(buf):
        raise ValueError("string runs past its record")
    return bytes(buf[p + 4 : end]).decode("utf-8"), end


def _schema(body: bytes | memoryview) -> tuple[int, str, str, bytes]:
    (sid,) = _U16.unpack_from(body, 0)
    name, p = _string(body, 2)
    enc, p = _string(body, p)
    (n,) = _U32.unpack_from(body, p)
    return sid, name, enc, bytes(body[p + 4 : p + 4 + n])


def _channel(body: bytes | memoryview) -> tuple[int, int, str, str, dict[str, str]]:
    cid, sid = struct.unpack_from("<HH", body, 0)
    topic, p = _string(body, 4)
    enc, p = _string(body, p)
    (n,) = _U32.unpack_from(body, p)
    p += 4
    end = p + n
    meta: dict[str, str] = {}
    while p < end:
        k, p = _string(body, p)
        v, p = _string(body, p)
        meta[k] = v
    return cid, sid, topic, enc, meta


def _decompress(compression: str, data: bytes | memoryview, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        return bytes(zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=size))
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(bytes(data)))
    raise ValueError(f"unsupported chunk compression {compression!r}")


Raw = tuple[ChannelInfo, int, int, int, bytes]
"""(channel, log_time_ns, publish_time_ns, sequence, payload)"""


class Records:
    """Parses the records of one log (or one chunk) into messages, keeping channel state."""

    def __init__(self) -> None:
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, ChannelInfo] = {}

    def block(self, buf: bytes, out: list[Raw]) -> None:
        """Schemas, channels and messages of a chunk's records, appended to ``out``."""
        unpack_rec, unpack_msg = RECORD.unpack_from, MESSAGE.unpack_from
        channels = self.channels
        p, n = 0, len(buf)
        while p < n:
            if p + 9 > n:
                raise ValueError("chunk ends inside a record header")
            op, length = unpack_rec(buf, p)
            s = p + 9
            p = s + length
            if p > n:
                raise ValueError("chunk record runs past the chunk")
            if op == OP_MESSAGE:
                cid, seq, lt, pt = unpack_msg(buf, s)
                out.append((channels[cid], lt, pt, seq, buf[s + 22 : p]))
            else:
                self.other(op, memoryview(buf)[s:p])

    def other(self, op: int, body: memoryview) -> None:
        """Take in a record that is not a message (a schema or channel; others are ignored)."""
        if op == OP_SCHEMA:
            sid, name, enc, data = _schema(body)
            self.schemas[sid] = (name, enc, data)
        elif op == OP_CHANNEL:
            cid, sid, topic, enc, meta = _channel(body)
            if sid != 0 and sid not in self.schemas:
                raise ValueError(f"channel {cid} names unknown schema {sid}")
            sname, senc, sdata = self.schemas.get(sid, ("", "", b""))
            self.channels[cid] = ChannelInfo(cid, topic, enc, meta, sid, sname, senc, sdata)


def check_log_file(path: str | Path) -> Path:
    """``path`` if it is a readable file starting with the MCAP magic, else :class:`LogError`."""
    p = Path(path)
    if not p.exists():
        raise LogError(f"{p}: no such file")
    if not p.is_file():
        raise LogError(f"{p}: not a file")
    try:
        with open(p, "rb") as f:
            head = f.read(len(MAGIC))
    except OSError as e:
        raise LogError(f"{p}: cannot read: {e.strerror or e}") from None
    if head != MAGIC:
        raise LogError(f"{p}: not an MCAP file (no MCAP magic at the start)")
    return p


def blocks(path: str | Path, rec: Recovery) -> Iterator[bytes]:
    """The log's content as record sequences, up to the last complete chunk.

    Yields each chunk's records (decompressed, CRC checked) and each top-level
    schema, channel or message record (chunkless writers) as the bytes of that
    one record; consumers walk them with the same loop. Raises :class:`LogError` for a file that
    is missing or not an MCAP file; a log cut short is not an error: it stops,
    and ``rec`` says where and why.
    """
    p = check_log_file(path)
    data = p.read_bytes()
    n = len(data)
    rec.file_bytes = n
    pos = len(MAGIC)
    rec.bytes_read = pos
    # A file that ends with the magic was finished by its writer: any record that
    # does not read before the footer is damage, not a cut.
    ends_finished = n > 2 * len(MAGIC) and data[n - len(MAGIC):] == MAGIC
    while True:
        if pos + 9 > n:
            rec.error = ("the file ends without a footer: the writer did not finish"
                         if pos == n else f"incomplete record header at byte {pos}")
            rec.corrupted = rec.corrupted or ends_finished
            break
        op, length = RECORD.unpack_from(data, pos)
        s = pos + 9
        end = s + length
        if end > n:
            rec.error = f"incomplete record (opcode {op}) at byte {pos}: {end - n} bytes missing"
            rec.corrupted = rec.corrupted or ends_finished
            break
        out: bytes | None = None
        try:
            if op == OP_CHUNK:
                _, _, size, crc = _CHUNK.unpack_from(data, s)
                comp, q = _string(data, s + 28)
                (clen,) = _U64.unpack_from(data, q)
                if q + 8 + clen > end:
                    raise ValueError("chunk data runs past its record")
                out = _decompress(comp, memoryview(data)[q + 8 : q + 8 + clen], size)
                if len(out) != size:
                    raise ValueError(f"chunk decompressed to {len(out)} bytes, expected {size}")
                if crc != 0 and zlib.crc32(out) != crc:
                    raise ValueError("chunk CRC mismatch")
                rec.chunks += 1
            elif op == OP_MESSAGE or op == OP_SCHEMA or op == OP_CHANNEL:
                out = data[pos:end]
            elif op == OP_FOOTER:
                rec.finished = True
                rec.bytes_read = end
                if data[end : end + len(MAGIC)] == MAGIC:
                    rec.bytes_read = end + len(MAGIC)
                break
            elif op == OP_HEADER:
                rec.profile, q = _string(data, s)
                rec.library, _ = _string(data, q)
        except (ValueError, struct.error, UnicodeDecodeError) as e:
            rec.error = f"unreadable record (opcode {op}) at byte {pos}: {e}"[:200]
            rec.corrupted = True
            if op != OP_CHUNK:
                break
            rec.corrupt_chunks += 1  # its framing holds: skip it, read on
            out = None
        except Exception as e:  # a decompressor's own error types
            rec.error = f"unreadable chunk at byte {pos}: {type(e).__name__}: {e}"[:200]
            rec.corrupted = True
            rec.corrupt_chunks += 1
            out = None
        pos = end
        rec.bytes_read = end
        if out is not None:
            yield out
    if rec.bytes_read <= len(MAGIC) and not rec.profile and rec.error and not rec.corrupted:
        raise LogError(f"{p}: not a readable MCAP log ({rec.error})")


def iter_messages(path: str | Path, recovery: Recovery | None = None) -> Iterator[Raw]:
    """Every message of a log, in file order, up to the last complete chunk.

    Raises :class:`LogError` for a file that is missing or not an MCAP file; a
    log cut short is not an error: iteration stops and ``recovery`` tells.
    """
    rec = recovery if recovery is not None else Recovery()
    state = Records()
    batch: list[Raw] = []
    for buf in blocks(path, rec):
        try:
            state.block(buf, batch)  # the whole chunk first: a bad chunk yields nothing
        except (ValueError, KeyError, struct.error, UnicodeDecodeError) as e:
            rec.error = f"unreadable record inside a chunk: {e}"[:200]
            return
        rec.messages += len(batch)
        yield from batch
        batch.clear()


def repair(src: str | Path, dst: str | Path, chunk_size: int = 1 << 20) -> Recovery:
    """Copy every recoverable message of ``src`` into a finished, indexed MCAP at ``dst``."""
    from mcap.writer import CompressionType, Writer

    rec = Recovery()
    src_p, dst_p = Path(src), Path(dst)
    if src_p.resolve() == dst_p.resolve():
        raise LogError(f"{dst_p}: the repaired copy must not overwrite its source")
    check_log_file(src_p)
    dst_p.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst_p.with_name(dst_p.name + ".part")
    with open(tmp, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        started = False
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for ch, lt, pt, seq, payload in iter_messages(src_p, rec):
            if not started:
                writer.start(profile=rec.profile,
                             library=(rec.library + "; repaired by patternrl replay").lstrip("; "))
                started = True
            cid = channel_ids.get(ch.id)
            if cid is None:
                sid = 0
                if ch.schema_id != 0:
                    sid = schema_ids.get(ch.schema_id, 0)
                    if not sid:
                        sid = schema_ids[ch.schema_id] = writer.register_schema(
                            ch.schema_name, ch.schema_encoding, ch.schema_data)
                cid = channel_ids[ch.id] = writer.register_channel(
                    ch.topic, ch.message_encoding, sid, ch.metadata)
            writer.add_message(cid, lt, payload, pt, seq)
        if not started:
            writer.start(profile=rec.profile, library="patternrl replay (repaired, empty)")
        writer.finish()  # type: ignore[no-untyped-call]
    tmp.replace(dst_p)
    return rec
