"""
DUAL's parts in your own TorchRL loop
=====================================

DUAL (Algorithm 1 of the paper) is a handful of TorchRL objects. This tutorial wires
them by hand on ``Pendulum-v1`` at toy size, without the recipe:

1. an env transform that hands the policy the previous step ``(s_{t-1}, a_{t-1})``;
2. a trajectory diffusion planner trained on ``H``-step windows (Eq. 3);
3. its progressive distillation to a one-step sampler, whose action head is the actor;
4. DUAL's update as one loss, :class:`~torchrl_dual.objectives.DUALLoss` (IQL's critics,
   :class:`~torchrl_dual.objectives.IQLCriticLoss`, and Eq. 7's weighted MAP actor),
   stepped in Alg. 1's order by :class:`~torchrl_dual.trainers.CriticActorStepper`;
5. the last-layer Laplace ensemble (Eq. 8-9) and the shift-aware noise (Eq. 10);
6. online collection with TorchRL's ``Collector`` and online updates.

Every network is tiny and every loop a few dozen steps: the point is the wiring, not the
score. The :doc:`../pipeline` guide is the same example at full length, with every key
each part reads and writes.
"""

# %%
# Offline data in the transition layout
# -------------------------------------
# Any flat TensorDict with :data:`~torchrl_dual.data.TRANSITION_KEYS` works: the root
# ``observation`` and ``action``, the ``("next", ...)`` entries TorchRL's rollouts write,
# and an int64 ``episode`` id with each episode stored contiguously (windows of the
# planner never cross an episode). :func:`~torchrl_dual.data.validate_transitions`
# checks the layout. Here: 6 episodes of 40 random-action steps.
# :class:`~torchrl_dual.transforms.PreviousTransition` adds the previous observation and
# action, which the shift signal ``d_t`` of Eq. 10 compares with the planner's
# prediction.

import matplotlib.pyplot as plt
import torch
from tensordict.nn import TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, OfflineToOnlineReplayBuffer, ReplayBuffer
from torchrl.envs import GymEnv
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives import SoftUpdate

from torchrl_dual.data import TRANSITION_KEYS, validate_transitions
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout, WindowReplayBuffer
from torchrl_dual.modules import (
    LaplaceEnsembleActor,
    PlannerActor,
    ShiftAwareNoise,
    TransitionModel,
)
from torchrl_dual.objectives import (
    DiffusionPlannerLoss,
    DUALLoss,
    IQLCriticLoss,
    progressive_distillation,
)
from torchrl_dual.trainers import CriticActorStepper
from torchrl_dual.transforms import PreviousTransition

torch.manual_seed(0)
torch.set_num_threads(1)

env = GymEnv("Pendulum-v1").append_transform(PreviousTransition())
episodes = []
for episode in range(6):
    env.set_seed(episode)
    rollout = env.rollout(max_steps=40)
    rollout["episode"] = torch.full((40,), episode)
    episodes.append(rollout.select(*TRANSITION_KEYS))
transitions = validate_transitions(torch.cat(episodes))
print(transitions.batch_size, list(transitions.keys(True, True)))

# %%
# The diffusion planner (Eq. 3; Alg. 1 lines 3-4)
# -----------------------------------------------
# :class:`~torchrl_dual.diffusion.TrajectoryDiffusion` denoises ``[H + 1, obs + action]``
# windows; :class:`~torchrl_dual.diffusion.WindowReplayBuffer` draws them from the flat
# transitions, and :class:`~torchrl_dual.objectives.DiffusionPlannerLoss` is its TorchRL
# loss. Half of the windows keep ``a_0`` known (``action_condition_prob=0.5``), which
# trains the transition model ``p(s'|s, a)`` into the same network. Its normalizer must be
# fitted on the offline data first.

layout = TrajectoryLayout(obs_dim=3, action_dim=1, horizon=4)
teacher = TrajectoryDiffusion(layout, num_steps=8, hidden=32, depth=1)
teacher.normalizer.fit(transitions["observation"], transitions["action"])
windows = WindowReplayBuffer(transitions, horizon=4, batch_size=32)
planner_loss = DiffusionPlannerLoss(teacher, action_condition_prob=0.5)
planner_optimizer = torch.optim.Adam(planner_loss.parameters(), lr=1e-3)
planner_curve = []
for _ in range(40):
    loss = planner_loss(windows.sample())["loss_diffusion"]
    planner_optimizer.zero_grad()
    loss.backward()
    planner_optimizer.step()
    planner_curve.append(loss.item())

# %%
# Distillation to one step, the actor and the transition model (Alg. 1 line 5)
# ----------------------------------------------------------------------------
# :func:`~torchrl_dual.objectives.progressive_distillation` halves the number of sampling
# steps per round (8, 4, 2, 1). The one-step student is ``π_θ``'s mean:
# :class:`~torchrl_dual.modules.PlannerActor` reads ``μ(s) = τ_a0`` at latent ``z = 0`` and
# fine-tunes the student's weights; :class:`~torchrl_dual.modules.TransitionModel` keeps a
# frozen copy as the transition model of Eq. 10.

student = progressive_distillation(teacher, windows.sample, updates_per_round=3, progress=False)
actor = PlannerActor(student)
transition_model = TransitionModel.frozen_copy(student)

# %%
# DUAL's update: one loss, two optimizers (Eq. 7; Alg. 1 lines 6-8)
# -----------------------------------------------------------------
# :class:`~torchrl_dual.objectives.IQLCriticLoss` is TorchRL's ``IQLLoss`` without its
# actor: twin Q networks and an expectile value network.
# :class:`~torchrl_dual.objectives.DUALLoss` pairs it with Eq. 7's advantage-weighted MAP
# actor loss and owns both parts' parameters, so TorchRL's ``SoftUpdate``, ``state_dict``
# and ``.to(device)`` see one module. Its ``forward`` returns every term, as ``IQLLoss``
# does; :class:`~torchrl_dual.trainers.CriticActorStepper` instead keeps Algorithm 1's
# order: a critic step, the target update, then an actor step on the updated critic.

critic = IQLCriticLoss(
    ValueOperator(
        MLP(in_features=4, out_features=1, num_cells=[32, 32]), ["observation", "action"]
    ),
    ValueOperator(MLP(in_features=3, out_features=1, num_cells=[32, 32]), ["observation"]),
    loss_function="l2",
    expectile=0.7,
)
loss = DUALLoss(actor, critic, temperature=3.0)
loss.make_value_estimator(gamma=0.99)
stepper = CriticActorStepper(
    loss,
    torch.optim.Adam(loss.critic_parameters(), lr=3e-4),
    torch.optim.Adam(loss.actor_parameters(), lr=3e-4),
    target_update=SoftUpdate(loss, tau=0.005),
)

keys = [key for key in TRANSITION_KEYS if key != "episode"]
offline = ReplayBuffer(storage=LazyTensorStorage(len(transitions)))
offline.extend(transitions.select(*keys))
offline_terms = [stepper.update(offline.sample(64)) for _ in range(30)]
print(sorted(offline_terms[-1].keys()))

# %%
# The acting policy: Laplace ensemble and shift-aware noise (Eq. 8-10)
# --------------------------------------------------------------------
# :class:`~torchrl_dual.modules.LaplaceEnsembleActor` fits a Laplace posterior over the
# actor's last layer (Eq. 8, the prior precision chosen by the evidence) and acts with the
# ensemble's mean and epistemic variance (Eq. 9); given the transition model it also
# predicts ``ŝ_t`` from ``(s_{t-1}, a_{t-1})``. :class:`~torchrl_dual.modules.ShiftAwareNoise`
# widens the executed action's noise with the distance ``d_t`` between ``ŝ_t`` and the
# observed ``s_t`` (Eq. 10). (:func:`~torchrl_dual.modules.make_dual_policy` builds the
# same two-module policy in one call.)

ensemble = LaplaceEnsembleActor(
    actor,
    num_samples=5,
    action_low=-2.0,
    action_high=2.0,
    sample_action=False,  # ShiftAwareNoise draws the executed action
    transition_model=transition_model,
)
laplace = ensemble.fit_laplace(
    transitions.split(80), weight_fn=loss.actor_objective.advantage_weights
)
print(f"prior precision chosen by the evidence: {laplace.prior_precision.item():.3g}")
policy = TensorDictSequential(ensemble, ShiftAwareNoise(env.action_spec, shift_weight=0.5))

# %%
# Online: collect, store, update, refit (Alg. 1 lines 11-17)
# ----------------------------------------------------------
# TorchRL's ``OfflineToOnlineReplayBuffer`` mixes a fixed share of offline transitions
# into every batch. The collected batches carry what the policy wrote: the executed
# (noisy) action, ``epistemic_variance`` and ``shift_distance``.

replay = OfflineToOnlineReplayBuffer(
    offline, online_capacity=500, offline_fraction=0.5, batch_size=64
)
collector = Collector(
    env, policy, frames_per_batch=40, total_frames=120, auto_register_policy_transforms=False
)
online_terms, shift = [], []
for data in collector:
    shift.append(data["shift_distance"].mean().item())
    replay.extend(data.select(*keys))
    online_terms += [stepper.update(replay.sample()) for _ in range(10)]
    ensemble.fit_laplace(
        [offline[:], replay.online_buffer[:]], weight_fn=loss.actor_objective.advantage_weights
    )
collector.shutdown()
print("mean d_t per collected batch:", [round(d, 3) for d in shift])

# %%
# What the losses did
# -------------------
# The planner's denoising loss, then the critic's TD loss and the actor's loss over the
# offline and the online updates (toy sizes: the curves show the wiring runs, not that
# DUAL has learned Pendulum).

terms = offline_terms + online_terms
fig, axes = plt.subplots(1, 3, figsize=(11, 3))
axes[0].plot(planner_curve)
axes[0].set(title="planner: loss_diffusion", xlabel="update")
axes[1].plot([t["loss_qvalue"].item() for t in terms])
axes[1].set(title="critic: loss_qvalue", xlabel="update")
axes[2].plot([t["loss_actor"].item() for t in terms])
axes[2].set(title="actor: loss_actor (Eq. 7)", xlabel="update")
for ax in axes[1:]:
    ax.axvline(len(offline_terms), color="grey", linestyle="--", linewidth=1)
fig.tight_layout()
plt.show()
