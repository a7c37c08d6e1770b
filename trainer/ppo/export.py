"""Export a trained agent as a brain: one ONNX graph plus its manifest.

The graph holds everything from the raw observation to the action::

    obs [batch, D] -> Reshape, Gather, ReduceSum, MatMul, Less ...    front end (paper brains)
                   -> Sub(shift) -> Mul(scale) -> Clip(+-5)          normaliser
                   -> Gemm -> Relu -> Gemm                          encoder (Pattern-RL only)
                   -> Gemm -> Relu -> Gemm -> Relu -> Gemm -> Relu  policy trunk 256-128-128
                   -> Gemm -> Tanh -> Mul(v_max)                    "action" [batch, 2], m/s
                   -> Gemm -> Softplus -> Add(min) -> Mul(v_max)    "std"    [batch, 2], m/s

A brain with memory (``TrainConfig.memory_frames`` > 1) first puts ``memory`` behind
``obs`` (Concat) and answers the newest rows of that as ``memory_out`` (Slice).

**Why the graph is built from the weights with ``onnx.helper``, not
``torch.onnx.export``.** torch 2.13's default exporter is the dynamo one, which
needs ``onnxscript`` (not a dependency here) and whose output graph changes
with torch versions; the legacy TorchScript exporter (``dynamo=False``) is
deprecated. The network is a fixed chain of affine layers and element-wise
activations, so writing the ~20 nodes by hand is short, exact and
torch-version proof: the graph is opset 17 (``Gemm``, ``Relu``, ``Tanh``,
``Softplus``, ``Clip``), checked by ``onnx.checker``, and its initializers
carry the torch parameter names, so :func:`agent_from_onnx` reads a brain back
for fine-tuning (``patternrl train --init BRAIN.onnx``).

The manifest (:class:`runtime.brain.brain.BrainManifest`, DESIGN.md "Brain = ONNX
file + manifest") travels twice: in the ONNX ``metadata_props`` under
``patternrl_manifest`` (without ``brain_id``, which is the sha256 of the file's
own bytes) and as the sidecar ``<stem>.json`` beside ``<stem>.onnx`` (with
``brain_id``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import TensorProto, helper, numpy_helper

from runtime.brain.brain import (
    METADATA_KEY,
    BrainError,
    BrainManifest,
    brain_digest,
    read_brain_file,
    sidecar_path,
)
from runtime.brain.signing import load_private_key, sign_manifest, user_key
from runtime.errors import InputError
from trainer.config import TrainConfig
from trainer.ppo.front_end import onnx_nodes
from trainer.ppo.networks import NORM_CLIP, Agent

OPSET = 17
IR_VERSION = 8  # readable by every onnxruntime this project supports (>= 1.17)


class BrainFileError(InputError):
    """A brain file that cannot be read back as an agent; the message is one line."""


def _linear_layers(module: torch.nn.Module, prefix: str) -> list[tuple[str, torch.nn.Linear]]:
    return [
        (f"{prefix}.{name}", m)
        for name, m in module.named_modules()
        if isinstance(m, torch.nn.Linear)
    ]


def build_onnx(agent: Agent, metadata: dict[str, str] | None = None, frames: int = 1
               ) -> onnx.ModelProto:
    """The agent's deterministic action (and std) as an ONNX model with a dynamic batch axis.

    ``frames`` > 1: the agent reads that many rows, newest first; the graph takes the newest
    as ``obs`` and the older ones as ``memory``, and answers ``memory_out`` (the rows the next
    step reads behind its own), the contract of :mod:`runtime.decision.observation`'s memory.
    """
    inits: list[TensorProto] = []
    nodes: list[onnx.NodeProto] = []

    def const(name: str, value: np.ndarray | float) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value, dtype=np.float32), name))
        return name

    def gemm(x: str, name: str, lin: torch.nn.Linear) -> str:
        w = const(f"{name}.weight", lin.weight.detach().numpy())
        b = const(f"{name}.bias", lin.bias.detach().numpy())
        nodes.append(helper.make_node("Gemm", [x, w, b], [f"{name}.out"], transB=1, name=name))
        return f"{name}.out"

    def const_i64(name: str, value: list[int]) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value, dtype=np.int64), name))
        return name

    def unary(op: str, x: str, name: str) -> str:
        nodes.append(helper.make_node(op, [x], [name], name=name))
        return name

    def chain(x: str, layers: list[tuple[str, torch.nn.Linear]], relu_last: bool) -> str:
        for i, (name, lin) in enumerate(layers):
            x = gemm(x, name, lin)
            if i < len(layers) - 1 or relu_last:
                x = unary("Relu", x, f"{name}.relu")
        return x

    row_dim = agent.obs_dim // frames
    memory_dim = agent.obs_dim - row_dim
    x = "obs"
    if memory_dim:  # the row, then its older rows: what the network reads
        nodes += [
            helper.make_node("Concat", ["obs", "memory"], ["stacked"], axis=1, name="stacked"),
            helper.make_node(
                "Slice",
                ["stacked", const_i64("memory.start", [0]), const_i64("memory.end", [memory_dim]),
                 const_i64("memory.axes", [1])],
                ["memory_out"],
                name="memory_out",
            ),
        ]
        x = "stacked"
    if agent.front is not None:  # the paper brain's fixed front end, before the normaliser
        front_nodes, x = onnx_nodes(agent.front, x, const, const_i64)
        nodes += front_nodes
    norm = agent.normaliser
    shift = const("normaliser.shift", norm.shift.numpy())
    scale = const("normaliser.scale", norm.scale.numpy())
    lo, hi = const("normaliser.clip_lo", -NORM_CLIP), const("normaliser.clip_hi", NORM_CLIP)
    nodes += [
        helper.make_node("Sub", [x, shift], ["norm.centred"], name="norm.sub"),
        helper.make_node("Mul", ["norm.centred", scale], ["norm.scaled"], name="norm.mul"),
        helper.make_node("Clip", ["norm.scaled", lo, hi], ["norm.out"], name="norm.clip"),
    ]
    x = "norm.out"
    if agent.decoder is not None:
        x = chain(x, _linear_layers(agent.encoder, "encoder"), relu_last=False)
    x = chain(x, _linear_layers(agent.policy.trunk, "policy.trunk"), relu_last=True)
    v_max = const("v_max", agent.v_max_mps)
    mean = unary("Tanh", gemm(x, "policy.mean_head", agent.policy.mean_head), "mean.tanh")
    if agent.residual:  # action = v_max * tanh(.) + the rule's velocity, read off obs
        first, end, part = (2, 4, "rule.pace") if agent.on_plan else (0, 2, "rule.slot")
        nodes += [
            helper.make_node("Mul", [mean, v_max], ["residual"], name="residual"),
            helper.make_node(
                "Slice",
                ["obs", const_i64("rule.start", [first]), const_i64("rule.end", [end]),
                 const_i64("rule.axes", [1])],
                [part],
                name=part,
            ),
        ]
        if agent.on_plan:  # the plan's step: v_max * obs[:, 2:4]
            nodes.append(helper.make_node(
                "Mul", [part, const("rule.plan_vmax", agent.v_max_mps)], ["rule.out"],
                name="rule.out"))
        else:  # rule:assign: clip_vmax(obs[:, 0:2] / dt)
            nodes += [
                helper.make_node("Div", [part, const("rule.dt", agent.dt_s)], ["rule.v"],
                                 name="rule.v"),
                helper.make_node("ReduceL2", ["rule.v"], ["rule.speed"], axes=[1], keepdims=1,
                                 name="rule.speed"),
                helper.make_node("Max", ["rule.speed", v_max], ["rule.den"], name="rule.den"),
                helper.make_node("Div", [v_max, "rule.den"], ["rule.scale"], name="rule.scale"),
                helper.make_node("Mul", ["rule.v", "rule.scale"], ["rule.out"], name="rule.out"),
            ]
        nodes.append(helper.make_node("Add", ["residual", "rule.out"], ["action"],
                                      name="action"))
    else:
        nodes.append(helper.make_node("Mul", [mean, v_max], ["action"], name="action"))
    sp = unary("Softplus", gemm(x, "policy.std_head", agent.policy.std_head), "std.softplus")
    min_std = const("policy.min_std", agent.policy.min_std)
    nodes.append(helper.make_node("Add", [sp, min_std], ["std.floor"], name="std.floor"))
    nodes.append(helper.make_node("Mul", ["std.floor", v_max], ["std"], name="std"))

    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", row_dim])]
    outputs = [
        helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2]),
        helper.make_tensor_value_info("std", TensorProto.FLOAT, ["batch", 2]),
    ]
    if memory_dim:
        inputs.append(helper.make_tensor_value_info("memory", TensorProto.FLOAT,
                                                    ["batch", memory_dim]))
        outputs.append(helper.make_tensor_value_info("memory_out", TensorProto.FLOAT,
                                                     ["batch", memory_dim]))
    graph = helper.make_graph(nodes, "patternrl_brain", inputs, outputs, initializer=inits)
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="patternrl-trainer",
        doc_string="Pattern-RL brain: raw observation -> velocity (m/s) and its std.",
    )
    model.ir_version = IR_VERSION
    for key, value in (metadata or {}).items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=key, value=value))
    onnx.checker.check_model(model, full_check=True)
    return model


def write_brain(
    agent: Agent, path: str | Path, manifest: BrainManifest, sign_key: str | Path | None = None
) -> BrainManifest:
    """Write ``path`` (.onnx) and its sidecar ``<stem>.json``; return the manifest with its id.

    The ONNX metadata gets the manifest without ``brain_id`` (the digest of the
    very bytes it sits in) and without signature; the sidecar gets both. The
    signature is by ``sign_key`` (a private key file), by default the user's own
    key (:func:`runtime.brain.signing.user_key`, made on first use).
    """
    out = Path(path)
    manifest.file = out.name
    manifest.brain_id = ""
    manifest.signature = None
    body = manifest.to_json(with_id=False, indent=None)
    model = build_onnx(agent, {METADATA_KEY: body}, manifest.observation.frames)
    data = model.SerializeToString()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(data)
    manifest.brain_id = brain_digest(data)
    key = load_private_key(sign_key if sign_key is not None else user_key(create=True) or "")
    manifest.signature = sign_manifest(manifest.to_dict(), manifest.brain_id, key)
    sidecar_path(out).write_text(manifest.to_json(with_id=True) + "\n")
    return manifest


def read_manifest(path: str | Path) -> BrainManifest:
    """The manifest embedded in an ONNX brain, ``brain_id`` recomputed from its bytes."""
    try:
        brain = read_brain_file(str(path), sidecar=False)
    except BrainError as e:
        raise BrainFileError(str(e)) from None
    manifest = brain.manifest
    if manifest is None:
        raise BrainFileError(f"{path} is a rule brain, not a brain file")
    manifest.brain_id = brain_digest(brain.data)
    return manifest


def agent_from_onnx(path: str | Path, cfg: TrainConfig, v_max_mps: float) -> Agent:
    """Rebuild an agent from a brain's initializers (the value network starts fresh).

    The brain decides the architecture: with encoder weights it is a Pattern-RL
    agent, without them a PPO agent; ``cfg.algo`` must agree.
    """
    try:
        model = onnx.load(str(path))
    except Exception as e:  # onnx raises DecodeError and friends
        raise BrainFileError(f"cannot read brain {path}: {str(e).splitlines()[0][:200]}") from None
    w = {t.name: torch.from_numpy(numpy_helper.to_array(t).copy()) for t in model.graph.initializer}
    if "normaliser.shift" not in w or "policy.mean_head.weight" not in w:
        raise BrainFileError(f"{path} is not a Pattern-RL brain (unknown layout)")
    has_ae = "encoder.0.weight" in w
    if "front.axis" in w and cfg.obs != "paper":
        raise BrainFileError(f"{path} reads the paper observation; train it with --obs paper")
    front = "none"
    if "front.axis" in w:
        front = "transport" if "front.g_init" in w else "slots" if "front.slots" in w else "rank"
    if "rule.plan_vmax" in w and cfg.obs != "plan":
        raise BrainFileError(f"{path} acts on the plan observation; train it with --obs plan")
    cfg = cfg.with_(residual="rule.dt" in w or "rule.plan_vmax" in w, front_end=front)
    dt_s = float(w["rule.dt"]) if "rule.dt" in w else 0.1
    if "front.inv_dt" in w:
        dt_s = 1.0 / float(w["front.inv_dt"])
    if has_ae != cfg.uses_autoencoder:
        kind = "pattern-rl" if has_ae else "ppo"
        raise BrainFileError(f"{path} is a {kind} brain; train it with --algo {kind}")
    obs_dim = 0  # the row and its memory: what the network reads
    for inp in model.graph.input:
        dims = inp.type.tensor_type.shape.dim
        obs_dim += int(dims[1].dim_value) if len(dims) == 2 else 0
    if obs_dim <= 0:
        obs_dim = int(w["normaliser.shift"].numel())
    if has_ae:
        cfg = cfg.with_(
            latent_dim=int(w["encoder.2.weight"].shape[0]),
            ae_hidden=int(w["encoder.0.weight"].shape[0]),
        )
    agent = Agent(obs_dim, cfg, v_max_mps, dt_s)
    state = agent.state_dict()
    for key, value in w.items():
        if key in state and state[key].shape == value.shape:
            state[key] = value
    agent.load_state_dict(state)
    agent.policy.min_std = float(w["policy.min_std"])
    # the normaliser's statistics, from its constants, with a moderate weight so fine-tuning adapts
    scale = w["normaliser.scale"].double()
    agent.normaliser.mean64.copy_(w["normaliser.shift"].double())
    agent.normaliser.var64.copy_((1.0 / scale) ** 2)
    agent.normaliser.count.fill_(1e5)
    agent.normaliser.shift.copy_(w["normaliser.shift"])
    agent.normaliser.scale.copy_(w["normaliser.scale"])
    return agent
