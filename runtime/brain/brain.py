"""Brains: "observation in, action out", learned (ONNX) or rule-based (numpy).

A brain is anything with ``brain_id``, ``spec`` (the :class:`ObservationSpec` it
reads), ``manifest`` and ``act(obs) -> velocities``. Two kinds ship here:

:class:`OnnxBrain`
    An ONNX graph run by onnxruntime on one thread without spinning. Contract:
    input ``obs`` float32 ``[batch, obs_dim]`` (dynamic batch), output
    ``action`` float32 ``[batch, 2]`` already in m/s (the policy mean), and
    optionally ``std``. The graph holds everything from raw observation to
    action (normalisation, encoder, policy head). A brain with memory
    (``spec.frames`` > 1) also takes ``memory`` float32 ``[batch, spec.memory_dim]``
    and answers ``memory_out`` of the same shape, the state its caller hands back
    in at the next step (:meth:`OnnxBrain.act_memory`; ``act`` alone starts from zeros).

:class:`RuleBrain` (``rule:assign``)
    Pure numpy on the general observation: drive straight to the slot of the
    shared assignment at up to v_max and stop there (velocity = slot vector /
    dt, clipped to v_max). The first baseline, and what exercises the whole
    runtime without a trained brain.

:class:`runtime.decision.rules.FrameRule` (``rule:frame``, ``rule:frame-travel``)
    Team rules: straight lines in one frame fixed per pattern, every robot
    arriving at the same step (fewer metres than ``rule:assign`` for the same
    or a few more steps). :data:`RULES` is the registry of every rule name;
    :func:`make_rule` builds one. Rules are code, not files: no signature.

Manifest (:mod:`runtime.brain.manifest`). Every ONNX brain carries a
:class:`BrainManifest` twice: as a sidecar ``<stem>.json`` next to
``<stem>.onnx`` (with ``brain_id``), and inside the ONNX metadata (without).
:func:`read_brain_file`, the one reader of brain files (the robot's
:func:`load_brain`, ``patternrl swap`` and the trainer all use it), prefers
the sidecar and falls back on the metadata. A swap message names a rule brain
with the manifest ``{"rule": "rule:assign"}`` and no ONNX bytes
(:func:`load_sent_brain`).

Validation (:func:`validate_brain_bytes`, used for files and for hot swaps)
refuses a brain with a one-line :class:`BrainError` when its digest does not
match, it is not signed by a key of ``trust`` (when given: the robot always
gives its trusted keys, :mod:`runtime.brain.signing`; rule brains need no
signature), onnxruntime cannot load it, its inputs/outputs do not match the spec
the manifest declares, or it answers non-finite values on a fixed set of
seeded probe observations. A brain that passes is warmed before it is
returned, so its first real decision is as fast as the next ones.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Protocol, runtime_checkable

import numpy as np
import onnxruntime as ort
from numpy.typing import NDArray

from runtime.brain.checks import (
    ACTION_NAME,
    INPUT_NAME,
    MEMORY_NAME,
    MEMORY_OUT_NAME,
    check_io,
    probe,
    probe_observations,
)
from runtime.brain.manifest import (
    METADATA_KEY,
    BrainError,
    BrainManifest,
    error_line,
)
from runtime.brain.signing import TrustedKeys, verify_manifest
from runtime.decision.observation import ObservationSpec
from runtime.decision.rules import FRAME_RULES, FrameRule
from runtime.errors import InputError
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "METADATA_KEY",
    "RULE_ASSIGN",
    "Brain",
    "BrainError",
    "BrainFile",
    "BrainManifest",
    "OnnxBrain",
    "RuleBrain",
    "brain_digest",
    "load_brain",
    "load_sent_brain",
    "make_rule",
    "open_brain",
    "probe_observations",
    "read_brain_file",
    "short_id",
    "sidecar_path",
    "validate_brain_bytes",
]


RULE_PREFIX: Final = "rule:"
RULE_ASSIGN: Final = "rule:assign"
RULES: Final = (RULE_ASSIGN, *FRAME_RULES)
"""The rule registry: every name ``--brain rule:NAME`` accepts, in the robot,
``eval``, ``launch --brains`` and the benchmarks."""
RULE_KEY: Final = "rule"
"""The key of the manifest a swap sends for a rule brain: ``{"rule": "rule:assign"}``."""


def brain_digest(onnx_bytes: bytes) -> str:
    """A brain's id: the sha256 hex digest of its ONNX bytes."""
    return hashlib.sha256(onnx_bytes).hexdigest()


def sidecar_path(onnx_path: str | Path) -> Path:
    """The manifest file of a brain: ``<stem>.json`` next to ``<stem>.onnx``."""
    p = Path(onnx_path)
    return p.with_suffix(".json")


# -------------------------------------------------------------------- interface


@runtime_checkable
class Brain(Protocol):
    """Observation in, action out. ``act`` is deterministic (the policy mean)."""

    brain_id: str
    spec: ObservationSpec
    manifest: BrainManifest | None

    def act(self, obs: NDArray[Any]) -> Array:
        """(m, spec.dim) observations -> (m, 2) velocities in m/s (float64)."""
        ...


class RuleBrain:
    """``rule:assign``: straight to the shared-assignment slot at up to v_max, then stop."""

    def __init__(self, world: WorldConfig = DEFAULT_WORLD, k_neighbours: int = 6) -> None:
        self.brain_id = RULE_ASSIGN
        self.spec = ObservationSpec("general", k_neighbours=k_neighbours)
        self.manifest: BrainManifest | None = None
        self._inv_dt = 1.0 / world.dt_s
        self._v_max = world.v_max_mps

    def act(self, obs: NDArray[Any]) -> Array:
        o = np.asarray(obs)
        if o.shape[0] == 1:  # the robot's path: plain floats beat numpy on 2 numbers
            vx = float(o[0, 0]) * self._inv_dt
            vy = float(o[0, 1]) * self._inv_dt
            speed = math.hypot(vx, vy)
            if speed > self._v_max:
                f = self._v_max / speed
                vx, vy = vx * f, vy * f
            return np.array([[vx, vy]])
        v = np.asarray(o[:, 0:2], dtype=np.float64) * self._inv_dt
        sp = np.hypot(v[:, 0], v[:, 1])
        scale = np.where(sp > self._v_max, self._v_max / np.maximum(sp, 1e-300), 1.0)
        out: Array = v * scale[:, None]
        return out


def _session_options() -> ort.SessionOptions:
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.add_session_config_entry("session.inter_op.allow_spinning", "0")
    so.log_severity_level = 3
    return so


def _new_session(onnx_bytes: bytes) -> ort.InferenceSession:
    try:
        return ort.InferenceSession(
            onnx_bytes, sess_options=_session_options(), providers=["CPUExecutionProvider"]
        )
    except Exception as e:  # onnxruntime raises several private exception types
        raise BrainError(f"onnxruntime cannot load the brain: {error_line(e)}") from None


class OnnxBrain:
    """An ONNX policy run by onnxruntime (one intra-op thread, no spinning)."""

    def __init__(
        self,
        session: ort.InferenceSession,
        brain_id: str,
        spec: ObservationSpec,
        manifest: BrainManifest | None = None,
    ) -> None:
        self.brain_id = brain_id
        self.spec = spec
        self.manifest = manifest
        self._session = session
        self._outputs = [ACTION_NAME]
        self._one = np.zeros((1, spec.dim), dtype=np.float32)  # the robot's reused input
        self._feed: dict[str, NDArray[np.float32]] = {INPUT_NAME: self._one}
        self.memory_dim = spec.memory_dim
        """The memory this brain carries in and out (0: none)."""
        if self.memory_dim:
            self._feed[MEMORY_NAME] = np.zeros((1, self.memory_dim), dtype=np.float32)
        self._run = self._fast_run(session)
        self._out1 = np.zeros((1, 2), dtype=np.float32)  # act_input's output, bound once
        self._run_bound = None if self.memory_dim else self._bound_run(session)

    def _fast_run(self, session: ort.InferenceSession) -> Any:
        """``session.run`` without its Python wrapper when the binding allows (~4 us less).

        The wrapper re-checks names and types on every call; our feed is fixed and
        checked once at validation. Falls back on the public call if the private
        binding is missing or answers differently.
        """
        public = session.run
        raw = getattr(session, "_sess", None)
        if raw is None or not hasattr(ort, "RunOptions"):
            return public
        options = ort.RunOptions()

        def run(outputs: list[str], feed: dict[str, Any]) -> Any:
            return raw.run(outputs, feed, options)

        try:
            a = run(self._outputs, self._feed)[0]
            b = public(self._outputs, self._feed)[0]
            if np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True):
                return run
        except Exception:
            pass
        return public

    def _bound_run(self, session: ort.InferenceSession) -> Any:
        """A run of the one-row input into :attr:`_out1` with both bound once (onnxruntime's
        IO binding: no feed dictionary, no output array a call; ~2 us less), or None where
        the binding is missing or answers differently from :meth:`act`."""
        raw = getattr(session, "_sess", None)
        if raw is None or not hasattr(ort, "RunOptions"):
            return None
        try:
            io = session.io_binding()
            io.bind_cpu_input(INPUT_NAME, self._one)
            io.bind_output(ACTION_NAME, "cpu", 0, np.float32, [1, 2], self._out1.ctypes.data)
            bound, options = io._iobinding, ort.RunOptions()

            def run() -> None:
                raw.run_with_iobinding(bound, options)

            saved = self._one.copy()
            try:
                for probe in (0.0, 0.5):  # the bound run reads the row and writes the output
                    self._one.fill(probe)
                    run()
                    want = np.asarray(self._run(self._outputs, self._feed)[0])
                    if not np.array_equal(self._out1, want, equal_nan=True):
                        return None
            finally:
                self._one[:] = saved
            return run
        except Exception:
            return None

    def act(self, obs: NDArray[Any]) -> Array:
        """The velocities (m/s) for ``obs``; a brain with memory starts from zeros."""
        if obs.shape[0] == 1:
            self._one[0] = obs[0]  # cast in place: no allocation on the robot's path
            feed = self._feed
        else:
            feed = {INPUT_NAME: np.ascontiguousarray(obs, dtype=np.float32)}
            if self.memory_dim:
                feed[MEMORY_NAME] = np.zeros((len(obs), self.memory_dim), dtype=np.float32)
        out = self._run(self._outputs, feed)[0]
        return np.asarray(out, dtype=np.float64)

    def act_memory(self, obs: NDArray[Any], memory: NDArray[Any]
                   ) -> tuple[Array, NDArray[np.float32]]:
        """(velocities (m, 2) m/s, the next memory (m, memory_dim) float32) for rows ``obs``
        (m, dim) and the memory they carry (m, memory_dim): a brain with memory's step."""
        if not self.memory_dim:
            return self.act(obs), np.zeros((len(obs), 0), dtype=np.float32)
        feed = {INPUT_NAME: np.ascontiguousarray(obs, dtype=np.float32),
                MEMORY_NAME: np.ascontiguousarray(memory, dtype=np.float32)}
        action, nxt = self._run([ACTION_NAME, MEMORY_OUT_NAME], feed)
        return np.asarray(action, dtype=np.float64), np.asarray(nxt, dtype=np.float32)

    @property
    def input_row(self) -> NDArray[np.float32]:
        """The reused (dim,) input of :meth:`act_input`: the robot writes its row here."""
        row: NDArray[np.float32] = self._one[0]
        return row

    def act_input(self) -> tuple[float, float]:
        """The velocity (m/s) for the row in :attr:`input_row`: :meth:`act` of one row,
        with nothing converted or allocated on the way in."""
        if self._run_bound is None:
            vx, vy = self._run(self._outputs, self._feed)[0][0].tolist()
        else:
            self._run_bound()
            vx, vy = self._out1[0].tolist()
        return float(vx), float(vy)

    @property
    def session(self) -> ort.InferenceSession:
        return self._session


# ------------------------------------------------------------------- validation


def _validate_session(
    session: ort.InferenceSession,
    manifest: BrainManifest,
    digest: str,
    world: WorldConfig,
) -> OnnxBrain:
    check_io(session, manifest.observation)
    brain = OnnxBrain(session, digest, manifest.observation, manifest)
    probe(brain, world)
    return brain


def validate_brain_bytes(
    onnx_bytes: bytes,
    manifest: BrainManifest,
    expected_digest: str,
    world: WorldConfig = DEFAULT_WORLD,
    trust: TrustedKeys | None = None,
) -> OnnxBrain:
    """Check a brain fully and return it loaded and warmed, or raise :class:`BrainError`.

    Refuses: bytes whose sha256 differs from ``expected_digest`` (or from the
    manifest's ``brain_id`` when it has one), bytes onnxruntime cannot load,
    inputs/outputs that do not match the manifest's observation spec, and
    non-finite outputs on :func:`probe_observations`; with ``trust``, a
    manifest not signed by one of its keys (checked before onnxruntime reads a byte).
    """
    return _validate_bytes(bytes(onnx_bytes), manifest, expected_digest, world, None, trust)


def _validate_bytes(
    data: bytes,
    manifest: BrainManifest,
    expected_digest: str,
    world: WorldConfig,
    session: ort.InferenceSession | None,
    trust: TrustedKeys | None = None,
) -> OnnxBrain:
    digest = brain_digest(data)
    if digest != expected_digest:
        raise BrainError(
            f"digest mismatch: bytes hash to {digest[:12]}, expected {expected_digest[:12]}"
        )
    if manifest.brain_id and manifest.brain_id != digest:
        raise BrainError(
            f"digest mismatch: bytes hash to {digest[:12]}, manifest says {manifest.brain_id[:12]}"
        )
    if trust is not None:
        try:
            verify_manifest(manifest.to_dict(with_id=True), digest, trust)
        except InputError as e:
            raise BrainError(str(e)) from None
    if session is None:
        session = _new_session(data)
    brain = _validate_session(session, manifest, digest, world)
    manifest.brain_id = digest
    return brain


# -------------------------------------------------------------- reading a brain file


@dataclass(frozen=True)
class BrainFile:
    """A brain as named on a command line, read but not yet validated.

    ``data`` is the ONNX bytes (empty for a rule brain), ``manifest`` its
    manifest (None for a rule brain) with ``file`` filled in, and ``brain_id``
    the manifest's id, else the sha256 of ``data`` (the rule's name for a rule
    brain). A sidecar may name other bytes than ``data``: the robots judge that.
    """

    ref: str
    data: bytes
    manifest: BrainManifest | None
    brain_id: str
    # the onnxruntime session opened to read the metadata, reused to validate
    session: ort.InferenceSession | None = field(default=None, compare=False, repr=False)

    @property
    def rule(self) -> str | None:
        """The rule's name (``rule:assign``) for a rule brain, else None."""
        return self.ref if self.manifest is None else None

    def wire_manifest(self) -> str:
        """The manifest text a brain swap carries: see :func:`load_sent_brain`."""
        if self.manifest is None:
            return json.dumps({RULE_KEY: self.ref})
        return self.manifest.to_json(indent=None)


def _known_rule(ref: str) -> str:
    if ref not in RULES:
        raise BrainError(f"unknown rule brain '{ref}' (known: {', '.join(RULES)})")
    return ref


def read_brain_file(ref: str, *, sidecar: bool = True) -> BrainFile:
    """Read ``rule:assign`` or an ``.onnx`` brain with its manifest: the one brain reader.

    The manifest is the sidecar ``<stem>.json`` when there is one (and
    ``sidecar``), else the ONNX metadata under :data:`METADATA_KEY`. Raises
    :class:`BrainError` with a one-line reason: unknown rule, missing or
    unreadable file, no manifest, a manifest that does not parse.
    """
    if ref.startswith(RULE_PREFIX):
        return BrainFile(_known_rule(ref), b"", None, ref)
    path = Path(ref)
    if not path.is_file():
        raise BrainError(f"brain file not found: {ref}")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise BrainError(f"cannot read brain {ref}: {error_line(e)}") from None
    session = None
    side = sidecar_path(path)
    if sidecar and side.is_file() and side != path:
        try:
            text = side.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise BrainError(f"cannot read manifest {side}: {error_line(e)}") from None
        manifest = BrainManifest.from_json(text)
    else:
        try:
            session = _new_session(data)
        except BrainError as e:  # name the file: the user may have given several
            raise BrainError(f"{ref}: {e}") from None
        meta = session.get_modelmeta().custom_metadata_map
        if METADATA_KEY not in meta:
            raise BrainError(f"brain {ref} has no manifest: neither {side.name} nor ONNX metadata")
        manifest = BrainManifest.from_json(meta[METADATA_KEY])
    if not manifest.brain_id:
        manifest.brain_id = brain_digest(data)
    if not manifest.file:
        manifest.file = path.name
    return BrainFile(ref, data, manifest, manifest.brain_id, session)


def open_brain(
    file: BrainFile, world: WorldConfig = DEFAULT_WORLD, trust: TrustedKeys | None = None
) -> Brain:
    """The brain of a :class:`BrainFile`, validated and warmed (:func:`validate_brain_bytes`)."""
    if file.manifest is None:
        return make_rule(file.ref, world)
    return _validate_bytes(file.data, file.manifest, file.brain_id, world, file.session, trust)


def make_rule(name: str, world: WorldConfig = DEFAULT_WORLD) -> Brain:
    """The rule brain called ``name`` (one of :data:`RULES`); :class:`BrainError` if unknown."""
    _known_rule(name)
    if name == RULE_ASSIGN:
        return RuleBrain(world)
    return FrameRule(name, world)


def load_brain(
    ref: str, world: WorldConfig = DEFAULT_WORLD, trust: TrustedKeys | None = None
) -> Brain:
    """``rule:assign`` or a path to a ``.onnx`` brain (sidecar manifest, else metadata).

    Raises :class:`BrainError` with a one-line reason for anything unusable
    (with ``trust``: a brain not signed by one of its keys).
    """
    return open_brain(read_brain_file(ref), world, trust)


def load_sent_brain(
    manifest_json: str,
    onnx_bytes: bytes,
    world: WorldConfig = DEFAULT_WORLD,
    trust: TrustedKeys | None = None,
) -> Brain:
    """The brain a swap message carries, validated; :class:`BrainError` if unusable.

    The convention (:meth:`BrainFile.wire_manifest`): a manifest ``{"rule":
    "rule:assign"}`` with no ONNX bytes names a rule brain; anything else is a
    :class:`BrainManifest` whose ``brain_id`` the bytes must hash to.
    """
    try:
        raw = json.loads(manifest_json)
    except (ValueError, RecursionError):
        raw = None
    if isinstance(raw, dict) and RULE_KEY in raw and not onnx_bytes:
        return open_brain(read_brain_file(str(raw[RULE_KEY])), world)
    manifest = BrainManifest.from_json(manifest_json)
    if not manifest.brain_id:
        raise BrainError("manifest has no brain_id (the sha256 of the ONNX bytes)")
    return validate_brain_bytes(onnx_bytes, manifest, manifest.brain_id, world, trust)


def short_id(brain_id: str) -> str:
    """A brain id for people: a rule's name, or the first 12 hex digits of a digest."""
    return brain_id if brain_id.startswith(RULE_PREFIX) else brain_id[:12]
