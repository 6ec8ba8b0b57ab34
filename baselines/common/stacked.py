"""Pieces of seed-batched training: N members' networks as stacked weights, and their replay.

Member k of a batch is one run: its weights are the slices ``[k]`` of every stacked tensor,
and every layer is one batched matrix product over the members, so the members are
computed together but never mixed. Losses are summed over members only to call backward
once: the gradient of a sum is each member's own gradient, and Adam is elementwise, so no
statistic is shared across members.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.device import make_adam
from baselines.common.networks import TanhGaussianPolicy

# Floats: a multiple of every CPU vector width, with room for an unrolled loop.
WHOLE_VECTORS = 64


def descend(optimizer: torch.optim.Optimizer, member_losses: torch.Tensor) -> None:
    """One step of ``optimizer`` on the sum of the members' losses (N,): each loss depends
    on its own member's weights only, so the members' gradients do not mix."""
    optimizer.zero_grad()
    member_losses.sum().backward()
    optimizer.step()


def member_adam(
    params: Iterable[torch.Tensor], lr: float, device: torch.device
) -> torch.optim.Adam:
    """Adam over stacked tensors (members first) in which member k's update does not depend
    on how many members are stacked.

    The CPU's fused Adam updates a tensor's last elements, those short of a whole vector,
    with scalar code that rounds differently from its vector code (seen on an AMD EPYC with
    AVX2), so a member whose slice ends in that tail would change with the batch size. A
    tensor whose slice per member is not whole vectors (an output layer's bias, say) takes
    the unfused Adam there, which rounds alike element by element.
    """
    params = list(params)
    if device.type != "cpu":
        return make_adam(params, lr, device, True)
    whole = [p for p in params if (p.numel() // p.shape[0]) % WHOLE_VECTORS == 0]
    rest = [p for p in params if (p.numel() // p.shape[0]) % WHOLE_VECTORS != 0]
    groups = ([{"params": whole}] if whole else []) + (
        [{"params": rest, "fused": False, "foreach": False}] if rest else []
    )
    return torch.optim.Adam(groups, lr=lr, fused=True)


class StackedMLP(nn.Module):
    """``members`` MLPs with ReLU between layers; weights (members, in, out), biases
    (members, 1, out). ``forward`` maps (members, batch, in) to (members, batch, out)."""

    def __init__(self, weights: Sequence[torch.Tensor], biases: Sequence[torch.Tensor]):
        super().__init__()
        self.weights = nn.ParameterList(nn.Parameter(w.detach().clone()) for w in weights)
        self.biases = nn.ParameterList(nn.Parameter(b.detach().clone()) for b in biases)

    @classmethod
    def stack(cls, networks: Sequence[nn.Sequential]) -> StackedMLP:
        """Stack the ``nn.Linear`` layers of equal-shaped ``networks``, in order."""
        layers = [[m for m in net if isinstance(m, nn.Linear)] for net in networks]
        weights = [
            torch.stack([member[i].weight.detach().T for member in layers])
            for i in range(len(layers[0]))
        ]
        biases = [
            torch.stack([member[i].bias.detach()[None, :] for member in layers])
            for i in range(len(layers[0]))
        ]
        return cls(weights, biases)

    @property
    def members(self) -> int:
        return self.weights[0].shape[0]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        last = len(self.weights) - 1
        for k, (weight, bias) in enumerate(zip(self.weights, self.biases)):
            x = torch.baddbmm(bias, x, weight)
            if k < last:
                x = torch.relu(x)
        return x

    def member_linear(self, k: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Member ``k``'s layers as ``nn.Linear`` stores them: (weight (out, in), bias)."""
        return [(w[k].T.detach(), b[k, 0].detach()) for w, b in zip(self.weights, self.biases)]


class StackedNormMLP(StackedMLP):
    """``StackedMLP`` with LayerNorm (a gain and a bias per member) after every hidden
    layer, before its ReLU, as RLPD's critics have it; gains and biases (members, 1, width)."""

    def __init__(
        self,
        weights: Sequence[torch.Tensor],
        biases: Sequence[torch.Tensor],
        norm_gains: Sequence[torch.Tensor],
        norm_biases: Sequence[torch.Tensor],
    ):
        super().__init__(weights, biases)
        self.norm_gains = nn.ParameterList(nn.Parameter(g.detach().clone()) for g in norm_gains)
        self.norm_biases = nn.ParameterList(nn.Parameter(b.detach().clone()) for b in norm_biases)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return layer_norm_mlp(x, self.weights, self.biases, self.norm_gains, self.norm_biases)


def layer_norm_mlp(
    x: torch.Tensor,
    weights: Sequence[torch.Tensor],
    biases: Sequence[torch.Tensor],
    norm_gains: Sequence[torch.Tensor],
    norm_biases: Sequence[torch.Tensor],
) -> torch.Tensor:
    """Stacked layers (n, in, out) on x (n, batch, in): Dense -> LayerNorm -> ReLU, the last
    layer Dense alone (RLPD's critic, one-run ensemble or batch of them alike)."""
    last = len(weights) - 1
    for k, (weight, bias) in enumerate(zip(weights, biases)):
        x = torch.baddbmm(bias, x, weight)
        if k < last:
            x = torch.relu(F.layer_norm(x, x.shape[-1:]) * norm_gains[k] + norm_biases[k])
    return x


class StackedPolicy(TanhGaussianPolicy):
    """Tanh-squashed Gaussian policies of N members: ``TanhGaussianPolicy`` on a stacked
    trunk, so forward, the deterministic action and ``sample(obs, noise=...)`` are its own."""

    def __init__(self, trunk: StackedMLP, action_scale: torch.Tensor, action_bias: torch.Tensor):
        nn.Module.__init__(self)  # the one-run trunk is not built: the stacked one replaces it
        self.trunk = trunk
        self.register_buffer("action_scale", action_scale.detach().clone())
        self.register_buffer("action_bias", action_bias.detach().clone())

    def member_policy(self, k: int) -> TanhGaussianPolicy:
        """Member ``k`` as a one-run policy on the CPU (what an expert file holds)."""
        layers = self.trunk.member_linear(k)
        obs_dim, act_dim = layers[0][0].shape[1], layers[-1][0].shape[0] // 2
        low = (self.action_bias - self.action_scale).cpu()
        high = (self.action_bias + self.action_scale).cpu()
        with torch.random.fork_rng(devices=[]):  # its throwaway initial weights draw no
            policy = TanhGaussianPolicy(
                obs_dim,
                act_dim,
                low,
                high,  # batch random numbers
                [w.shape[0] for w, _ in layers[:-1]],
            )
        linears = [m for m in policy.trunk if isinstance(m, nn.Linear)]
        with torch.no_grad():
            for linear, (weight, bias) in zip(linears, layers, strict=True):
                linear.weight.copy_(weight)
                linear.bias.copy_(bias)
        return policy


def pair_critics(q1: Sequence[nn.Sequential], q2: Sequence[nn.Sequential]) -> StackedMLP:
    """Two critics per member as one stack of 2N, member-major: (m0 Q1, m0 Q2, m1 Q1, ...)."""
    return StackedMLP.stack([net for pair in zip(q1, q2) for net in pair])


def critic_pairs(critics: StackedMLP, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
    """Q of both critics of every member: (N, B, .) inputs to (N, 2, B)."""
    return critic_ensembles(critics, obs, act, 2)


def critic_ensembles(
    critics: StackedMLP, obs: torch.Tensor, act: torch.Tensor, per_member: int
) -> torch.Tensor:
    """Q of every member's ``per_member`` critics, stacked member-major: (N, B, .) inputs to
    (N, per_member, B)."""
    members, rows = obs.shape[0], obs.shape[1]
    inputs = torch.cat([obs, act], dim=-1).unsqueeze(1).expand(-1, per_member, -1, -1)
    return critics(inputs.reshape(per_member * members, rows, -1)).view(members, per_member, rows)


def uniform_indices(
    members: int,
    rows: int,
    size: int | torch.Tensor,
    device: torch.device,
    dtype: torch.dtype = torch.float64,
) -> torch.Tensor:
    """``rows`` slots per member, uniform in [0, size), from the device's default generator
    (the GPU's replay sampling; ``size`` a tensor where a CUDA graph replays it). float64 by
    default: float32 steps of 2^-24 would make slots high in a 1M replay 3-6% more or less
    likely than others."""
    uniform = torch.rand((members, rows), device=device, dtype=dtype)
    return (uniform * size).long().clamp_(max=size - 1)


class StackedReplay:
    """One replay buffer per member, stored together: (members, capacity, width) float32 on
    the training device, each row (s, a, r, s', terminated). All members add one transition
    per step, so they share the write position and the size."""

    def __init__(
        self, members: int, obs_dim: int, act_dim: int, capacity: int, device: torch.device
    ):
        if capacity <= 0:
            raise ValueError(f"replay capacity must be positive, got {capacity}")
        self.obs_dim, self.act_dim, self.capacity = obs_dim, act_dim, capacity
        self.width = 2 * obs_dim + act_dim + 2
        self.device = device
        self.data = torch.zeros((members, capacity, self.width), dtype=torch.float32, device=device)
        self.position = 0
        self.size = 0
        self._members = torch.arange(members, device=device)[:, None]

    @staticmethod
    def bytes_per_member(obs_dim: int, act_dim: int, capacity: int) -> int:
        return 4 * capacity * (2 * obs_dim + act_dim + 2)

    def add(
        self,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        row = np.concatenate(
            [obs, actions, rewards[:, None], next_obs, terminated[:, None]], axis=1
        ).astype(np.float32)
        self.data[:, self.position] = torch.from_numpy(row).to(self.device, non_blocking=True)
        self.position = (self.position + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def gather(self, indices: torch.Tensor) -> Batch:
        """Member k's rows ``indices[k]`` (N, B) as one stacked batch."""
        return self.split(self.data[self._members, indices])

    def split(self, rows: torch.Tensor) -> Batch:
        """Stored rows (N, B, width) as a batch."""
        o, a = self.obs_dim, self.act_dim
        return Batch(
            observations=rows[..., :o],
            actions=rows[..., o : o + a],
            rewards=rows[..., o + a],
            next_observations=rows[..., o + a + 1 : 2 * o + a + 1],
            terminated=rows[..., -1],
        )

    def member(self, k: int) -> Batch:
        """Member k's stored transitions in slot order, as numpy arrays on the CPU."""
        return Batch(
            *(t.cpu().numpy() for t in vars(self.split(self.data[k, : self.size])).values())
        )

    def sample(self, batch_size: int, rngs: Sequence[np.random.Generator]) -> Batch:
        """Uniform with replacement, member k's indices from ``rngs[k]`` alone (as
        ``ReplayBuffer.sample`` draws them for one run)."""
        indices = np.stack([rng.integers(0, self.size, size=batch_size) for rng in rngs])
        return self.gather(torch.from_numpy(indices).to(self.device))

    def sample_on_device(self, batch_size: int, size: int | torch.Tensor) -> Batch:
        """Uniform with replacement among the first ``size`` rows, every member's indices
        from the device's generator (the GPU's sampling, inside the step's CUDA graph)."""
        return self.gather(uniform_indices(len(self.data), batch_size, size, self.device))

    def state_dict(self) -> dict[str, object]:
        # one host copy, filled member by member: each member's rows are contiguous, so a
        # GPU replay is never copied whole on the device first
        data = torch.empty(
            (len(self.data), self.size, self.width), dtype=self.data.dtype, device="cpu"
        )
        for k in range(len(self.data)):
            data[k].copy_(self.data[k, : self.size])
        return {"data": data, "position": self.position}

    def load_state_dict(self, state: dict) -> None:
        n = state["data"].shape[1]
        if n > self.capacity:
            raise ValueError(f"saved buffer holds {n} transitions, capacity is {self.capacity}")
        for k in range(len(self.data)):  # member by member: no second replay on the device
            self.data[k, :n].copy_(state["data"][k])
        self.size = n
        self.position = int(state["position"])


class StackedSymmetricReplay(StackedReplay):
    """RLPD's replay for N members: each member's online rows, kept as ``StackedReplay``
    keeps them, beside the demonstration transitions all members share (never overwritten).
    Every sample is half demonstration rows, first, then online rows."""

    def __init__(
        self,
        demos: ReplayBuffer,
        members: int,
        obs_dim: int,
        act_dim: int,
        capacity: int,
        device: torch.device,
    ):
        super().__init__(members, obs_dim, act_dim, capacity, device)
        n = demos.size
        rows = np.concatenate(
            [
                demos.observations[:n],
                demos.actions[:n],
                demos.rewards[:n, None],
                demos.next_observations[:n],
                demos.terminated[:n, None],
            ],
            axis=1,
        )
        self.demos = torch.from_numpy(np.ascontiguousarray(rows, dtype=np.float32)).to(device)

    def gather_halves(self, demo_indices: torch.Tensor, online_indices: torch.Tensor) -> Batch:
        """Member k's demonstration rows ``demo_indices[k]`` and then its online rows
        ``online_indices[k]``, as one stacked batch."""
        return self.split(
            torch.cat([self.demos[demo_indices], self.data[self._members, online_indices]], dim=1)
        )

    def sample(self, batch_size: int, rngs: Sequence[np.random.Generator]) -> Batch:
        """Member k draws ``batch_size // 2`` demonstration rows, then the rest online, from
        ``rngs[k]`` alone."""
        half = batch_size // 2
        demo_rows, online_rows = [], []
        for rng in rngs:
            demo_rows.append(rng.integers(0, len(self.demos), size=half))
            online_rows.append(rng.integers(0, self.size, size=batch_size - half))
        return self.gather_halves(
            torch.from_numpy(np.stack(demo_rows)).to(self.device),
            torch.from_numpy(np.stack(online_rows)).to(self.device),
        )

    def sample_on_device(self, batch_size: int, size: int | torch.Tensor) -> Batch:
        """As ``sample``, from the device's generator: the demonstration half first."""
        half, members = batch_size // 2, len(self.data)
        # the bound a Python number: a tensor made here would copy to the device, which
        # graph capture forbids; float32 draws, as RLPD's runs were trained with
        demo = uniform_indices(members, half, len(self.demos), self.device, torch.float32)
        online = uniform_indices(members, batch_size - half, size, self.device)
        return self.gather_halves(demo, online)
