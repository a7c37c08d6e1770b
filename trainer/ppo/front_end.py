"""The paper brain's fixed front end: the paper's observation in a form a policy can learn from.

A paper brain reads the paper's observation and nothing else (the other
robots' relative positions at t, t-1, t-2, nearest first). Its first layer has
no weights: it re-expresses that input so that what a robot must decide
depends smoothly on it, then the auto-encoder, policy and value of Algorithm 1
learn from there. Per robot, from frames t and t-1 (``n`` robots, ``k`` =
min(6, n-1) nearest others)::

    0:2        z: the robot's position relative to the team's centroid (m),
               -sum_j rel_j(t) / n (the robot itself is at 0 in its own view)
    2:4        dz / dt: how it moved relative to the team's centroid (m/s)
    4:4+n      its rank along the team axis, one-hot (trainer.ppo.rank): which of
               the n robots it is, in an order all robots agree on
    4+n:       the k nearest others, nearest first: [dx, dy, dvx, dvy] relative
               position (m) and relative velocity (m/s), for avoiding them

With ``rank`` nothing in it names a slot or the pattern: the brain learns,
from the reward, where the k-th robot of the team belongs (a table the one-hot
rank reads out) and how to get there without touching the others. With
``slots`` the brain carries its pattern's points in rank order (constants set
from the training pattern, :meth:`RankFrontEnd.set_pattern`) and puts in
front, as the general observation does::

    0:2        slot vector: the slot of the robot's rank minus z (m)
    2:4        the slot vector / max(|slot vector|, v_max dt)

so the learned part is how to get there: the way, the speed, the others. The same few nodes open the
exported ONNX graph (:func:`onnx_nodes`), so the robot, ``eval`` and the world
run the brain on the plain paper observation, unchanged.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from onnx import NodeProto, TensorProto, helper
from torch import nn

from trainer.ppo.rank import TEAM_AXIS

NEAREST = 6
MODES = ("rank", "slots", "transport")
SINKHORN_EPS = tuple(float(e) for e in np.geomspace(4.0, 1e-3, 36)) + (1e-3,) * 4
"""The entropic regularisation of each Sinkhorn iteration (m^2), large to small: the
matching anneals from "every slot a little" to one slot per robot (epsilon scaling)."""


def front_dim(n_robots: int, mode: str = "rank") -> int:
    """Length of the front end's output for a team of ``n_robots``."""
    k = min(NEAREST, n_robots - 1)
    if mode == "transport":
        return 8 + 4 * k
    return 4 * (mode == "slots") + 4 + n_robots + 4 * k


class RankFrontEnd(nn.Module):
    """Paper observation (B, 3 * (n-1) * 2) -> features (B, :func:`front_dim`)."""

    axis: torch.Tensor
    ranks: torch.Tensor
    slots: torch.Tensor

    def __init__(self, n_robots: int, dt_s: float, reach_m: float, mode: str = "rank",
                 axis: np.ndarray = TEAM_AXIS) -> None:
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"unknown front end '{mode}' (known: {', '.join(MODES)})")
        self.n = int(n_robots)
        self.k = min(NEAREST, self.n - 1)
        self.dt_s, self.reach_m = float(dt_s), float(reach_m)
        self.mode = mode
        self.with_slots = mode != "rank"  # carries its pattern (set_pattern)
        self.register_buffer("axis", torch.tensor(np.asarray(axis), dtype=torch.float32))
        self.register_buffer("ranks", torch.arange(self.n, dtype=torch.float32))
        self.register_buffer("slots", torch.zeros(self.n, 2))
        self.out_dim = front_dim(self.n, mode)

    def set_pattern(self, pattern: np.ndarray) -> None:
        """``slots``/``transport``: the pattern's (n, 2) points, centred, in rank order."""
        C = np.asarray(pattern, dtype=np.float64)
        C = C - C.mean(axis=0)
        self.slots.copy_(torch.from_numpy(C[np.argsort(C @ self.axis.double().numpy(),
                                                       kind="stable")]))

    def forward(self, obs: torch.Tensor, team_rows: int = 0) -> torch.Tensor:
        """Features (B, out_dim). ``team_rows`` = n when the rows come in whole teams
        (row b is robot b % n of team b // n, as the training world lays them out): the
        transport is then solved once per team instead of once per robot, the same
        matching (it is one problem, seen from each robot), ~n times less work."""
        o = obs.reshape(-1, 3, self.n - 1, 2)
        now, before = o[:, 0], o[:, 1]
        c_now, c_before = now.sum(1), before.sum(1)
        z = c_now * (-1.0 / self.n)
        vz = (c_before - c_now) * (1.0 / (self.n * self.dt_s))
        rank = (torch.matmul(now, self.axis) < 0).to(obs.dtype).sum(1, keepdim=True)
        one_hot = (rank == self.ranks).to(obs.dtype)
        near = now[:, : self.k]
        moved = (near - before[:, : self.k]) * (1.0 / self.dt_s)
        nb = torch.cat([near, moved], dim=2).reshape(-1, 4 * self.k)
        if self.mode == "transport":
            team = torch.cat([z[:, None, :], now + z[:, None, :]], dim=1)  # about the centroid
            if team_rows == self.n and team.shape[0] % self.n == 0:
                sv = self.team_transport_slots(team) - z
            else:
                sv = self.transport_slot(team) - z
            step = sv / sv.norm(dim=1, keepdim=True).clamp_min(self.reach_m)
            return torch.cat([sv, step, z, vz, nb], dim=1)
        out = torch.cat([z, vz, one_hot, nb], dim=1)
        if self.mode == "rank":
            return out
        sv = one_hot @ self.slots - z  # slot vector: own slot minus own position (m)
        step = sv / sv.norm(dim=1, keepdim=True).clamp_min(self.reach_m)
        return torch.cat([sv, step, out], dim=1)

    def transport_slot(self, team: torch.Tensor) -> torch.Tensor:
        """The robot's slot (B, 2) under the team's optimal matching to the pattern.

        ``team`` (B, n, 2): the team's positions about its centroid, the robot's own
        first. Entropic optimal transport (Sinkhorn, log domain, epsilon annealed by
        :data:`SINKHORN_EPS`) between the team and the pattern's slots with the cost
        of :func:`runtime.decision.formation.assign_slots` (squared distance): every robot
        solves the same problem from its own view, so the matchings agree; row 0 is
        the robot's own, a soft one-hot over the slots, whose mean is its slot.
        """
        cost, g = self._sinkhorn(team)
        own = torch.softmax((g[:, 0] - cost[:, 0]) * (1.0 / SINKHORN_EPS[-1]), dim=1)
        return own @ self.slots

    def team_transport_slots(self, team: torch.Tensor) -> torch.Tensor:
        """:meth:`transport_slot` for rows that come in whole teams (see :meth:`forward`):
        solved from each team's first robot's view, every member's slot read off the row
        whose position is the member's own."""
        B, n = team.shape[0], self.n
        lead = team[::n]  # (E, n, 2): each team from its first robot's view
        cost, g = self._sinkhorn(lead)
        plan = torch.softmax((g - cost) * (1.0 / SINKHORN_EPS[-1]), dim=2)  # (E, n, n)
        slots = plan @ self.slots  # (E, n, 2): each member's slot, in the lead's order
        own = team[:, 0].reshape(B // n, n, 2)  # each robot's own position, team by team
        which = (own[:, :, None, :] - lead[:, None, :, :]).pow(2).sum(-1).argmin(-1)
        return torch.take_along_dim(slots, which[..., None], dim=1).reshape(B, 2)

    def _sinkhorn(self, team: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Cost (B, n, n) and the slots' potentials g (B, 1, n) after the annealing."""
        cost = (team[:, :, None, :] - self.slots[None, None, :, :]).pow(2).sum(-1)
        g = torch.zeros(cost.shape[0], 1, self.n, dtype=team.dtype)
        for eps in SINKHORN_EPS:
            f = -eps * torch.logsumexp((g - cost) * (1.0 / eps), dim=2, keepdim=True)
            g = -eps * torch.logsumexp((f - cost) * (1.0 / eps), dim=1, keepdim=True)
        return cost, g


def onnx_nodes(front: RankFrontEnd, x: str,
               const: Callable[[str, np.ndarray | float], str],
               const_i64: Callable[[str, list[int]], str]) -> tuple[list[NodeProto], str]:
    """The ONNX nodes computing ``front`` from the input ``x``; returns them and their output.

    ``const``/``const_i64`` add float32/int64 initializers (the exporter's). The
    initializer ``front.axis`` marks a brain with this front end when it is read back.
    """
    n, k = front.n, front.k
    axis = const("front.axis", front.axis.numpy())
    ranks = const("front.ranks", front.ranks.numpy())
    zero = const("front.zero", 0.0)

    def node(op: str, inputs: list[str], out: str, **attrs: Any) -> str:
        nodes.append(helper.make_node(op, inputs, [out], name=out, **attrs))
        return out

    nodes: list[NodeProto] = []
    o = node("Reshape", [x, const_i64("front.shape", [-1, 3, n - 1, 2])], "front.frames")
    now = node("Gather", [o, const_i64("front.t0", [0])], "front.now4", axis=1)
    now = node("Squeeze", [now, const_i64("front.sq", [1])], "front.now")
    before = node("Gather", [o, const_i64("front.t1", [1])], "front.before4", axis=1)
    before = node("Squeeze", [before, "front.sq"], "front.before")
    c_now = node("ReduceSum", [now, const_i64("front.others", [1])], "front.c_now", keepdims=0)
    c_before = node("ReduceSum", [before, "front.others"], "front.c_before", keepdims=0)
    z = node("Mul", [c_now, const("front.inv_n", -1.0 / n)], "front.z")
    dc = node("Sub", [c_before, c_now], "front.dc")
    vz = node("Mul", [dc, const("front.inv_ndt", 1.0 / (n * front.dt_s))], "front.vz")
    proj = node("MatMul", [now, axis], "front.proj")
    below = node("Cast", [node("Less", [proj, zero], "front.below_b")], "front.below",
                 to=TensorProto.FLOAT)
    rank = node("ReduceSum", [below, "front.others"], "front.rank", keepdims=1)
    one_hot = node("Cast", [node("Equal", [rank, ranks], "front.is_rank")], "front.one_hot",
                   to=TensorProto.FLOAT)
    starts, ends = const_i64("front.k0", [0]), const_i64("front.k1", [k])
    near = node("Slice", [now, starts, ends, "front.others"], "front.near")
    near_before = node("Slice", [before, starts, ends, "front.others"], "front.near_before")
    moved = node("Mul", [node("Sub", [near, near_before], "front.dnear"),
                         const("front.inv_dt", 1.0 / front.dt_s)], "front.moved")
    nb = node("Concat", [near, moved], "front.nb3", axis=2)
    nb = node("Reshape", [nb, const_i64("front.nb_shape", [-1, 4 * k])], "front.nb")
    if front.mode == "transport":
        slot = _transport_nodes(front, now, z, node, const, const_i64)
        sv, step = _slot_step_nodes(front, slot, z, node, const)
        return nodes, node("Concat", [sv, step, z, vz, nb], "front.out", axis=1)
    out = node("Concat", [z, vz, one_hot, nb], "front.rank_out", axis=1)
    if not front.with_slots:
        return nodes, out
    slot = node("MatMul", [one_hot, const("front.slots", front.slots.numpy())], "front.slot")
    sv, step = _slot_step_nodes(front, slot, z, node, const)
    return nodes, node("Concat", [sv, step, out], "front.out", axis=1)


Node = Callable[..., str]


def _slot_step_nodes(front: RankFrontEnd, slot: str, z: str, node: Node,
                     const: Callable[[str, np.ndarray | float], str]) -> tuple[str, str]:
    """Slot vector (slot - z) and the step toward it, saturated at one reach."""
    sv = node("Sub", [slot, z], "front.sv")
    length = node("ReduceL2", [sv], "front.sv_len", axes=[1], keepdims=1)
    den = node("Max", [length, const("front.reach", front.reach_m)], "front.sv_den")
    return sv, node("Div", [sv, den], "front.step")


def _transport_nodes(front: RankFrontEnd, now: str, z: str, node: Node,
                     const: Callable[[str, np.ndarray | float], str],
                     const_i64: Callable[[str, list[int]], str]) -> str:
    """:meth:`RankFrontEnd.transport_slot` as nodes, its Sinkhorn iterations unrolled."""
    n = front.n
    zu = node("Unsqueeze", [z, const_i64("front.ax1", [1])], "front.z3")
    team = node("Concat", [zu, node("Add", [now, zu], "front.others_c")], "front.team", axis=1)
    team4 = node("Unsqueeze", [team, const_i64("front.ax2", [2])], "front.team4")
    slots4 = const("front.slots4", front.slots.numpy()[None, None])
    diff = node("Sub", [team4, slots4], "front.diff")
    cost = node("ReduceSum", [node("Mul", [diff, diff], "front.diff2"),
                              const_i64("front.ax3", [3])], "front.cost", keepdims=0)
    g = const("front.g_init", np.zeros((1, 1, n)))
    for i, eps in enumerate(SINKHORN_EPS):
        inv, neg = const(f"front.inv_eps{i}", 1.0 / eps), const(f"front.neg_eps{i}", -eps)
        t = node("Mul", [node("Sub", [g, cost], f"front.gc{i}"), inv], f"front.gt{i}")
        f = node("Mul", [node("ReduceLogSumExp", [t], f"front.flse{i}", axes=[2], keepdims=1),
                         neg], f"front.f{i}")
        t = node("Mul", [node("Sub", [f, cost], f"front.fc{i}"), inv], f"front.ft{i}")
        g = node("Mul", [node("ReduceLogSumExp", [t], f"front.glse{i}", axes=[1], keepdims=1),
                         neg], f"front.g{i}")
    cost0 = node("Gather", [cost, const_i64("front.self", [0])], "front.cost0", axis=1)
    g_row = node("Squeeze", [g, "front.ax1"], "front.g_row")
    logits = node("Mul", [node("Sub", [g_row, node("Squeeze", [cost0, "front.ax1"],
                                                    "front.cost0r")], "front.own_gc"),
                          const("front.inv_eps_last", 1.0 / SINKHORN_EPS[-1])], "front.own_t")
    own = node("Softmax", [logits], "front.own", axis=1)
    return node("MatMul", [own, const("front.slots", front.slots.numpy())], "front.slot")
