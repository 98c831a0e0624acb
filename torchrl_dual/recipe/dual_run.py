"""The state of one DUAL run and the steps of Algorithm 1 that act on it.

:class:`DualRun` owns the data, networks, losses, optimizers, replay buffers, logger
and counters of a run, checkpoints all of them atomically (each weight once), and
resumes from them. :func:`~torchrl_dual.recipe.dual.run_dual` calls its methods in the
order of Algorithm 1.
"""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import (
    LazyTensorStorage,
    OfflineToOnlineReplayBuffer,
    RandomSampler,
    ReplayBuffer,
)
from torchrl.envs.utils import ExplorationType
from torchrl.record.loggers import get_logger
from tqdm.auto import tqdm

from torchrl_dual.checkpoint import CheckpointError, RunCheckpoint, rng_state, set_rng_state
from torchrl_dual.data import TRANSITION_KEYS
from torchrl_dual.diffusion import WindowReplayBuffer
from torchrl_dual.objectives import progressive_distillation, train_planner
from torchrl_dual.recipe import env_kits, networks
from torchrl_dual.recipe.critics import CRITICS
from torchrl_dual.recipe.errors import ConfigError, UserError
from torchrl_dual.recipe.plots import plot_learning_curve

STAGES = ("planner", "distillation", "actor_critic", "laplace", "offline_eval")
# Settings that may change when a run is resumed; everything else must match.
RESUMABLE_KEYS = ("resume", "progress", "interrupt_at_frames", "num_threads", "device", "debug")
_COUNTERS = (
    "stages_done",
    "frames",
    "updates",
    "updates_since_refit",
    "update_credit",
    "next_episode",
    "history",
)


def check_output_dir(cfg: DictConfig) -> None:
    """``output_dir`` must be a directory (or not exist yet) and hold no checkpoint unless
    ``resume=true``: a fresh run never overwrites another run's checkpoint."""
    output_dir = Path(cfg.output_dir)
    for path in (output_dir, *output_dir.parents):
        if path.exists() and not path.is_dir():
            raise ConfigError("output_dir", cfg.output_dir, f"{path} is a file, not a directory")
    checkpoint = output_dir / "checkpoint.pt"
    if checkpoint.exists() and not cfg.resume:
        raise ConfigError(
            "resume",
            False,
            f"{checkpoint} exists: pass resume=true to continue that run, or choose "
            "another output_dir (or delete it) to start afresh",
        )


class DualRun:
    """Everything one run of Algorithm 1 needs, with checkpoint and resume.

    ``cfg`` must have passed :func:`~torchrl_dual.recipe.validate_config`.
    """

    def __init__(self, cfg: DictConfig) -> None:
        self.cfg = cfg
        torch.set_num_threads(cfg.num_threads)
        self.seed_everything(cfg.seed)
        self.output_dir = Path(cfg.output_dir)
        fingerprint = {
            k: v
            for k, v in OmegaConf.to_container(cfg, resolve=True).items()
            if k not in RESUMABLE_KEYS
        }
        check_output_dir(cfg)
        self.checkpoint = RunCheckpoint(self.output_dir / "checkpoint.pt", fingerprint)
        # Read a checkpoint first, so a corrupt or incompatible one fails before any work.
        saved = self._load_checkpoint() if cfg.resume and self.checkpoint.exists() else None
        # ---- data and envs (Alg. 1 line 1)
        self.data = env_kits.make_offline_dataset(cfg)
        self.env = env_kits.make_train_env(cfg)
        env_kits.check_dims(self.env, self.data, cfg.env.name)
        self.evaluate_policy = env_kits.make_evaluator(cfg, self.data)
        try:
            self.windows = WindowReplayBuffer(
                self.data.transitions,
                cfg.planner.horizon,
                cfg.planner.batch_size,
                device=cfg.device,
            )
        except ValueError as err:  # no episode is long enough for a window
            raise UserError("planner.horizon", cfg.planner.horizon, str(err)) from err
        self.offline_buffer = self._offline_buffer()
        # ---- networks: teacher g_θ', actor π_θ and its transition model, critics
        self.teacher = networks.make_planner(cfg, self.data)
        self.actor = networks.make_actor(cfg, self.teacher)
        self.transition = networks.make_transition_model(cfg, self.teacher, self.actor)
        make_critic = CRITICS[cfg.critic.name][1]
        self.critic = make_critic(cfg, self.data.obs_dim, self.data.action_dim)
        self.actor_loss = networks.make_actor_loss(cfg, self.actor, self.critic)
        self.actor_optimizer = torch.optim.Adam(self.actor_loss.parameters(), lr=cfg.actor.lr)
        self.policy = networks.make_policy(cfg, self.actor, self.env.action_spec, self.transition)
        self.ensemble = self.policy[0]  # LaplaceEnsembleActor: acts and holds ŝ_t's model
        self.replay = OfflineToOnlineReplayBuffer(
            self.offline_buffer,
            online_capacity=max(cfg.budget.online_frames, 1),
            offline_fraction=cfg.online.offline_fraction,
            batch_size=cfg.online.batch_size,
        )
        # ---- counters
        self.stages_done: list[str] = []
        self.frames = 0
        self.updates = 0
        self.updates_since_refit = 0
        self.update_credit = 0.0
        self.next_episode = int(self.data.transitions["episode"].max()) + 1
        self.history: list[dict] = []
        logger_state = self.load(saved) if saved is not None else None
        self.logger = get_logger(
            cfg.logger.backend, str(self.output_dir / "logs"), "dual", state_dict=logger_state
        )

    # ------------------------------------------------------------------ bookkeeping
    @staticmethod
    def seed_everything(seed: int) -> None:
        random.seed(seed)
        np.random.seed(seed)
        torch.manual_seed(seed)

    def _offline_buffer(self) -> ReplayBuffer:
        """Uniform transitions from D_offline; a plain ``ReplayBuffer`` so its samples carry
        the same keys as the online part of ``OfflineToOnlineReplayBuffer``."""
        buffer = ReplayBuffer(
            storage=LazyTensorStorage(len(self.data), device=self.cfg.device),
            sampler=RandomSampler(),
            batch_size=self.cfg.online.batch_size,
        )
        buffer.extend(self.data.transitions)
        return buffer

    def modules(self) -> dict:
        """What the checkpoint holds, each weight once: the frozen transition model is
        inside the ensemble, a shared one is the actor's own planner."""
        return {
            "teacher": self.teacher,
            "ensemble": self.ensemble,  # actor, σ̄, Laplace posterior, frozen ŝ_t model
            "critic": self.critic.loss,
            "critic_optimizer": self.critic.optimizer,
            "actor_optimizer": self.actor_optimizer,
        }

    def save(self) -> None:
        """Checkpoints everything needed to continue (atomic write)."""
        online = self.replay.online_buffer
        state = {name: module.state_dict() for name, module in self.modules().items()}
        state.update({name: getattr(self, name) for name in _COUNTERS})
        state.update(
            online_data=online[: len(online)].clone() if len(online) else None,
            rng=rng_state(),
            logger=self.logger.state_dict() if hasattr(self.logger, "state_dict") else None,
        )
        self.checkpoint.save(state)

    def _load_checkpoint(self) -> dict:
        try:
            return self.checkpoint.load()
        except CheckpointError as err:  # corrupt, not a checkpoint, or another run's settings
            raise UserError("resume", True, str(err)) from err

    def load(self, state: dict | None = None):
        """Restores the checkpoint's ``state`` (read if not given); returns the logger's."""
        state = self._load_checkpoint() if state is None else state
        try:
            for name, module in self.modules().items():
                module.load_state_dict(state[name])
        except (KeyError, RuntimeError, ValueError) as err:
            raise UserError(
                "resume",
                True,
                f"the checkpoint {self.checkpoint.path} does not fit this run's networks "
                f"({err}). Resume with the settings that wrote it, or use another output_dir.",
            ) from err
        for name in _COUNTERS:
            setattr(self, name, state[name])
        if state["online_data"] is not None:
            self.replay.extend(state["online_data"])
            # The collector starts a new episode on resume: never reuse the cut one's id.
            self.next_episode = int(state["online_data"]["episode"].max()) + 1
        set_rng_state(state["rng"])
        return state["logger"]

    def stage(self, name: str, fn) -> None:
        """Runs one offline step of Algorithm 1 unless a resumed run already did it."""
        if name in self.stages_done:
            print(f"[dual] {name}: done in the checkpoint, skipped")
            return
        fn()
        self.stages_done.append(name)
        self.save()

    def log(self, values: dict, step: int, prefix: str) -> None:
        for key, value in values.items():
            self.logger.log_scalar(f"{prefix}{key}", float(value), step=step)

    # ------------------------------------------------------------------ offline phase
    def pretrain_planner(self) -> None:
        """Alg. 1 lines 3-4: θ' ← θ' − λ_g ∇ L_VLB on D_offline (Eq. 3)."""
        p = self.cfg.planner
        train_planner(
            self.teacher,
            self.windows.sample,
            self.cfg.budget.planner_updates,
            lr=p.lr,
            action_condition_prob=p.action_condition_prob,
            logger=self.logger,
            log_prefix="planner/",
            progress=self.cfg.progress,
        )

    def distill(self) -> None:
        """Alg. 1 line 5: distil g_θ' into the one-step π_θ and p(s'|s, a; θ)."""
        student = progressive_distillation(
            self.teacher,
            self.windows.sample,
            list(self.cfg.budget.distill_updates),
            lr=self.cfg.distillation.lr,
            action_condition_prob=self.cfg.planner.action_condition_prob,
            logger=self.logger,
            progress=self.cfg.progress,
        )
        self.actor.model.load_state_dict(student.state_dict())
        if self.transition.frozen:  # a shared transition model is actor.model itself
            self.transition.model.load_state_dict(student.state_dict())

    def update(self, batch: TensorDictBase) -> dict:
        """One critic (IQL) and one actor (Eq. 7) gradient step, Alg. 1 lines 7-8 / 15-16."""
        critic = self.critic
        q_loss, _ = critic.loss.qvalue_loss(batch)
        v_loss, _ = critic.loss.value_loss(batch)
        critic.optimizer.zero_grad(set_to_none=True)
        (q_loss + v_loss).backward()
        critic.optimizer.step()
        critic.target_updater.step()
        out = self.actor_loss(batch)
        self.actor_optimizer.zero_grad(set_to_none=True)
        out["loss_actor"].backward()
        self.actor_optimizer.step()
        self.updates += 1
        self.updates_since_refit += 1
        return {
            "loss_qvalue": q_loss.item(),
            "loss_value": v_loss.item(),
            **{k: v.item() for k, v in out.items()},
        }

    def pretrain_actor_critic(self) -> None:
        """Alg. 1 lines 6-8: pre-train Q_φ and π_θ on D_offline."""
        bar = tqdm(
            range(self.cfg.budget.offline_updates),
            desc="actor+critic",
            disable=not self.cfg.progress,
            leave=False,
        )
        for i in bar:
            metrics = self.update(self.offline_buffer.sample().to(self.cfg.device))
            if i % 100 == 0:
                self.log(metrics, self.updates, "offline/")
                bar.set_postfix(actor=f"{metrics['loss_actor']:.3f}")

    def _all_transitions(self, chunk: int = 8192):
        for source in (self.data.transitions, self.replay.online_buffer):
            for start in range(0, len(source), chunk):
                yield source[start : start + chunk].to(self.cfg.device)

    def fit_laplace(self) -> None:
        """Alg. 1 lines 9 and 17: last-layer Laplace of L_π on D (Eq. 8)."""
        with torch.no_grad():
            # The Hessian of Eq. (7) carries the actor loss's own weights (uniform for
            # "uniform"; "sac" has no per-sample weights, so its GGN uses uniform ones).
            advantage = self.cfg.actor.weighting == "advantage"
            laplace = self.ensemble.fit_laplace(
                self._all_transitions(),
                weight_fn=self.actor_loss.advantage_weights if advantage else None,
            )
        self.updates_since_refit = 0
        self.log({"prior_precision": laplace.prior_precision}, self.updates, "laplace/")

    def evaluate(self, label: str) -> dict:
        result = self.evaluate_policy(self.ensemble)
        result.update(frames=self.frames, label=label)
        self.history.append(result)
        self.log({k: v for k, v in result.items() if k != "label"}, self.frames, "eval/")
        print(
            f"[dual] {label} @ {self.frames} frames: normalized score "
            f"{result['normalized_score']:.1f} (return {result['return']:.3f})"
        )
        return result

    # ------------------------------------------------------------------ online phase
    def collector(self) -> Collector:
        """Alg. 1 lines 11-12: act with Eq. 9 + Eq. 10 in the online env."""
        remaining = self.cfg.budget.online_frames - self.frames
        self.env.set_seed(self.cfg.seed + 1 + self.frames)
        return Collector(
            self.env,
            self.policy,
            frames_per_batch=self.cfg.budget.frames_per_batch,
            total_frames=max(remaining, 0),
            exploration_type=ExplorationType.RANDOM,
            device=self.cfg.device,
            auto_register_policy_transforms=False,
        )

    def store(self, batch: TensorDictBase) -> dict:
        """Alg. 1 line 13: D_online ← D_online ∪ {(s_t, a_t, s_t+1, r_t)}."""
        batch = batch.reshape(-1)
        done = batch["next", "done"].squeeze(-1).long()
        episode = self.next_episode + torch.cumsum(done, 0) - done
        self.next_episode = int(episode[-1]) + int(done[-1])
        keys = [k for k in TRANSITION_KEYS if k != "episode"]
        online = batch.select(*keys).clone()
        online.set("episode", episode)
        self.replay.extend(online.cpu())
        self.frames += batch.numel()
        return {
            "reward_per_step": float(batch["next", "reward"].mean()),
            "shift_distance": float(batch["shift_distance"].mean()),
            "epistemic_std": float(batch["epistemic_variance"].mean().sqrt()),
        }

    def train_online(self, num_frames: int) -> dict:
        """Alg. 1 lines 14-16: UTD-ratio updates on D_offline ∪ D_online."""
        self.update_credit += self.cfg.online.utd_ratio * num_frames
        metrics: dict = {}
        while self.update_credit >= 1:
            metrics = self.update(self.replay.sample().to(self.cfg.device))
            self.update_credit -= 1
        return metrics

    def finish(self) -> None:
        """Writes the learning curve and prints where everything is."""
        self.save()
        png = plot_learning_curve(
            self.history,
            self.output_dir / "learning_curve.png",
            title=f"DUAL on {self.cfg.env.name}",
        )
        offline = next((h for h in self.history if h["label"] == "offline"), None)
        final = self.history[-1] if self.history else None
        print("[dual] done.")
        if offline is not None:
            print(
                f"[dual] normalized score after the offline phase: {offline['normalized_score']:.1f}"
            )
        if final is not None:
            print(
                f"[dual] normalized score at the end of the online phase: "
                f"{final['normalized_score']:.1f}"
            )
        print(f"[dual] metrics CSV: {self.output_dir / 'logs' / 'dual' / 'scalars'}")
        print(f"[dual] learning curve: {png}")
