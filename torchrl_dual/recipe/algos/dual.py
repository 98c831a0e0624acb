"""DUAL (Algorithm 1 of the paper) as the recipe's learner: builders, then the learner.

Read top to bottom: the builders of DUAL's own networks (Alg. 1 line 1), each from its
typed config section (the run's
:class:`~torchrl_dual.recipe.settings.structured.RecipeSettings`; DUAL's schemas and checks
live in ``settings/dual.py`` so that a bad value is reported before torch is imported), then :class:`DualLearner`: its networks, its offline stages (lines
2-9), its update (lines 7-8 and 15-16) and its Laplace refits (line 17). The online loop
that calls them (lines 10-18) is :func:`~torchrl_dual.recipe.run_o2o` (``o2o/loop.py``);
the critics are ``parts/critics.py``. The offline phase pre-trains the diffusion planner,
distils it to one step, pre-trains the weighted MAP actor and the critic and fits the
last-layer Laplace posterior; the online phase acts with the Laplace ensemble plus
shift-aware noise and fine-tunes on offline and online data. See docs/recipe.md.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data.tensor_specs import TensorSpec

from torchrl_dual import PlannerActor, TransitionModel
from torchrl_dual.diffusion import TrajectoryDiffusion
from torchrl_dual.modules import ShiftAwareNoise, exploration_signals
from torchrl_dual.objectives import DUALLoss, progressive_distillation
from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.kits.build import env_kit
from torchrl_dual.recipe.o2o.learner import Learner, RunContext
from torchrl_dual.recipe.parts.critics import Critic, make_critic, policy_view
from torchrl_dual.recipe.parts.mc_labels import MonteCarloLabels
from torchrl_dual.recipe.parts.networks import make_planner, make_policy, student_like
from torchrl_dual.recipe.parts.planner_augment import augment_capacity, make_augmenter
from torchrl_dual.recipe.parts.planner_stage import offline_windows, pretrain_planner
from torchrl_dual.recipe.settings.dual import ActorSettings
from torchrl_dual.recipe.settings.parts import CRITICS
from torchrl_dual.trainers.hooks import RefitSchedule
from torchrl_dual.trainers.stepper import CriticActorStepper


# ---------------------------------------------------------------------- builders (l. 1)
def make_actor(
    actor: ActorSettings, final_steps: int, teacher: TrajectoryDiffusion
) -> PlannerActor:
    """The actor ``π_θ`` (Eq. 5, 7): a planner shaped like the teacher with ``final_steps`` steps.

    ``distillation.final_steps`` is 1 for DUAL; the distillation loads its weights.

    Built before any training, it holds the teacher's fresh initialisation and its
    normalizer fitted on ``D_offline``: with ``actor.init=scratch`` that is what Eq. 7
    starts from (the distillation then only feeds the transition model).
    """
    student = student_like(teacher, final_steps)
    return PlannerActor(student, latent=actor.latent, init_std=actor.init_std)


def make_transition_model(
    kind: str, final_steps: int, teacher: TrajectoryDiffusion, actor: PlannerActor
) -> TransitionModel:
    """The transition model ``p(s' | s, a; θ)``, the source of Eq. (10)'s ``ŝ_t``.

    ``kind`` is ``exploration.transition_model``.

    ``frozen``: its own frozen copy of the distilled student (loaded after distillation),
    which the actor's fine-tuning leaves alone; saved inside the ensemble. ``shared``: the
    actor's own fine-tuned planner (Alg. 1's single ``θ``), held by reference and saved
    only as the actor's weights.
    """
    if kind == "frozen":
        return TransitionModel(student_like(teacher, final_steps))
    return TransitionModel(actor.model, frozen=False)


def make_loss(
    settings: ActorSettings,
    actor: PlannerActor,
    critic: Critic,
    action_spec: TensorSpec,
    entropy_coef: float | None = None,
) -> DUALLoss:
    """DUAL's update (Alg. 1 lines 7-8): the critic's loss and Eq. (7)'s weighted MAP actor on it.

    ``action_spec`` bounds the actions at which the ``sac`` weighting reads Q, whose
    ``α`` is ``entropy_coef`` when the critic has one (SO2: the same ``α`` as its
    targets).
    """
    entropy = {} if entropy_coef is None else {"entropy_coef": entropy_coef}
    return DUALLoss(
        actor,
        critic.loss,
        weighting=settings.weighting,
        temperature=settings.temperature,
        max_weight=settings.max_weight,
        action_spec=action_spec,
        **entropy,
    )


# ---------------------------------------------------------------------- the learner
class DualLearner(Learner):
    """DUAL's learner: its networks, offline stages, update and Laplace refits.

    The networks are the teacher ``g_θ'``, the actor ``π_θ``, the transition model and
    the IQL critics; the update is an IQL critic step, then Eq. 7.

    Examples:
        Algorithm 1 at toy size on Frozen-Lake: every offline stage, then 100 online frames.

        >>> import contextlib, io, tempfile
        >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked, run_o2o
        >>> out = tempfile.mkdtemp()
        >>> cfg = compose_checked(CONFIG_DIR, [
        ...     "algo=dual", "env=frozenlake", "budget=smoke", "progress=false",
        ...     f"output_dir={out}/run", f"data_cache_dir={out}/data",
        ...     "budget.dataset_transitions=1000", "budget.network_width=16",
        ...     "budget.planner_updates=4", "budget.distill_updates=[2,2,2,2,2]",
        ...     "budget.offline_updates=4", "budget.online_frames=100",
        ...     "budget.frames_per_batch=50", "budget.laplace_refit_every=10",
        ...     "budget.eval_episodes=1"])
        >>> with contextlib.redirect_stdout(io.StringIO()):
        ...     run = run_o2o(cfg, DualLearner)
        >>> run.stages_done
        ['planner', 'distillation', 'actor_critic', 'laplace', 'offline_eval']
        >>> run.frames, run.learner.actor.model.num_steps  # the distilled one-step actor
        (100, 1)
    """

    title = "DUAL"
    # offline_cache: DUAL's online ablations (no UQ, λ = 0) and every shift share these
    shared_stages = ("planner", "distillation", "actor_critic")
    online_keys = (
        "laplace.num_samples",
        "laplace.uq",
        "laplace.posterior_temperature",
        "exploration.shift_weight",
        "exploration.shift_floor",
        "exploration.extra_variance",
        "augment",
    )

    def __init__(self, run: RunContext) -> None:
        self.run = run
        s = self.settings = run.settings
        data, spec = run.data, run.env.action_spec
        self.windows = offline_windows(s, data, s.planner.batch_size)
        # ---- networks: teacher g_θ', actor π_θ and its transition model, critics
        self.teacher = make_planner(s.planner, data, s.device)
        final_steps = s.distillation.final_steps
        self.actor = make_actor(s.actor, final_steps, self.teacher)
        self.transition = make_transition_model(
            s.exploration.transition_model, final_steps, self.teacher, self.actor
        )
        kind = CRITICS[s.critic.name]  # what the critic asks of the learner
        view = policy_view(self.actor, spec) if kind.samples_policy else None  # N(μ, σ̄²)
        self.critic = make_critic(s, data.obs_dim, data.action_dim, actor=view)
        self.online_batches_per_update = self.critic.online_steps_per_update  # SO2: 10
        # Cal-QL's Monte-Carlo bound: on D_offline now, on D_online per episode
        self.labels = MonteCarloLabels(run) if kind.monte_carlo_labels else None
        entropy_coef = getattr(s.critic, "entropy_coef", None)  # SO2's α
        self.loss = make_loss(s.actor, self.actor, self.critic, spec, entropy_coef)
        self.actor_optimizer = adam(self.loss.actor_parameters(), lr=s.actor.lr)
        self.stepper = CriticActorStepper(  # Alg. 1's order: critic, target, then actor
            self.loss,
            self.critic.optimizer,
            self.actor_optimizer,
            target_update=self.critic.target_updater,
        )
        self.policy = make_policy(  # Eq. 9 + Eq. 10
            s.laplace,
            self.actor,
            spec,
            transition=self.transition,
            shift_weight=s.exploration.shift_weight,
            action_projection=env_kit(s).action_projection,
            device=s.device,
        )
        self.ensemble = self.policy[0]  # Eq. 9's ensemble: acts and holds ŝ_t's model
        # the one decision point of the no-UQ and latent-UQ ablations: no posterior to fit
        self.uses_posterior = s.laplace.uq == "laplace" and s.laplace.num_samples > 0
        self.exploration_policy = self.policy  # Eq. 9 + Eq. 10
        self.noise = next(m for m in self.policy.modules() if isinstance(m, ShiftAwareNoise))
        self.noise.extra_variance = float(s.exploration.extra_variance)  # v_c, beyond Eq. 10
        self.evaluation_policy = self.ensemble  # the MAP mean under DETERMINISTIC
        self.refits = RefitSchedule(s.budget.laplace_refit_every)  # Alg. 1 l. 17
        # augment.kind=planner: guided teacher windows added to D_online (Alg. 1 l. 14);
        # built last, so the networks above get the same weights either way
        self.augmenter = make_augmenter(run, self.teacher)
        self.extra_online_capacity = augment_capacity(s)

    # ------------------------------------------------------------------ the protocol
    def modules(self) -> dict:
        """What the checkpoint holds, each weight once.

        The frozen transition model is inside the ensemble, a shared one is the
        actor's own planner; with ``augment.kind=planner``, the augmenter's.
        """
        return {
            "teacher": self.teacher,
            "ensemble": self.ensemble,  # actor, σ̄, Laplace posterior, frozen ŝ_t model
            **self.critic.modules(),
            "actor_optimizer": self.actor_optimizer,
            **(self.augmenter.modules() if self.augmenter else {}),
        }

    def shared_modules(self) -> dict:
        """The shared offline phase, without the ensemble's ``M`` posterior draws.

        Their number is ``laplace.num_samples``; the Laplace stage runs after it in
        every run.
        """
        shared = {
            "teacher": self.teacher,
            "actor": self.actor,
            **self.critic.modules(),
            "actor_optimizer": self.actor_optimizer,
        }
        if self.transition.frozen:
            shared["transition"] = self.transition
        return shared

    def state_dict(self) -> dict:
        """The updates since the refit, the noise's ``d_0``, the augmenter's and labels' state."""
        state = {
            "updates_since_refit": self.refits.since,
            "shift_floor": float(self.noise.shift_floor),
        }
        if self.augmenter:
            state["augment"] = self.augmenter.state_dict()
        if self.labels:
            state["mc_labels"] = self.labels.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        """Restores what :meth:`state_dict` returned."""
        self.refits.since = state["updates_since_refit"]
        self.noise.shift_floor.fill_(state.get("shift_floor", 0.0))  # 0: before the floor
        if self.augmenter and "augment" in state:  # absent: a shared offline phase
            self.augmenter.load_state_dict(state["augment"])  # written without one
        if self.labels:
            self.labels.load_state_dict(state["mc_labels"])

    def online_transitions(self, transitions: TensorDictBase) -> TensorDictBase:
        """All of them; with ``critic=calql``, whole episodes with their bound."""
        return transitions if self.labels is None else self.labels.online_transitions(transitions)

    def collector_started(self) -> None:
        """Online from here: ``critic=so2`` takes its online settings.

        With ``critic=calql``, the held episode ends at the cut.
        """
        self.critic.set_phase(online=True)
        if self.labels:
            self.labels.cut()

    def offline_stages(self) -> list:
        """Algorithm 1's offline stages, lines 3-9.

        The planner's pre-training (l. 3-4, Eq. 3), the distillation (l. 5), the actor-critic
        updates (l. 6-8, Eq. 7), the Laplace fit (l. 9, Eq. 8) and, with a nonzero
        ``exploration.shift_floor``, the noise's ``d_0``.
        """
        return [
            ("planner", self.pretrain_planner),  # l.3-4: L_VLB (Eq. 3)
            ("distillation", self.distill),  # l.5: N=32 -> 1, π_θ and p(s'|s,a)
            ("actor_critic", self.run.pretrain_updates),  # l.6-8: IQL + Eq. 7
            ("laplace", self.fit_laplace),  # l.9: Eq. 8
            # d_0 of the noise (beyond the paper; none with the default d_0 = 0, Eq. 10)
            *([("shift_floor", self.set_shift_floor)] if self.uses_shift_floor else []),
        ]

    @property
    def uses_shift_floor(self) -> bool:
        """Whether an offline stage sets the noise's ``d_0`` (``exploration.shift_floor != 0``)."""
        return self.settings.exploration.shift_floor != 0

    def update(self, batch: TensorDictBase) -> dict:
        """One critic and one actor (Eq. 7) gradient step, Alg. 1 lines 7-8 / 15-16.

        The critic is IQL, Cal-QL's TD + bounded penalty, or SO2's ensemble TD (one
        step per batch of a stacked ``[k, B]``).
        """
        return dict(self.stepper.update(batch).items())

    def after_update(self) -> None:
        """One more update toward the next refit (Alg. 1 line 17)."""
        self.refits.count()

    def after_updates(self) -> None:
        """Alg. 1 line 17: refits the posterior when due; then line 14's planner augmentation.

        The posterior is refitted once ``budget.laplace_refit_every`` updates have
        accumulated since the last fit; with ``augment.kind=planner``, guided
        planner transitions are added to D_online for the next block when due.
        """
        if self.refits.due:
            self.fit_laplace()
        if self.augmenter:
            self.augmenter.after_updates()

    def batch_metrics(self, batch: TensorDictBase) -> dict:
        """DUAL's exploration signals (Eq. 9-10), each averaged over the collected batch.

        ``d_t``, the ensemble's epistemic std and share of the executed variance,
        and the executed action's std ``sqrt(σ² + λ d_t)``
        (:func:`~torchrl_dual.modules.exploration_signals`).
        """
        return exploration_signals(batch)

    # ------------------------------------------------------------------ offline stages
    def pretrain_planner(self) -> None:
        """Alg. 1 lines 3-4: θ' ← θ' − λ_g ∇ L_VLB on D_offline (Eq. 3)."""
        pretrain_planner(self.run, self.teacher, self.windows)

    def distill(self) -> None:
        """Alg. 1 line 5: distil g_θ' into the one-step π_θ and p(s'|s, a; θ).

        Ablations: ``distillation.final_steps = N > 1`` stops the halving at N steps
        ("w/o distillation"); ``actor.init=scratch`` keeps the actor's fresh weights
        ("w/o planner"), the student then only serves as the transition model. The rounds
        are checkpointed within the stage.
        """
        with self.run.stage_checkpoints() as checkpoints:
            student = progressive_distillation(
                self.teacher,
                self.windows.sample,
                list(self.settings.budget.distill_updates),
                final_steps=self.settings.distillation.final_steps,
                lr=self.settings.distillation.lr,
                action_condition_prob=self.settings.planner.action_condition_prob,
                logger=self.run.logger,
                progress=self.settings.progress,
                checkpoints=checkpoints,
            )
        if self.settings.actor.init == "distilled":
            self.actor.model.load_state_dict(student.state_dict())
        if self.transition.frozen:  # a shared transition model is actor.model itself
            self.transition.model.load_state_dict(student.state_dict())

    def fit_laplace(self) -> None:
        """Alg. 1 lines 9 and 17: the last-layer Laplace of L_π on D (Eq. 8).

        Skipped in the no-UQ ablation (``laplace.num_samples=0``), which never draws
        from the posterior, and in the latent-UQ one (``laplace.uq=latent``), which
        has none.
        """
        self.refits.reset()
        if not self.uses_posterior:
            return
        with torch.no_grad():
            # The Hessian of Eq. (7) carries the actor loss's own weights (uniform for
            # "uniform"; "sac" has no per-sample weights, so its GGN uses uniform ones).
            advantage = self.settings.actor.weighting == "advantage"
            laplace = self.ensemble.fit_laplace(
                self.run.all_transitions(),
                weight_fn=self.loss.actor_objective.advantage_weights if advantage else None,
            )
        self.run.log({"prior_precision": laplace.prior_precision}, self.run.updates, "laplace/")

    def set_shift_floor(self) -> None:
        """Sets ``d_0`` of the noise's ``λ max(d_t − d_0, 0)`` from ``exploration.shift_floor``.

        A number, or ``offline``: the mean of :meth:`offline_shift_distances` (up to
        20000 transitions), the transition model's error where it was fitted.
        """
        floor = self.settings.exploration.shift_floor
        if floor == "offline":
            floor = self.offline_shift_distances(20000, int(self.settings.seed)).mean()
        self.noise.shift_floor.fill_(float(floor))
        self.run.log({"shift_floor": float(floor)}, self.run.updates, "exploration/")

    @torch.no_grad()
    def offline_shift_distances(self, samples: int, seed: int) -> torch.Tensor:
        """Eq. 10's ``d = ‖ŝ' − s'‖`` of the transition model on ``samples`` offline transitions.

        The transitions are drawn from D_offline without replacement with ``seed``:
        ``d`` on the data the model was fitted on.
        """
        data = self.run.data.transitions
        gen = torch.Generator().manual_seed(seed)
        batch = data[torch.randperm(len(data), generator=gen)[:samples]].to(self.settings.device)
        predicted = self.transition.predict(batch["observation"], batch["action"])
        return (predicted - batch["next", "observation"]).norm(dim=-1).cpu()
