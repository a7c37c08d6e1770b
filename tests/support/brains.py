"""ONNX test brains: a tanh MLP of any observation spec, written as the trainer's export writes
a brain (``<name>.onnx`` + its ``<name>.json`` manifest), optionally signed.

- :func:`mlp_model`: the ONNX model alone (random weights, seeded); :func:`trainer_sized_mlp`
  one of the trainer's policy size;
- :func:`write_brain`: any model written with its manifest, embedded and/or beside it, and the
  ways to break it (truncated bytes, a digest of other bytes, no signature, another key);
- :func:`write_test_brain`: an MLP brain of an observation kind in one call, signed by the test
  run's own key unless told otherwise (what robots started by the tests trust);
- :func:`onnx_brain`: an MLP brain loaded in memory, no file;
- :func:`copy_shipped_brain`: a shipped brain of ``exports/`` copied, to change it freely.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from runtime.brain.brain import METADATA_KEY, BrainManifest, OnnxBrain, validate_brain_bytes
from runtime.decision.observation import ObservationSpec
from support import ROOT

GENERAL = ObservationSpec("general", k_neighbours=6)
"""The general observation spec (the robots' default)."""


def mlp_model(
    in_dim: int,
    hidden: tuple[int, ...] = (16,),
    *,
    seed: int = 0,
    out_std: float | None = 0.5,
    gain: float = 1.0,
    nan: bool = False,
    out_dim: int = 2,
    fixed_batch: bool = False,
    input_name: str = "obs",
    name: str = "policy",
) -> onnx.ModelProto:
    """A tanh MLP ``obs -> action`` (m/s) with random weights drawn from ``seed``.

    Hidden layers are drawn N(0, 1/sqrt(fan-in)); the output layer N(0, ``out_std``) (None:
    1/sqrt(fan-in)) times ``gain``. ``hidden=()`` gives a linear brain. ``nan`` poisons every
    output; ``out_dim``, ``fixed_batch`` (batch 1 instead of a dynamic batch) and
    ``input_name`` give models the runtime must refuse.
    """
    rng = np.random.default_rng(seed)
    nodes, inits = [], []
    prev, d = input_name, in_dim
    for i, h in enumerate(hidden):
        w = rng.normal(0, 1 / np.sqrt(d), (d, h)).astype(np.float32)
        inits += [
            numpy_helper.from_array(w, f"W{i}"),
            numpy_helper.from_array(np.zeros(h, np.float32), f"b{i}"),
        ]
        nodes += [
            helper.make_node("Gemm", [prev, f"W{i}", f"b{i}"], [f"g{i}"]),
            helper.make_node("Tanh", [f"g{i}"], [f"h{i}"]),
        ]
        prev, d = f"h{i}", h
    std = 1 / np.sqrt(d) if out_std is None else out_std
    w = (rng.normal(0, std, (d, out_dim)) * gain).astype(np.float32)
    inits += [
        numpy_helper.from_array(w, "Wo"),
        numpy_helper.from_array(np.zeros(out_dim, np.float32), "bo"),
    ]
    if nan:
        inits.append(numpy_helper.from_array(np.array([np.nan], np.float32), "poison"))
        nodes += [
            helper.make_node("Gemm", [prev, "Wo", "bo"], ["mean"]),
            helper.make_node("Mul", ["mean", "poison"], ["action"]),
        ]
    else:
        nodes.append(helper.make_node("Gemm", [prev, "Wo", "bo"], ["action"]))
    batch: str | int = 1 if fixed_batch else "batch"
    graph = helper.make_graph(
        nodes,
        name,
        [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, [batch, in_dim])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, [batch, out_dim])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def trainer_sized_mlp(in_dim: int, seed: int = 0) -> onnx.ModelProto:
    """A random MLP of the trainer's policy size (256-128-128), small outputs."""
    hidden = (256, 128, 128)
    return mlp_model(in_dim, hidden, seed=seed, out_std=0.1 / np.sqrt(hidden[-1]))


def write_brain(
    directory: Path,
    name: str,
    spec: ObservationSpec = GENERAL,
    model: onnx.ModelProto | None = None,
    *,
    pattern: str | None = None,
    n_robots: int | None = None,
    sidecar: bool = True,
    metadata: bool = True,
    corrupt: bool = False,
    wrong_digest: bool = False,
    sign: bool | Path = False,
) -> Path:
    """Write ``<name>.onnx`` (+ ``<name>.json``) in ``directory`` as the trainer's export does.

    ``model``: default a :func:`mlp_model` of ``spec``. The manifest names ``pattern`` and
    ``n_robots`` (default the spec's own, if any); ``metadata`` embeds it in the model,
    ``sidecar`` writes it beside. ``corrupt`` writes truncated bytes, ``wrong_digest`` a
    manifest naming other bytes. ``sign``: by the test run's own key (``True``), by the private
    key file ``sign``, or not at all (``False``). Returns the ``.onnx`` path.
    """
    model = model if model is not None else mlp_model(spec.dim)
    manifest = BrainManifest(
        observation=spec,
        file=f"{name}.onnx",
        pattern=pattern,
        n_robots=n_robots if n_robots is not None else (spec.n_robots or None),
        training={"algorithm": "test"},
    )
    if metadata:
        entry = model.metadata_props.add()
        entry.key, entry.value = METADATA_KEY, manifest.to_json(with_id=False)
    data = model.SerializeToString()
    if corrupt:
        data = data[: len(data) // 2]
    path = directory / f"{name}.onnx"
    path.write_bytes(data)
    if not sidecar:
        return path
    manifest.brain_id = hashlib.sha256(data).hexdigest()
    if sign is not False:
        from runtime.brain.signing import load_private_key, sign_manifest, user_key

        key = load_private_key(user_key() or "" if sign is True else sign)
        manifest.signature = sign_manifest(manifest.to_dict(), manifest.brain_id, key)
    if wrong_digest:
        manifest.brain_id = hashlib.sha256(data + b"other").hexdigest()
    path.with_suffix(".json").write_text(manifest.to_json())
    return path


def observation_spec(obs: str | ObservationSpec, n_robots: int | None = None) -> ObservationSpec:
    """``obs`` as a spec: a kind's default spec (a paper spec for ``n_robots`` robots)."""
    if isinstance(obs, ObservationSpec):
        return obs
    return ObservationSpec(obs, n_robots=n_robots or 0) if obs == "paper" else ObservationSpec(obs)


def write_test_brain(
    directory: Path,
    name: str,
    obs: str | ObservationSpec = "general",
    pattern: str | None = None,
    n_robots: int | None = None,
    *,
    seed: int = 0,
    hidden: tuple[int, ...] = (32, 32),
    out_std: float | None = None,
    gain: float = 0.5,
    in_dim: int | None = None,
    nan: bool = False,
    corrupt: bool = False,
    wrong_digest: bool = False,
    sign: bool | Path = True,
) -> Path:
    """An MLP brain ``<name>.onnx`` of observation ``obs`` with its sidecar manifest, signed by
    the test run's own key unless ``sign`` says otherwise (see :func:`write_brain`).

    It passes the runtime's validation (shapes, finite outputs) but forms nothing. ``in_dim``
    other than the spec's dim gives a wrong-shape brain, ``nan`` a brain whose every output is
    NaN; ``hidden``, ``out_std`` and ``gain`` shape the network (see :func:`mlp_model`).
    """
    spec = observation_spec(obs, n_robots)
    model = mlp_model(spec.dim if in_dim is None else in_dim, hidden, seed=seed,
                      out_std=out_std, gain=gain, nan=nan, name=name)
    return write_brain(directory, name, spec, model, pattern=pattern, n_robots=n_robots,
                       corrupt=corrupt, wrong_digest=wrong_digest, sign=sign)


def onnx_brain(spec: ObservationSpec, seed: int = 0, hidden: tuple[int, ...] = (32, 32)
               ) -> OnnxBrain:
    """A random MLP brain of ``spec`` loaded in memory (validated as a received brain is)."""
    data = mlp_model(spec.dim, hidden, seed=seed).SerializeToString()
    return validate_brain_bytes(data, BrainManifest(observation=spec),
                                hashlib.sha256(data).hexdigest())


def copy_shipped_brain(directory: Path, name: str = "general") -> Path:
    """``exports/<name>.onnx`` and its manifest copied to ``directory`` as ``b.onnx`` +
    ``b.json``; returns the ``.onnx`` path."""
    for suffix in (".onnx", ".json"):
        (directory / f"b{suffix}").write_bytes((ROOT / "exports" / f"{name}{suffix}").read_bytes())
    return directory / "b.onnx"
