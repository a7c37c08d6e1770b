"""Recorded poses and commands as columns: a batch of wire payloads decoded at once.

The payloads of today's logs (protobuf ``patternrl.RobotPose`` / ``RobotCommand``)
are viewed with the fixed layouts of :mod:`sim_bridge.log.schemas`; a payload in
another layout (another writer) is parsed by protobuf, one by one. Those of old
logs (``patternrl-wire``) are viewed with the numpy layouts of :mod:`runtime.wire.messages`
(:data:`~runtime.wire.messages.POSE_DTYPE`, :func:`~runtime.wire.messages.command_dtype`),
which are derived, as the very struct formats the robots and the world encode with
are, from the field tables of :mod:`runtime.wire.fields`. A payload that does not
decode (wrong size, tag or version, a non-finite value, a robot id other than its
key's) is counted as malformed and dropped, as the robots and the world drop it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from runtime.types import Array, BoolArray, IntArray
from runtime.wire.codec import reads
from runtime.wire.fields import POSE
from runtime.wire.messages import POSE_DTYPE, VERSION, Tag, command_dtype
from sim_bridge.log import schemas as pb

_POSE_FIELDS = POSE.names()
_POSE_FLOATS = tuple(f.name for f in POSE.fields if f.kind == "f64")


def _finite(rec: NDArray[Any], names: tuple[str, ...]) -> BoolArray:
    """Where every column ``names`` of ``rec`` is finite."""
    good: BoolArray = np.isfinite(rec[names[0]])
    for name in names[1:]:
        good &= np.isfinite(rec[name])
    return good


@dataclass
class Commands:
    """Every recorded command, column-wise (length m), in file order."""

    robot_id: IntArray
    step: IntArray
    v: Array
    """(m, 2) m/s"""
    safety_changed: BoolArray
    brain_index: IntArray
    """(m,) index into :attr:`brain_ids` of the brain that decided each command"""
    brain_ids: list[str]
    """the brain ids on the log (one run has one or a few: stored once)"""
    brain_v: Array
    """(m, 2) m/s: what the brain asked for, before the clamp and the safety filter (``v``
    where the log predates it)"""

    @property
    def brain(self) -> list[str]:
        """Brain id of each command."""
        return [self.brain_ids[i] for i in self.brain_index.tolist()]

    def brain_counts(self, sel: BoolArray) -> dict[str, int]:
        """Brain id -> commands it decided among ``sel`` (m,), in order of first appearance."""
        codes, first, counts = np.unique(self.brain_index[sel], return_index=True,
                                         return_counts=True)
        out: dict[str, int] = {}
        for k in np.argsort(first, kind="stable").tolist():
            name = self.brain_ids[int(codes[k])]
            out[name] = out.get(name, 0) + int(counts[k])
        return out

    def select(self, sel: BoolArray) -> Commands:
        """The commands where ``sel`` (m,) holds."""
        return Commands(self.robot_id[sel], self.step[sel], self.v[sel], self.safety_changed[sel],
                        self.brain_index[sel], self.brain_ids, self.brain_v[sel])

    def concat(self, other: Commands) -> Commands:
        """These commands, then ``other``'s (file order is the caller's: see ``order``)."""
        if not len(other.step):
            return self
        if not len(self.step):
            return other
        return Commands(
            np.concatenate([self.robot_id, other.robot_id]),
            np.concatenate([self.step, other.step]), np.concatenate([self.v, other.v]),
            np.concatenate([self.safety_changed, other.safety_changed]),
            np.concatenate([self.brain_index, other.brain_index + len(self.brain_ids)]),
            self.brain_ids + other.brain_ids, np.concatenate([self.brain_v, other.brain_v]))

    @staticmethod
    def empty() -> Commands:
        return Commands(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)),
                        np.zeros(0, bool), np.zeros(0, np.int64), [], np.zeros((0, 2)))


@dataclass
class Frames:
    """The recorded poses as a dense table: one row per recorded step, one column per robot.

    ``steps`` (S,) sorted; ``ids`` (m,) robot ids, sorted; ``xy`` (S, m, 2) metres,
    NaN where a robot has no pose at that step; ``present`` (S, m);
    ``first_msg`` (S,) the message index of each step's first pose (file order).
    """

    steps: IntArray
    ids: IntArray
    xy: Array
    present: BoolArray
    first_msg: IntArray

    def row(self, step: int) -> int:
        """Row of ``step``, or -1 when no pose of it was recorded."""
        k = int(np.searchsorted(self.steps, step))
        return k if k < len(self.steps) and self.steps[k] == step else -1

    def at(self, step: int) -> tuple[IntArray, Array]:
        """(robot ids (k,), positions (k, 2) metres) of the robots with a pose at ``step``,
        in id order; :class:`KeyError` when no pose of that step was recorded."""
        k = self.row(step)
        if k < 0:
            raise KeyError(step)
        here = self.present[k]
        return self.ids[here], self.xy[k, here]

    def rows(self, first_step: int, last_step: int) -> IntArray:
        """Rows of the recorded steps in [first_step, last_step]."""
        lo = int(np.searchsorted(self.steps, first_step))
        hi = int(np.searchsorted(self.steps, last_step, side="right"))
        return np.arange(lo, hi, dtype=np.int64)


def decode_poses(raw: list[bytes], idx: list[int], key_rid: list[int]
                 ) -> tuple[NDArray[Any], IntArray, int]:
    """Pose payloads as structured records (:data:`runtime.wire.messages.POSE_DTYPE`).

    ``idx`` is each payload's message index, ``key_rid`` the robot id on its key.
    Returns (the good records, their message indices, how many were malformed).
    """
    size = POSE_DTYPE.itemsize
    bad = 0
    if set(map(len, raw)) - {size}:  # rare: payloads of the wrong size are malformed
        ok_len = [k for k, b in enumerate(raw) if len(b) == size]
        bad = len(raw) - len(ok_len)
        raw = [raw[k] for k in ok_len]
        idx = [idx[k] for k in ok_len]
        key_rid = [key_rid[k] for k in ok_len]
    rec = np.frombuffer(b"".join(raw), dtype=POSE_DTYPE)
    good = (
        (rec["tag"] == Tag.POSE) & (rec["version"] == VERSION) & _finite(rec, _POSE_FLOATS)
        & (rec["robot_id"].astype(np.int64) == np.asarray(key_rid, np.int64))
    )
    bad += int((~good).sum())
    return rec[good], np.asarray(idx, np.int64)[good], bad


def _command_columns(rec: NDArray[Any], order: IntArray, blen: int,
                     brain_ids: list[str]) -> tuple[Any, ...]:
    """Columns of a batch of decoded command records whose brain ids are ``blen`` bytes.

    New brain ids are appended to ``brain_ids``; each row's index points into it. Records
    without ``brain_vx``, ``brain_vy`` (older layouts) give ``v`` as the brain velocity.
    """
    if blen:
        names, inv = np.unique(rec["brain"], return_inverse=True)
        index = inv.astype(np.int64).reshape(-1) + len(brain_ids)
        brain_ids += [bytes(b).decode("utf-8", "replace") for b in names]
    else:
        index = np.full(len(rec), len(brain_ids), np.int64)
        brain_ids.append("")
    v = np.stack([rec["vx"], rec["vy"]], axis=1).astype(np.float64).reshape(-1, 2)
    bv = (np.stack([rec["brain_vx"], rec["brain_vy"]], axis=1).astype(np.float64).reshape(-1, 2)
          if "brain_vx" in (rec.dtype.names or ()) else v.copy())
    return (rec["robot_id"].astype(np.int64), rec["step"].astype(np.int64), v,
            rec["safety_changed"].astype(bool), index, order, bv)


_Cols = tuple[IntArray, IntArray, Array, BoolArray, IntArray, IntArray, Array]


def _joined(raw: list[bytes], ks: list[int]) -> bytes:
    return b"".join(raw) if len(ks) == len(raw) else b"".join([raw[k] for k in ks])


def _gather(cols: list[_Cols], brain_ids: list[str], sel: IntArray | None = None) -> Commands:
    """One :class:`Commands` of column batches ``cols``, rows ``sel`` of their concatenation
    (all, in batch order, when None)."""
    parts = [np.concatenate([c[j] for c in cols]) for j in (0, 1, 2, 3, 4, 6)]
    if sel is not None:
        parts = [p[sel] for p in parts]
    rid, step, v, changed, index, bv = parts
    return Commands(rid, step, v, changed, index, brain_ids, bv)


def decode_commands(raw: list[bytes], key_rid: list[int], idx: list[int] | None = None
                    ) -> tuple[Commands, int]:
    """Command payloads (wire format version 1 or 2) as :class:`Commands`, in the order
    given; (commands, malformed).

    ``idx`` (message indices) is accepted for symmetry with :func:`decode_commands_pb`.
    """
    lengths = list(map(len, raw))
    by_len: dict[int, list[int]] = {}
    if len(set(lengths)) == 1:  # the usual case: one brain id length for the whole run
        by_len[lengths[0]] = list(range(len(raw)))
    else:
        for k, n in enumerate(lengths):
            by_len.setdefault(n, []).append(k)
    groups: list[tuple[int, int, list[int]]] = []  # (length, format version, positions)
    for length, ks in by_len.items():
        if length < 2:
            groups.append((length, -1, ks))
            continue
        versions = np.frombuffer(_joined(raw, ks), np.uint8)[1::length]
        for version in np.unique(versions).tolist():
            sel = versions == version
            groups.append((length, version, ks if sel.all() else
                           [ks[k] for k in np.flatnonzero(sel).tolist()]))
    cols: list[_Cols] = []
    brain_ids: list[str] = []
    bad = 0
    for length, version, ks in groups:
        if version not in reads(Tag.COMMAND):
            bad += len(ks)
            continue
        blen = length - command_dtype(0, version).itemsize
        if blen < 0:
            bad += len(ks)
            continue
        rec = np.frombuffer(_joined(raw, ks), dtype=command_dtype(blen, version))
        good = (
            (rec["tag"] == Tag.COMMAND) & (rec["brain_len"] == blen) & (rec["safety_changed"] <= 1)
            & np.isfinite(rec["vx"]) & np.isfinite(rec["vy"])
            & (rec["robot_id"].astype(np.int64) == np.asarray([key_rid[k] for k in ks]))
        )
        if "brain_vx" in (rec.dtype.names or ()):
            good &= np.isfinite(rec["brain_vx"]) & np.isfinite(rec["brain_vy"])
        bad += int((~good).sum())
        cols.append(_command_columns(rec[good], np.asarray(ks, np.int64)[good], blen, brain_ids))
    if not cols:
        return Commands.empty(), bad
    order = np.argsort(np.concatenate([c[5] for c in cols]), kind="stable")
    return _gather(cols, brain_ids, order), bad


def frames_of(rec: NDArray[Any], idx: IntArray) -> Frames:
    """The dense table of pose records ``rec`` (message indices ``idx``)."""
    if len(rec) == 0:
        return Frames(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 0, 2)),
                      np.zeros((0, 0), bool), np.zeros(0, np.int64))
    step = rec["step"].astype(np.int64)
    rid = rec["robot_id"].astype(np.int64)
    steps, srow = np.unique(step, return_inverse=True)
    ids, rcol = np.unique(rid, return_inverse=True)
    xy = np.full((len(steps), len(ids), 2), np.nan)
    xy[srow, rcol, 0] = rec["x"]  # a pose recorded twice: the later one stands
    xy[srow, rcol, 1] = rec["y"]
    present = np.zeros((len(steps), len(ids)), bool)
    present[srow, rcol] = True
    first = np.full(len(steps), np.iinfo(np.int64).max, np.int64)
    np.minimum.at(first, srow, idx)
    return Frames(steps, ids, xy, present, first)


# -- today's layout (protobuf) -----------------------------------------------------------


def _fixed(raw: list[bytes], size: int) -> tuple[list[int], list[int]]:
    """Positions of the payloads of ``size`` bytes, and of the others."""
    if not (set(map(len, raw)) - {size}):
        return list(range(len(raw))), []
    ok = [k for k, b in enumerate(raw) if len(b) == size]
    okset = set(ok)
    return ok, [k for k in range(len(raw)) if k not in okset]


def _tags_ok(rec: NDArray[Any], tags: dict[str, int]) -> BoolArray:
    good = np.ones(len(rec), bool)
    for name, t in tags.items():
        good &= rec[name] == t
    return good


def _parse_each(name: str, raw: list[bytes], ks: list[int]) -> tuple[list[Any], list[int], int]:
    """Parse the payloads ``ks`` one by one: (messages, their positions, how many failed)."""
    out, pos, bad = [], [], 0
    for k in ks:
        try:
            out.append(pb.parse(name, raw[k]))
            pos.append(k)
        except ValueError:
            bad += 1
    return out, pos, bad


def decode_poses_pb(raw: list[bytes], idx: list[int], key_rid: list[int]
                    ) -> tuple[NDArray[Any], IntArray, int]:
    """``patternrl.RobotPose`` payloads as :data:`runtime.wire.messages.POSE_DTYPE` records.

    Same contract as :func:`decode_poses`: (good records, their message indices, malformed).
    """
    if not raw:
        return np.zeros(0, POSE_DTYPE), np.zeros(0, np.int64), 0
    ok, other = _fixed(raw, pb.POSE_PB_DTYPE.itemsize)
    rec = np.frombuffer(b"".join(raw) if not other else b"".join(raw[k] for k in ok),
                        dtype=pb.POSE_PB_DTYPE)
    fixed = _tags_ok(rec, pb.POSE_PB_TAGS)
    if not fixed.all():
        other += [ok[k] for k in np.flatnonzero(~fixed).tolist()]
        ok = [ok[k] for k in np.flatnonzero(fixed).tolist()]
        rec = rec[fixed]
    msgs, pos, bad = _parse_each(pb.ROBOT_POSE, raw, other)
    out = np.zeros(len(ok) + len(msgs), POSE_DTYPE)
    out["tag"], out["version"] = Tag.POSE, VERSION
    for f in _POSE_FIELDS:
        out[f][: len(ok)] = rec[f]
        out[f][len(ok):] = [getattr(m, f) for m in msgs]
    order = ok + pos
    rid = np.asarray(key_rid, np.int64)[order]
    good = _finite(out, _POSE_FLOATS) & (out["robot_id"].astype(np.int64) == rid)
    bad += int((~good).sum())
    sort = np.argsort(np.asarray(idx, np.int64)[order][good], kind="stable")
    return out[good][sort], np.asarray(idx, np.int64)[order][good][sort], bad


def decode_commands_pb(raw: list[bytes], key_rid: list[int], idx: list[int]
                       ) -> tuple[Commands, int]:
    """``patternrl.RobotCommand`` payloads as :class:`Commands`, in message order.

    Today's fixed layout first, then the older one (no brain velocity), then protobuf.
    """
    if not raw:
        return Commands.empty(), 0
    by_len: dict[int, list[int]] = {}
    lengths = list(map(len, raw))
    if len(set(lengths)) == 1:
        by_len[lengths[0]] = list(range(len(raw)))
    else:
        for k, n in enumerate(lengths):
            by_len.setdefault(n, []).append(k)
    cols: list[_Cols] = []
    brain_ids: list[str] = []
    other: list[int] = []
    for length, ks in by_len.items():
        for old, tags in ((False, pb.COMMAND_PB_TAGS), (True, pb.COMMAND_PB_TAGS_V1)):
            blen = length - pb.command_pb_dtype(0, old).itemsize
            if not ks or not 0 <= blen <= pb.MAX_FIXED_BRAIN_BYTES:
                continue
            rec = np.frombuffer(_joined(raw, ks), dtype=pb.command_pb_dtype(blen, old))
            fixed = _tags_ok(rec, tags) & (rec["brain_len"] == blen) & (
                rec["safety_changed"] <= 1)
            cols.append(_command_columns(rec[fixed], np.asarray(ks, np.int64)[fixed], blen,
                                         brain_ids))
            ks = [ks[k] for k in np.flatnonzero(~fixed).tolist()]
        other += ks
    msgs, pos, bad = _parse_each(pb.ROBOT_COMMAND, raw, other)
    if msgs:
        index = np.arange(len(msgs), dtype=np.int64) + len(brain_ids)
        brain_ids += [str(m.brain_id) for m in msgs]
        cols.append((np.asarray([m.robot_id for m in msgs], np.int64),
                     np.asarray([m.step for m in msgs], np.uint64).astype(np.int64),
                     np.asarray([(m.vx, m.vy) for m in msgs], np.float64).reshape(-1, 2),
                     np.asarray([m.safety_changed for m in msgs], bool),
                     index, np.asarray(pos, np.int64),
                     np.asarray([pb.brain_velocity(m) for m in msgs], np.float64).reshape(-1, 2)))
    if not cols:
        return Commands.empty(), bad
    pos_all = np.concatenate([c[5] for c in cols])
    rid = np.concatenate([c[0] for c in cols])
    v = np.concatenate([c[2] for c in cols])
    bv = np.concatenate([c[6] for c in cols])
    good = ((rid == np.asarray(key_rid, np.int64)[pos_all]) & np.isfinite(v).all(axis=1)
            & np.isfinite(bv).all(axis=1))
    bad += int((~good).sum())
    order = np.argsort(np.asarray(idx, np.int64)[pos_all][good], kind="stable")
    return _gather(cols, brain_ids, np.flatnonzero(good)[order]), bad
