"""Planner data augmentation: generated transitions added to ``D_online``.

EDIS; Algorithm 1 line 14, the grey step.

Every ``augment.every`` online updates (by default ``budget.laplace_refit_every``, the
"update frequency" of Algorithm 1 whose ``IF`` holds lines 14 and 17), a round:

1. refits the energy guider, a :class:`~torchrl_dual.diffusion.NoisyWindowClassifier` of
   noisy offline (0) vs real online (1) windows (``augment.guider_updates`` steps,
   :func:`~torchrl_dual.diffusion.density_ratio_loss`); its logit estimates
   ``log q_online(τ)/q_offline(τ) = −ε(τ)``;
2. refits the :class:`~torchrl_dual.modules.RewardModel` on real transitions of
   ``D_offline ∪ D_online`` (``augment.reward_updates`` steps): the windows carry no reward;
3. samples ``augment.num_windows`` windows from ``p_offline(τ)·e^{−ε(τ)}`` by classifier
   guidance of the trained planner's DDPM sampler (all ``planner.num_steps`` steps,
   ``augment.guidance_scale``), ``s_0`` drawn from the real online states and kept exact;
4. cuts each window into its ``H`` transitions ``(s_i, a_i, s_{i+1})``, the action clamped
   to the action box (and projected by the env kit, e.g. Frozen-Lake's one-hot argmax),
   labels them with the reward model (a window is cut after its first predicted terminal)
   and adds them to the online replay buffer.

**Marker.** A generated transition has a negative ``episode`` id (one per window, never
reused); :func:`is_generated` tells them apart. The real online episodes keep their
ids, so the guider and the reward model only ever learn from real data, and windows
never mix generated and real steps. The online buffer's capacity grows by
:func:`augment_capacity`, so generated data never overwrites real data.

The round runs after a block of updates (:meth:`PlannerAugmenter.after_updates`), so its
transitions feed the next block's gradient steps. A round with no real online window of
``H + 1`` steps yet is postponed to the next block.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from torchrl_dual.diffusion import (
    NoisyWindowClassifier,
    TrajectoryDiffusion,
    WindowReplayBuffer,
    classifier_guidance,
    density_ratio_loss,
)
from torchrl_dual.modules import PlannerSampler, RewardModel
from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.kits.build import env_kit
from torchrl_dual.recipe.o2o.learner import RunContext
from torchrl_dual.recipe.parts.planner_stage import offline_windows
from torchrl_dual.recipe.settings.parts import online_updates
from torchrl_dual.recipe.settings.structured import RecipeSettings

_REWARD_KEYS = (
    "observation",
    "action",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "terminated"),
)


def augment_capacity(settings: RecipeSettings) -> int:
    """Room the online buffer needs beyond the collected frames for the generated transitions.

    At most one round per ``augment.every`` online updates, ``num_windows × H``
    transitions each.
    """
    a = settings.get("augment")
    if a is None or a.kind == "none":
        return 0
    return online_updates(settings) // a.every * a.num_windows * settings.planner.horizon


def is_generated(transitions: TensorDictBase) -> torch.Tensor:
    """``[N]`` bool: the transitions the planner generated (negative ``episode`` ids).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"episode": torch.tensor([0, 0, -1, 1, -2])}, batch_size=[5])
        >>> is_generated(td).tolist()
        [False, False, True, False, True]
    """
    return transitions["episode"] < 0


class PlannerAugmenter:
    """Augmentation rounds for a learner with a trained planner (see the module docstring).

    A learner builds it last in its ``__init__`` (:func:`make_augmenter`), adds
    :meth:`modules` to its own, :meth:`state_dict` to its counters, calls
    :meth:`after_updates` from its own and sets ``extra_online_capacity`` to
    :func:`augment_capacity`.

    Args:
        run (RunContext): the run (its config's ``augment`` section, data, env, replay).
        planner (TrajectoryDiffusion): the ``N``-step planner trained on ``D_offline``.
    """

    def __init__(self, run: RunContext, planner: TrajectoryDiffusion) -> None:
        self.run = run
        settings = run.settings
        a = self.settings = settings.augment
        self.planner = planner
        self.layout = planner.layout
        self.offline_windows = offline_windows(settings, run.data, a.batch_size)
        # initialised from their own stream: the run's random stream, hence its offline
        # phase, is the same as without augmentation (and may be shared with such runs)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(settings.seed)
            self.guider = NoisyWindowClassifier(self.layout.window_shape, hidden=a.hidden)
            self.reward_model = RewardModel(planner.normalizer, hidden=a.hidden)
        self.guider.to(settings.device)
        self.reward_model.to(settings.device)
        self.guider_optimizer = adam(self.guider.parameters(), lr=a.lr)
        self.reward_optimizer = adam(self.reward_model.parameters(), lr=a.lr)
        self.sampler = PlannerSampler(planner, sampler="ddpm")
        space = run.env.action_spec.space
        self.action_low = space.low.to(settings.device)
        self.action_high = space.high.to(settings.device)
        self.projection = env_kit(settings).action_projection
        self.rounds_done = 0
        self.generated_windows = 0  # the next window's episode id is -(this + 1)

    # ------------------------------------------------------------------ learner protocol
    def modules(self) -> dict[str, Any]:
        """The guide, the reward model and their optimizers (checkpointed)."""
        return {
            "augment_guider": self.guider,
            "augment_guider_optimizer": self.guider_optimizer,
            "augment_reward": self.reward_model,
            "augment_reward_optimizer": self.reward_optimizer,
        }

    def state_dict(self) -> dict[str, int]:
        """The augmentation rounds done and the windows generated."""
        return {"rounds_done": self.rounds_done, "generated_windows": self.generated_windows}

    def load_state_dict(self, state: dict[str, int]) -> None:
        """Restores what :meth:`state_dict` returned."""
        self.rounds_done = state["rounds_done"]
        self.generated_windows = state["generated_windows"]

    def after_updates(self) -> None:
        """Runs a round once ``augment.every`` more online updates have been made."""
        done = self.run.updates - self.run.settings.budget.offline_updates
        if done // self.settings.every > self.rounds_done:
            if self.augment():
                self.rounds_done = done // self.settings.every

    # ------------------------------------------------------------------ one round
    def real_online(self) -> TensorDictBase:
        """The real (collected) transitions of ``D_online``, in episode order."""
        online = self.run.replay.online_buffer
        data = online[: len(online)]
        return data[~is_generated(data)] if len(online) else data

    def augment(self) -> bool:
        """One round (guider, reward model, generation); ``False`` if postponed."""
        a, real = self.settings, self.real_online()
        try:
            online_windows = WindowReplayBuffer(
                real, self.layout.horizon, a.batch_size, device=self.run.settings.device
            )
        except (ValueError, RuntimeError, KeyError):  # no real online window yet
            return False
        metrics = self.fit_guider(online_windows)
        metrics.update(self.fit_reward_model(real))
        windows = self.generate(real["observation"])
        generated = self.windows_to_transitions(windows, self.generated_windows)
        self.generated_windows += windows.shape[0]
        self.run.replay.extend(generated.cpu())
        metrics.update(
            transitions=generated.shape[0],
            reward_mean=float(generated["next", "reward"].mean()),
            log_ratio=float(self.log_ratio(windows).mean()),
        )
        self.run.log(metrics, self.run.updates, "augment/")
        return True

    def normalized(self, windows: TensorDictBase) -> torch.Tensor:
        """``[B, H + 1]`` window TensorDict -> the planner's normalized ``[B, H + 1, D]``."""
        return self.planner.normalized_window(windows["observation"], windows["action"])

    def normalize(self, windows: torch.Tensor) -> torch.Tensor:
        """Raw ``[B, H + 1, D]`` windows in the planner's normalized units."""
        layout = self.layout
        return self.planner.normalized_window(layout.observations(windows), layout.actions(windows))

    def fit_guider(self, online_windows: WindowReplayBuffer) -> dict[str, float]:
        """``augment.guider_updates`` logistic-loss steps, offline (0) vs online (1)."""
        mask = self.layout.condition_mask("s0", device=self.run.settings.device)
        metrics: dict[str, float] = {}
        for _ in range(self.settings.guider_updates):
            offline = self.normalized(self.offline_windows.sample().to(self.run.settings.device))
            online = self.normalized(online_windows.sample().to(self.run.settings.device))
            loss, accuracy = density_ratio_loss(self.guider, self.planner, offline, online, mask)
            self.guider_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.guider_optimizer.step()
            metrics = {"guider_loss": loss.item(), "guider_accuracy": accuracy.item()}
        return metrics

    def fit_reward_model(self, real: TensorDictBase) -> dict[str, float]:
        """``augment.reward_updates`` steps on half offline, half real online transitions."""
        keys = _REWARD_KEYS
        half, offline_data = self.settings.batch_size, self.run.data.transitions
        metrics: dict[str, float] = {}
        for _ in range(self.settings.reward_updates):
            offline = offline_data[torch.randint(offline_data.shape[0], (half,))].select(*keys)
            online = real[torch.randint(real.shape[0], (half,))].select(*keys)
            batch = torch.cat([offline, online], 0).to(self.run.settings.device)
            loss, metrics = self.reward_model.loss(batch)
            self.reward_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.reward_optimizer.step()
        return metrics

    @torch.no_grad()
    def generate(self, states: torch.Tensor) -> torch.Tensor:
        """``augment.num_windows`` raw guided windows ``[W, H + 1, D]``.

        ``s_0`` is drawn among ``states`` (kept exact).
        """
        a = self.settings
        s0 = states[torch.randint(states.shape[0], (a.num_windows,))].to(self.run.settings.device)
        guidance = classifier_guidance(self.guider, a.guidance_scale) if a.guidance_scale else None
        return self.sampler.plan(s0, deterministic=False, mean_shift=guidance)

    @torch.no_grad()
    def log_ratio(self, windows: torch.Tensor) -> torch.Tensor:
        """The guider's ``log q_online/q_offline`` (``−ε``) of raw clean windows (``t = 0``)."""
        normalized = self.normalize(windows)
        return self.guider(normalized, normalized.new_zeros(normalized.shape[0]))

    def windows_to_transitions(self, windows: torch.Tensor, first: int) -> TensorDictBase:
        """Raw ``[W, H + 1, D]`` windows -> flat transitions ``(s_i, a_i, s_{i+1})``, ``i < H``.

        The transitions carry the reward model's labels; window ``w`` gets ``episode
        = −(first + w + 1)``, and its transitions after the first predicted terminal
        are dropped.
        """
        layout = self.layout
        states, actions = layout.observations(windows), layout.actions(windows)
        actions = actions.clamp(self.action_low, self.action_high)
        if self.projection is not None:
            actions = self.projection(actions)
        s, a, s_next = states[:, :-1], actions[:, :-1], states[:, 1:]
        reward, terminated = self.reward_model.predict(s, a, s_next)
        past_terminal = (terminated.long().cumsum(1) - terminated.long()) > 0
        num_windows, horizon = s.shape[:2]
        episode = -(first + 1 + torch.arange(num_windows, device=s.device))
        transitions = TensorDict(
            {
                "observation": s,
                "action": a,
                "next": {
                    "observation": s_next,
                    "reward": reward,
                    "terminated": terminated,
                    "truncated": torch.zeros_like(terminated),
                    "done": terminated.clone(),
                },
                "episode": episode[:, None].expand(num_windows, horizon).clone(),
            },
            batch_size=[num_windows, horizon],
        )
        return transitions[~past_terminal.squeeze(-1)]


def make_augmenter(run: RunContext, planner: TrajectoryDiffusion) -> PlannerAugmenter | None:
    """The run's :class:`PlannerAugmenter` (``augment.kind=planner``), else ``None``."""
    if run.settings.augment.kind == "none":
        return None
    return PlannerAugmenter(run, planner)
