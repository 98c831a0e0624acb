"""
DUAL on other critics: Cal-QL, SO2 and OFF2ON's balanced replay
===============================================================

DUAL's actor loss (Eq. 7) works on any critic. Besides IQL's
(:class:`~torchrl_dual.objectives.IQLCriticLoss`, the :doc:`first tutorial
<1_dual_in_your_torchrl_loop>`), the package has the critics and the replay buffer of the
paper's other rows as TorchRL pieces:

1. :class:`~torchrl_dual.objectives.CalQLLoss`, Cal-QL's calibrated conservative critic
   (Nakamoto et al. 2023), on which the paper's Table 2 also runs DUAL;
2. :class:`~torchrl_dual.objectives.SO2QLoss`, SO2's Q ensemble (Zhang et al. 2024);
3. :class:`~torchrl_dual.data.BalancedReplayBuffer`, OFF2ON's balanced replay (Lee et
   al.), trained with :class:`~torchrl_dual.objectives.DensityRatioLoss`;
4. :class:`~torchrl_dual.objectives.DUALLoss` with SO2's ensemble as its critic.

In the recipe they are ``algo=calql``, ``algo=dual critic=calql``, ``algo=so2``,
``algo=dual critic=so2`` and ``replay=balanced`` (:doc:`../recipe`, "SO2 + OFF2ON").
Networks and batches are toy-sized: the point is the wiring.
"""

# %%
# A Cal-QL critic
# ---------------
# :class:`~torchrl_dual.objectives.CalQLLoss` is TorchRL's ``CQLLoss`` whose conservative
# penalty bounds the policy Q-values from below by the data's Monte-Carlo return
# ``G(s)``: ``max(Q(s, a∼π), G(s))`` inside the logsumexp.
# :func:`~torchrl_dual.data.monte_carlo_returns` labels the offline data once, with the
# critic's discount, and :func:`~torchrl_dual.data.episode_returns` labels an online
# episode when it ends. Both follow Cal-QL's code: the sum stops at an episode's last step
# whether it terminated or hit a time limit (no bootstrap of the tail), and with
# ``sparse_failure_reward=r_fail`` an episode that never left the failure reward is worth
# ``r_fail / (1 − γ)`` at every step. All of ``CQLLoss``'s knobs stay (``min_q_weight``,
# ``num_random``, ``temperature``, ``with_lagrange``); use ``loss_qvalue + loss_cql`` for
# the critics (only they receive its gradients). ``penalty_layout="calql"`` (default)
# groups the logsumexp as the Cal-QL reference code does; ``"torchrl"`` keeps
# ``CQLLoss``'s grouping, and with ``G = -inf`` reproduces ``CQLLoss`` itself.

import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.data import Bounded, LazyTensorStorage, ReplayBuffer
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import SoftUpdate

from torchrl_dual.data import BalancedReplayBuffer, make_transitions, monte_carlo_returns
from torchrl_dual.modules import LinearHeadActor
from torchrl_dual.modules.actors import ClippedNormal
from torchrl_dual.objectives import (
    CalQLLoss,
    DensityRatioLoss,
    DUALLoss,
    SO2QLoss,
    make_density_ratio_network,
)

torch.manual_seed(0)
torch.set_num_threads(1)

n = 6  # two 3-step episodes: one reaches the goal (terminated), one times out
cal_data = make_transitions(
    torch.randn(n, 3),
    torch.rand(n, 2) * 2 - 1,
    torch.randn(n, 3),
    torch.tensor([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]),
    torch.tensor([0, 0, 1, 0, 0, 0]).bool(),
    torch.tensor([0, 0, 0, 0, 0, 1]).bool(),
    torch.tensor([0, 0, 0, 1, 1, 1]),
)
cal_data["mc_return"] = monte_carlo_returns(cal_data, gamma=0.99)
print("G:", cal_data["mc_return"].squeeze(-1))  # [0.98, 0.99, 1, 0, 0, 0]

cal_spec = Bounded(-torch.ones(2), torch.ones(2), (2,))
cal_actor = ProbabilisticActor(
    TensorDictModule(
        nn.Sequential(MLP(in_features=3, out_features=4, num_cells=[16]), NormalParamExtractor()),
        in_keys=["observation"],
        out_keys=["loc", "scale"],
    ),
    in_keys=["loc", "scale"],
    spec=cal_spec,
    distribution_class=TanhNormal,
)
cal_q = ValueOperator(
    MLP(in_features=5, out_features=1, num_cells=[16]), in_keys=["observation", "action"]
)
calql = CalQLLoss(cal_actor, cal_q, min_q_weight=5.0, num_random=4)
calql.make_value_estimator(gamma=0.99)
cal_out = calql(cal_data)
(cal_out["loss_qvalue"] + cal_out["loss_cql"]).backward()
print(f"loss_cql={cal_out['loss_cql'].item():.2f}, bounded: {cal_out['bound_rate'].item():.0%}")

# %%
# SO2's Q ensemble and OFF2ON's balanced replay
# ---------------------------------------------
# :class:`~torchrl_dual.objectives.SO2QLoss` is an ensemble of ``E = 10`` Q networks, one
# functional module evaluated with ``vmap``, trained on TD3-smoothed targets
# ``ã' = clip(a' + clip(σ·ε, −c, c), low, high)`` with ``σ = 0.3``, ``c = 0.6``. As in the
# authors' code, each member regresses on its own target
# ``y_k = r + γ(1 − terminated)(Q̄_k(s', ã') − α·log π(a'|s'))``
# (``target_reduction="min"`` or ``"mean"`` are variants), ``a'`` is a sample of a SAC
# actor (``entropy_coef=0.2`` with ``return_log_prob=True``), and the actor maximises
# ``loss.q_value(s, a)``, the minimum over the members. Targets follow with TorchRL's
# ``SoftUpdate(loss, tau=0.005)``; SO2's 10 critic updates per env step are the loop's
# business.
#
# :class:`~torchrl_dual.data.BalancedReplayBuffer` replaces TorchRL's
# ``OfflineToOnlineReplayBuffer``: each transition of ``D_offline ∪ D_online`` is drawn
# with probability proportional to
# ``p = clip(w^{1/T} / mean_offline(w^{1/T}), 10⁻³, 10³)``, ``T = 5``, where
# ``w(s, a) ≈ d_online / d_offline`` is a network trained by
# :class:`~torchrl_dual.objectives.DensityRatioLoss` (the Jensen-Shannon estimator of the
# authors' code). Priorities are refreshed for each sampled batch; new online data gets
# the largest priority seen so far.


def toy_transitions(n):
    return TensorDict(
        {
            "observation": torch.randn(n, 3),
            "action": torch.rand(n, 1) * 2 - 1,
            "next": {
                "observation": torch.randn(n, 3),
                "reward": torch.randn(n, 1),
                "terminated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        [n],
    )


offline_data = ReplayBuffer(storage=LazyTensorStorage(500))
offline_data.extend(toy_transitions(500))
ratio_net = make_density_ratio_network(3, 1, num_cells=(32, 32))
replay = BalancedReplayBuffer(
    offline_data, online_capacity=1000, batch_size=64, ratio_network=ratio_net
)
replay.extend(toy_transitions(100))  # online data

sac_actor = ProbabilisticActor(
    TensorDictModule(
        nn.Sequential(MLP(3, 2, num_cells=[32]), NormalParamExtractor()),
        ["observation"],
        ["loc", "scale"],
    ),
    in_keys=["loc", "scale"],
    distribution_class=TanhNormal,
    return_log_prob=True,
)
so2 = SO2QLoss(
    sac_actor,
    ValueOperator(MLP(4, 1, num_cells=[32]), ["observation", "action"]),
    action_spec=Bounded(-1.0, 1.0, (1,)),
    num_qvalue_nets=10,
    entropy_coef=0.2,
)
ratio_loss = DensityRatioLoss(ratio_net)
critic_optim = torch.optim.Adam(so2.parameters(), lr=3e-4)
ratio_optim = torch.optim.Adam(ratio_loss.parameters(), lr=3e-4)
so2_targets = SoftUpdate(so2, tau=0.005)
for _ in range(10):  # SO2: 10 critic updates per env step
    batch = replay.sample()
    critic_optim.zero_grad()
    so2(batch)["loss_qvalue"].backward()
    critic_optim.step()
    so2_targets.step()
    ratio_batch = replay.ratio_batch()
    ratio_optim.zero_grad()
    ratio_loss(ratio_batch)["loss_density_ratio"].backward()
    ratio_optim.step()
    replay.refresh_priorities(batch, ratio_batch)  # OFF2ON: lazily, for the sampled batch
# the actor's objective: min_k Q_k(s, a) - α log π(a|s), critic weights detached
q_pi = so2.q_value(batch["observation"], batch["action"])
print(f"min_k Q_k on the last batch: {q_pi.mean().item():.3f}, shape {tuple(q_pi.shape)}")

# %%
# The cost of these updates (SO2 at ``E = 10`` is about 2.5x a TorchRL ``IQLLoss`` critic
# update; the balanced replay adds about half an IQL update) is measured by
# ``python -m benchmarks.speed.so2_cost`` (:doc:`../benchmarks`, "The other critics'
# updates").
#
# DUAL's actor on SO2's ensemble
# ------------------------------
# :class:`~torchrl_dual.objectives.DUALLoss` takes :class:`~torchrl_dual.objectives.CalQLLoss`
# or :class:`~torchrl_dual.objectives.SO2QLoss` as its critic in place of
# :class:`~torchrl_dual.objectives.IQLCriticLoss`. Neither has a value network, so Eq. 7
# uses the ``"sac"`` weighting (``weighting="advantage"`` needs IQL's ``V``). The critic
# samples DUAL's own actor ``N(μ(s), σ̄²)``, its draws clamped to the action box
# (:class:`~torchrl_dual.modules.actors.ClippedNormal`), so the critic's policy and Eq. 7
# read the same weights.


class MeanAndStd(nn.Module):
    """``observation -> (μ(s), σ̄)`` of a last-layer actor."""

    def __init__(self, actor):
        super().__init__()
        self.actor = actor

    def forward(self, observation):
        loc = self.actor(observation)
        return loc, self.actor.std.expand_as(loc)


box = Bounded(-1.0, 1.0, (1,))
dual_actor = LinearHeadActor(MLP(in_features=3, out_features=1, num_cells=[32]), 1)
dual_policy = ProbabilisticActor(
    TensorDictModule(MeanAndStd(dual_actor), ["observation"], ["loc", "scale"]),
    in_keys=["loc", "scale"],
    spec=box,
    distribution_class=ClippedNormal,
    distribution_kwargs={"low": box.low, "high": box.high},
    return_log_prob=True,  # SO2's targets read log π(a'|s')
)
so2_critic = SO2QLoss(
    dual_policy,
    ValueOperator(MLP(4, 1, num_cells=[32]), ["observation", "action"]),
    action_spec=box,
    num_qvalue_nets=10,
)
dual = DUALLoss(dual_actor, so2_critic, weighting="sac", action_spec=box)
dual.make_value_estimator(gamma=0.99)
dual_targets = SoftUpdate(dual, tau=0.005)  # the critic's targets, now DUALLoss's own
dual_optim = torch.optim.Adam(dual.parameters(), lr=3e-4)
dual_out = dual(replay.sample())  # TorchRL's way: one optimizer over every loss_* term
losses = [key for key in dual_out.keys() if key.startswith("loss_")]
sum(dual_out[key] for key in losses).backward()
dual_optim.step()
dual_targets.step()
print(sorted(losses))
