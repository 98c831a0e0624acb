"""The ``iql`` baseline: Implicit Q-Learning (Kostrikov et al. 2022) offline, then online.

TorchRL's ``IQLLoss`` trains an MLP actor by advantage-weighted regression
(``exp(β (Q − V))``, clipped at 100) on the same IQL critics as DUAL (the ``CRITICS``
entry, same sizes), with CORL's settings (actor MLP 256 x 2 at the default budget, Adam
3e-4, β = 3). The actor is CORL's and d3rlpy's Gaussian with a tanh mean and a
state-independent σ (``actor.distribution=gaussian``, the default; checked against
d3rlpy's IQL on the same data, docs/results.md) or TorchRL's ``TanhNormal``
(``tanh_normal``), see :func:`make_iql_actor`. It shares everything else with DUAL
through :class:`~torchrl_dual.recipe.O2ORun`: data, ``budget.offline_updates`` offline
updates, online frames, UTD ratio, batch size, offline fraction, replay and evaluator.
Online it collects with the actor's samples (``ExplorationType.RANDOM``), projected onto
the box and by the env kit's ``action_projection`` (Frozen-Lake's one-hot argmax), and is
evaluated with its deterministic action (the Gaussian's mean; ``tanh(loc)`` for the
``TanhNormal``).
"""

from __future__ import annotations

from tensordict import TensorDictBase
from tensordict.nn import (
    AddStateIndependentNormalScale,
    NormalParamExtractor,
    TensorDictModule,
)
from torch import nn
from torchrl.data import TensorSpec
from torchrl.data.utils import DEVICE_TYPING
from torchrl.envs.utils import ExplorationType
from torchrl.modules import MLP, IndependentNormal, ProbabilisticActor, TanhNormal

from torchrl_dual.modules.actors.last_layer_actor import TanhSquash
from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.kits.build import projected_policy
from torchrl_dual.recipe.o2o.learner import Learner, RunContext
from torchrl_dual.recipe.parts.critics import make_critic
from torchrl_dual.recipe.settings.baselines import (
    ACTOR_DISTRIBUTIONS,
    MLPActorSettings,
)


def make_iql_actor(
    settings: MLPActorSettings,
    obs_dim: int,
    action_spec: TensorSpec,
    *,
    distribution: str = "tanh_normal",
    return_log_prob: bool = False,
    device: DEVICE_TYPING = "cpu",
) -> ProbabilisticActor:
    """The AWR baselines' MLP actor on the action box of ``action_spec``, on ``device``.

    ``settings.depth`` hidden layers of ``settings.hidden`` units; with
    ``return_log_prob`` it writes ``"action_log_prob"`` too.

    ``distribution="gaussian"`` is CORL's and d3rlpy's IQL actor:
    ``π(a|s) = N(c + r ⊙ tanh(f(s)), diag σ²)`` with one learned ``σ = exp(log σ)`` per
    action dimension (TensorDict's ``AddStateIndependentNormalScale``, initial ``σ = 1``),
    a density over all of ``ℝ^d``, so a data action on a face of the box (61 % of
    PointMaze's action components) has a finite log-likelihood; draws are projected onto
    the box (``safe=True``) and the deterministic action is the mean, inside the box.
    ``distribution="tanh_normal"`` is TorchRL's ``TanhNormal(loc(s), scale(s))`` with a
    state-dependent scale, the SAC-style actor of ``calql`` and ``so2`` (their losses
    need its reparameterised, box-bounded draws and its log-density): on a face,
    ``atanh(±1)`` is clamped, and the AWR fit of such an action is dominated by the clamp.
    """
    a = settings
    action_dim = action_spec.shape[-1]
    space = action_spec.space
    low, high = space.low.to(device), space.high.to(device)
    mlp = MLP(
        in_features=obs_dim,
        out_features=(1 if distribution == "gaussian" else 2) * action_dim,
        num_cells=[a.hidden] * a.depth,
        activation_class=nn.ReLU,
    )
    if distribution == "gaussian":
        net = nn.Sequential(mlp, TanhSquash(low, high), AddStateIndependentNormalScale(action_dim))
        dist_class, dist_kwargs = IndependentNormal, {}
    elif distribution == "tanh_normal":
        net = nn.Sequential(mlp, NormalParamExtractor())
        dist_class, dist_kwargs = TanhNormal, {"low": low, "high": high}
    else:
        raise ValueError(
            f"unknown actor distribution {distribution!r}; choose one of "
            + ", ".join(ACTOR_DISTRIBUTIONS)
        )
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=action_spec,
        safe=distribution == "gaussian",
        distribution_class=dist_class,
        distribution_kwargs=dist_kwargs,
        default_interaction_type=ExplorationType.RANDOM,
        return_log_prob=return_log_prob,
    ).to(device)


class IQLLearner(Learner):
    """IQL: one ``budget.offline_updates`` stage offline, then the same update online.

    Examples:
        >>> import contextlib, io, tempfile
        >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked, run_o2o
        >>> out = tempfile.mkdtemp()
        >>> cfg = compose_checked(CONFIG_DIR, [
        ...     "algo=iql", "env=frozenlake", "budget=smoke", "progress=false",
        ...     f"output_dir={out}/run", f"data_cache_dir={out}/data",
        ...     "budget.dataset_transitions=1000", "budget.network_width=16",
        ...     "budget.offline_updates=4", "budget.online_frames=100",
        ...     "budget.frames_per_batch=50", "budget.eval_episodes=1"])
        >>> with contextlib.redirect_stdout(io.StringIO()):
        ...     run = run_o2o(cfg, IQLLearner)
        >>> run.stages_done, run.frames
        (['actor_critic', 'offline_eval'], 100)
        >>> sorted(run.learner.modules())  # what the checkpoint holds
        ['actor_optimizer', 'critic', 'critic_optimizer']
    """

    title = "IQL"
    shared_stages = ("actor_critic",)  # offline_cache: shared by every online shift

    def __init__(self, run: RunContext) -> None:
        self.run = run
        settings = run.settings
        spec = run.env.action_spec
        self.settings = settings
        s = settings.actor
        self.actor = make_iql_actor(
            s, run.data.obs_dim, spec, distribution=s.distribution, device=settings.device
        )
        self.critic = make_critic(
            settings,
            run.data.obs_dim,
            run.data.action_dim,
            actor=self.actor,
            temperature=s.temperature,
        )
        self.actor_optimizer = adam(self.actor.parameters(), lr=s.lr)
        self.evaluation_policy = self.actor
        self.exploration_policy = projected_policy(settings, self.actor)

    def modules(self) -> dict:
        """The IQL loss holds the actor, V, both Q and the target Q networks."""
        return {
            **self.critic.modules(),
            "actor_optimizer": self.actor_optimizer,
        }

    def offline_stages(self) -> list:
        """One offline stage: ``budget.offline_updates`` IQL updates on D_offline."""
        return [("actor_critic", self.run.pretrain_updates)]

    def update(self, batch: TensorDictBase) -> dict:
        """IQL's three losses on one batch, one step of each optimizer, then the soft target update.

        The actor's and V's targets are the target Q networks, so no gradient
        crosses; :meth:`~torchrl_dual.objectives.OnePassIQLLoss.terms` evaluates
        them and ``V(s)`` once for both.
        """
        loss = self.critic.loss
        terms = loss.terms(batch)
        q_loss, v_loss, actor_loss = (terms[k] for k in ("loss_qvalue", "loss_value", "loss_actor"))
        self.critic.optimizer.zero_grad(set_to_none=True)
        self.actor_optimizer.zero_grad(set_to_none=True)
        (q_loss + v_loss + actor_loss).backward()
        self.critic.optimizer.step()
        self.actor_optimizer.step()
        self.critic.target_updater.step()
        return {
            "loss_qvalue": q_loss.detach(),
            "loss_value": v_loss.detach(),
            "loss_actor": actor_loss.detach(),
            "log_prob": batch[loss.tensor_keys.log_prob].mean().detach(),
        }
