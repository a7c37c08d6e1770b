"""A brain's manifest: what a brain is, in the file format every brain shares.

Every ONNX brain carries its :class:`BrainManifest` twice: as a sidecar
``<stem>.json`` next to ``<stem>.onnx`` (with ``brain_id``), and inside the
ONNX ``metadata_props`` under :data:`METADATA_KEY` (without ``brain_id``,
which is the sha256 hex digest of the ONNX bytes and so cannot be inside
them). Reading a brain file is :func:`runtime.brain.brain.read_brain_file`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Final

from runtime.decision.observation import ObservationError, ObservationSpec
from runtime.errors import InputError
from runtime.world_config import DEFAULT_WORLD

__all__ = ["FORMAT", "FORMAT_VERSION", "METADATA_KEY", "BrainError", "BrainManifest"]

FORMAT: Final = "patternrl-brain"
FORMAT_VERSION: Final = 1
METADATA_KEY: Final = "patternrl_manifest"


class BrainError(InputError):
    """A brain that cannot be used; the message is one line."""


def error_line(e: BaseException | str) -> str:
    """The first line of an error's text (at most 300 characters), or its type's name."""
    text = str(e).strip()
    first = text.splitlines()[0] if text else type(e).__name__
    return first[:300]


@dataclass
class BrainManifest:
    """What a brain is: its observation and action specs, provenance and scores."""

    observation: ObservationSpec
    action: dict[str, Any] = field(
        default_factory=lambda: {
            "kind": "cartesian",
            "v_max_mps": DEFAULT_WORLD.v_max_mps,
            "dt_s": DEFAULT_WORLD.dt_s,
        }
    )
    brain_id: str = ""
    file: str = ""
    pattern: str | None = None
    n_robots: int | None = None
    world: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    evaluation: dict[str, Any] = field(default_factory=dict)
    format: str = FORMAT
    format_version: int = FORMAT_VERSION
    signature: dict[str, str] | None = None
    """ed25519 signature over the ONNX bytes and this manifest (:mod:`runtime.brain.signing`)."""

    def to_dict(self, *, with_id: bool = True) -> dict[str, Any]:
        """The manifest as JSON data; ``with_id=False`` leaves out brain_id and signature."""
        d: dict[str, Any] = {
            "format": self.format,
            "format_version": self.format_version,
        }
        if with_id:
            d["brain_id"] = self.brain_id
        d.update(
            file=self.file,
            observation=self.observation.to_dict(),
            action=dict(self.action),
            pattern=self.pattern,
            n_robots=self.n_robots,
            world=dict(self.world),
            training=dict(self.training),
            evaluation=dict(self.evaluation),
        )
        if with_id and self.signature is not None:
            d["signature"] = dict(self.signature)
        return d

    def to_json(self, *, with_id: bool = True, indent: int | None = 2) -> str:
        """JSON text; ``with_id=False`` is what goes into the ONNX metadata."""
        return json.dumps(self.to_dict(with_id=with_id), indent=indent, allow_nan=False)

    @staticmethod
    def from_dict(d: object) -> BrainManifest:
        """Parse and check a manifest; raises :class:`BrainError` with a one-line reason."""
        if not isinstance(d, dict):
            raise BrainError(f"manifest must be a JSON object, got {type(d).__name__}")
        fmt = d.get("format")
        if fmt != FORMAT:
            raise BrainError(f"manifest format is {fmt!r}, expected {FORMAT!r}")
        ver = d.get("format_version")
        if ver != FORMAT_VERSION:
            raise BrainError(
                f"manifest format_version {ver!r} unsupported (reads {FORMAT_VERSION})"
            )
        obs = d.get("observation")
        if not isinstance(obs, dict):
            raise BrainError("manifest lacks an 'observation' object")
        try:
            spec = ObservationSpec.from_dict(obs)
        except ObservationError as e:
            raise BrainError(f"manifest observation: {error_line(e)}") from None
        action = d.get("action")
        if not isinstance(action, dict):
            raise BrainError("manifest lacks an 'action' object")
        if action.get("kind") != "cartesian":
            raise BrainError(f"manifest action kind {action.get('kind')!r} unsupported")
        for key in ("v_max_mps", "dt_s"):
            v = action.get(key)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not (math.isfinite(v) and v > 0)
            ):
                raise BrainError(f"manifest action.{key} must be a positive number, got {v!r}")
        brain_id = d.get("brain_id", "")
        if not isinstance(brain_id, str):
            raise BrainError("manifest brain_id must be a string")
        pattern = d.get("pattern")
        if pattern is not None and not isinstance(pattern, str):
            raise BrainError("manifest pattern must be a string or null")
        n_robots = d.get("n_robots")
        if n_robots is not None and (
            isinstance(n_robots, bool) or not isinstance(n_robots, int) or n_robots < 1
        ):
            raise BrainError("manifest n_robots must be a positive int or null")
        dicts: dict[str, dict[str, Any]] = {}
        for key in ("world", "training", "evaluation"):
            v = d.get(key, {})
            if v is None:
                v = {}
            if not isinstance(v, dict):
                raise BrainError(f"manifest {key} must be an object")
            dicts[key] = v
        file = d.get("file", "")
        signature = d.get("signature")
        if signature is not None and not (
            isinstance(signature, dict)
            and all(isinstance(k, str) and isinstance(v, str) for k, v in signature.items())
        ):
            raise BrainError("manifest signature must be an object of strings")
        return BrainManifest(
            observation=spec,
            action=dict(action),
            brain_id=brain_id,
            file=str(file) if file is not None else "",
            pattern=pattern,
            n_robots=n_robots,
            world=dicts["world"],
            training=dicts["training"],
            evaluation=dicts["evaluation"],
            signature=signature,
        )

    @staticmethod
    def from_json(text: str | bytes) -> BrainManifest:
        try:
            d = json.loads(text)
        except (ValueError, RecursionError) as e:
            raise BrainError(f"manifest is not valid JSON: {error_line(e)}") from None
        return BrainManifest.from_dict(d)

    @property
    def v_max_mps(self) -> float:
        return float(self.action["v_max_mps"])

    @property
    def dt_s(self) -> float:
        return float(self.action["dt_s"])
