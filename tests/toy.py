"""Plain helpers of the test suite (importable as ``toy`` from any test directory).

* a bimodal toy data set of 1-D trajectories that go either left or right;
* the one-step planner's reference computations (the unfolded path the exact fast path
  must equal) and the weight changes every cache of derived tensors must notice.
* tiny fitted Laplace ensembles over a linear-head or planner actor and their data.
* a tiny TorchRL ``TanhNormal`` actor and the by-hand forward of a one-hidden-layer ``MLP``
  (critic losses' reference computations);
* a linear-head actor, a tiny TorchRL ``IQLLoss`` and an observation-action batch (the
  actor losses' inputs).
"""

from __future__ import annotations

import copy

import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.data import TensorSpec
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import IQLLoss

from torchrl_dual.diffusion import Normalizer, TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import (
    LaplaceEnsembleActor,
    LinearHeadActor,
    PlannerActor,
    PlannerSampler,
)

LEFT_FRACTION = 0.3


def tanh_normal_actor(
    obs_dim: int,
    action_dim: int,
    spec: TensorSpec | None = None,
    return_log_prob: bool = False,
) -> ProbabilisticActor:
    """A TorchRL ``TanhNormal`` actor on ``observation``, one hidden layer of 8 cells
    (writing ``action_log_prob`` too with ``return_log_prob``)."""
    net = nn.Sequential(
        MLP(in_features=obs_dim, out_features=2 * action_dim, num_cells=[8]), NormalParamExtractor()
    )
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=spec,
        distribution_class=TanhNormal,
        return_log_prob=return_log_prob,
    )


def mlp_by_hand(params: TensorDict, x: torch.Tensor) -> torch.Tensor:
    """``W2 tanh(W0 x + b0) + b2`` of a one-hidden-layer TorchRL ``MLP`` inside a
    ``ValueOperator`` (``params`` as the loss holds them, under ``"module"``)."""
    hidden = torch.tanh(x @ params["module", "0", "weight"].T + params["module", "0", "bias"])
    return (hidden @ params["module", "2", "weight"].T + params["module", "2", "bias"]).squeeze(-1)


def bimodal_transitions(num_episodes: int = 400, length: int = 12, seed: int = 0) -> TensorDict:
    """Episodes start near 0 and move with velocity -1 (30 %) or +1 (70 %) plus small noise."""
    gen = torch.Generator().manual_seed(seed)
    direction = torch.where(torch.rand(num_episodes, generator=gen) < LEFT_FRACTION, -1.0, 1.0)
    action = direction[:, None] + 0.05 * torch.randn(num_episodes, length, generator=gen)
    start = 0.1 * torch.randn(num_episodes, 1, generator=gen)
    position = torch.cat([start, start + torch.cumsum(0.5 * action, dim=1)], dim=1)
    episode = torch.arange(num_episodes)[:, None].expand(num_episodes, length)
    done = torch.zeros(num_episodes, length, 1, dtype=torch.bool)
    done[:, -1] = True
    td = TensorDict(
        {
            "observation": position[:, :-1, None],
            "action": action[..., None],
            "episode": episode,
            "next": {
                "observation": position[:, 1:, None],
                "reward": torch.zeros(num_episodes, length, 1),
                "done": done,
                "terminated": torch.zeros_like(done),
                "truncated": done.clone(),
            },
        },
        batch_size=[num_episodes, length],
    )
    return td.reshape(-1)


def mode_statistics(windows: torch.Tensor, observation: torch.Tensor) -> tuple[float, float]:
    """Fraction of windows going left, and mean RMS distance to the nearest true mode.

    ``windows`` is ``[B, L, 2]`` (position, action) in raw units; ``observation`` the
    ``[B, 1]`` start position. The true modes are the noiseless left/right paths.
    """
    length = windows.shape[1]
    steps = torch.arange(length, dtype=windows.dtype)
    modes = []
    for velocity in (-1.0, 1.0):
        position = observation + 0.5 * velocity * steps
        modes.append(torch.stack([position, torch.full_like(position, velocity)], dim=-1))
    dist = torch.stack([((windows - m) ** 2).mean((-2, -1)).sqrt() for m in modes], dim=-1)
    left = (windows[..., 1].mean(-1) < 0).float().mean()
    return float(left), float(dist.min(-1).values.mean())


# ----------------------------------------------------------------------------- one-step planner
def transition_inputs(
    *batch: int, obs_dim: int = 3, action_dim: int = 2, seed: int = 1
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(s_t, s_{t-1}, a_{t-1})`` in raw units, the inputs of DUAL's two acting queries."""
    gen = torch.Generator().manual_seed(seed)
    return (
        torch.randn(*batch, obs_dim, generator=gen) * 2.0 + 1.0,
        torch.randn(*batch, obs_dim, generator=gen) * 2.0 + 1.0,
        torch.randn(*batch, action_dim, generator=gen) * 0.5,
    )


def previous_step_td(
    batch: int = 6,
    *,
    valid: torch.Tensor | None = None,
    obs_dim: int = 3,
    action_dim: int = 2,
    observation_scale: float = 1.0,
) -> TensorDict:
    """``s_t`` and the previous step ``(s_{t-1}, a_{t-1}, valid)`` as the
    ``PreviousTransition`` env transform writes them (``valid`` all true by default)."""
    observation, previous_observation, previous_action = transition_inputs(
        batch, obs_dim=obs_dim, action_dim=action_dim
    )
    return TensorDict(
        observation=observation * observation_scale,
        previous_observation=previous_observation * observation_scale,
        previous_action=previous_action,
        previous_valid=torch.ones(batch, 1, dtype=torch.bool) if valid is None else valid,
        batch_size=[batch],
    )


def fine_tuned(model: nn.Module, *, scale: float = 0.05, seed: int = 7) -> nn.Module:
    """A deep copy of ``model`` whose parameters moved by ``scale``-sized noise."""
    twin = copy.deepcopy(model)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in twin.parameters():
            parameter.add_(scale * torch.randn(parameter.shape, generator=gen))
    return twin


def plain_features(
    model: TrajectoryDiffusion, observation: torch.Tensor, action: torch.Tensor | None = None
) -> torch.Tensor:
    """The unfolded trunk ``φ`` of a zero-latent query at ``t = 1`` (``s_0`` or ``s_0, a_0``)."""
    norm = model.normalizer
    action = None if action is None else norm.normalize_action(action)
    z, mask = model.layout.conditioned_window(norm.normalize_observation(observation), action)
    return model.denoiser.features(z, torch.ones(z.shape[:-2], dtype=z.dtype), mask)


def plain_prediction(
    model: TrajectoryDiffusion, observation: torch.Tensor, action: torch.Tensor
) -> torch.Tensor:
    """The zero-latent transition prediction ``ŝ'`` through the general sampler."""
    return PlannerSampler(model).predict_next_observation(observation, action, deterministic=True)


WEIGHT_CHANGES = ("adam", "adam_foreach", "load_state_dict", "normalizer_fit", "double")


def apply_weight_change(model: TrajectoryDiffusion, change: str) -> None:
    """Changes the planner's tensors in one of the ways a cache of derived tensors must notice.

    ``adam*`` takes two optimizer steps (for a frozen model, an in-place edit of every
    weight instead), ``load_state_dict`` copies other weights in, ``normalizer_fit``
    refits the statistics and ``double`` replaces every tensor (``.to()``).
    """
    layout = model.layout
    if change.startswith("adam"):
        parameters = [p for p in model.parameters() if p.requires_grad]
        if not parameters:
            with torch.no_grad():
                for parameter in model.parameters():
                    parameter.mul_(1.1)
            return
        optimizer = torch.optim.Adam(parameters, lr=0.05, foreach=change == "adam_foreach")
        z, mask = layout.conditioned_window(torch.randn(5, layout.obs_dim))
        for _ in range(2):
            optimizer.zero_grad()
            model.denoiser(z, torch.ones(5), mask).square().mean().backward()
            optimizer.step()
    elif change == "load_state_dict":
        model.load_state_dict(fine_tuned(model, scale=0.5, seed=3).state_dict())
    elif change == "normalizer_fit":
        gen = torch.Generator().manual_seed(4)
        model.normalizer.fit(
            torch.randn(64, layout.obs_dim, generator=gen) * 5.0 - 1.0,
            torch.randn(64, layout.action_dim, generator=gen) + 1.0,
        )
    elif change == "double":
        model.double()
    else:
        raise ValueError(f"unknown change {change!r}")


def assert_all_close(got, expected, *, tol: float = 1e-5) -> None:
    """``torch.testing.assert_close`` over two equally long sequences of tensors."""
    assert len(got) == len(expected), (len(got), len(expected))
    for a, b in zip(got, expected, strict=True):
        torch.testing.assert_close(a, b, rtol=tol, atol=tol)


# ----------------------------------------------------------------------------- Laplace ensembles
ENSEMBLE_OBS_DIM, ENSEMBLE_ACTION_DIM = 2, 2


def ensemble_training_data(
    n: int = 256,
    obs_dim: int = ENSEMBLE_OBS_DIM,
    action_dim: int = ENSEMBLE_ACTION_DIM,
    seed: int = 0,
) -> TensorDict:
    """States in a small cluster around the origin; actions a smooth function of the state."""
    gen = torch.Generator().manual_seed(seed)
    observation = torch.randn(n, obs_dim, generator=gen) * 0.3
    action = torch.tanh(observation[:, :action_dim]) + 0.1 * torch.randn(
        n, action_dim, generator=gen
    )
    return TensorDict({"observation": observation, "action": action}, [n])


def identity_statistics(normalizer: Normalizer) -> Normalizer:
    """``normalizer`` with mean 0 and std 1 declared fitted (a fitted ``state_dict``
    loaded): the tests' by-hand computations then read the windows as they are."""
    state = normalizer.state_dict()
    state["fitted"] = torch.ones((), dtype=torch.bool)
    normalizer.load_state_dict(state)
    return normalizer


def ensemble_actor(kind: str, make_model, data: TensorDict | None = None, seed: int = 0):
    """A tiny ``LinearHeadActor`` (ReLU ``MLP``) or ``PlannerActor`` (normalizer fitted on
    ``data``); ``make_model`` is the conftest factory (unused for ``"linear_head"``)."""
    obs, act = ENSEMBLE_OBS_DIM, ENSEMBLE_ACTION_DIM
    data = ensemble_training_data() if data is None else data
    if kind == "linear_head":
        torch.manual_seed(seed)
        net = MLP(in_features=obs, out_features=act, num_cells=[16, 16], activation_class=nn.ReLU)
        return LinearHeadActor(net, act)
    model = make_model(TrajectoryLayout(obs, act, 4), num_steps=1, fit=False, seed=seed)
    model.normalizer.fit(data["observation"], data["action"] * 2.0)  # readout_scale != 1
    return PlannerActor(model)


def fitted_ensemble(kind: str, make_model, num_samples: int = 8, **kwargs) -> LaplaceEnsembleActor:
    """A ``LaplaceEnsembleActor`` over :func:`ensemble_actor`, fitted on two batches of
    :func:`ensemble_training_data`."""
    data = ensemble_training_data()
    policy = LaplaceEnsembleActor(
        ensemble_actor(kind, make_model, data), num_samples=num_samples, **kwargs
    )
    policy.fit_laplace([data[:128], data[128:]])
    return policy


def ensemble_observation_td(batch: int = 5, seed: int = 1, scale: float = 0.5) -> TensorDict:
    """``batch`` observations of the ensemble tests, ``scale`` times standard normal."""
    gen = torch.Generator().manual_seed(seed)
    return TensorDict(
        {"observation": torch.randn(batch, ENSEMBLE_OBS_DIM, generator=gen) * scale}, [batch]
    )


# ----------------------------------------------------------------------------- actor losses
def linear_head_actor(obs_dim: int = 3, action_dim: int = 2, *, seed: int = 0) -> LinearHeadActor:
    torch.manual_seed(seed)
    return LinearHeadActor(
        MLP(in_features=obs_dim, out_features=action_dim, num_cells=[8]), action_dim
    )


def tiny_iql_loss(
    obs_dim: int = 3,
    action_dim: int = 2,
    *,
    seed: int = 0,
    loss_class: type[IQLLoss] = IQLLoss,
    **kwargs,
) -> IQLLoss:
    """A real TorchRL ``IQLLoss`` (or ``loss_class``, with ``kwargs``) with tiny
    ``ValueOperator`` Q (twin) and V networks: one ``seed``, the same weights."""
    torch.manual_seed(seed)
    policy = tanh_normal_actor(obs_dim, action_dim)
    qvalue = ValueOperator(
        MLP(in_features=obs_dim + action_dim, out_features=1, num_cells=[8]),
        in_keys=["observation", "action"],
    )
    value = ValueOperator(
        MLP(in_features=obs_dim, out_features=1, num_cells=[8]), in_keys=["observation"]
    )
    return loss_class(policy, qvalue, value, num_qvalue_nets=2, **kwargs)


def observation_action_batch(
    batch: int = 16, obs_dim: int = 3, action_dim: int = 2, *, seed: int = 0
) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    return TensorDict(
        {
            "observation": torch.randn(batch, obs_dim, generator=gen),
            "action": torch.rand(batch, action_dim, generator=gen) * 2 - 1,
        },
        [batch],
    )
