"""The candidates of ``benchmarks/speed/latency.py``: one builder per timed policy.

Each ``build_x(cfg) -> TensorDictModuleBase`` builds one acting policy at the sizes of
:class:`Config`; :data:`BUILDERS` maps the candidate's name (the table row, ``--only``,
``--profile`` and the JSON key) to its builder. ``dual_m5`` is DUAL's online policy
(Laplace ensemble M = 5, Eq. 9, + shift-aware noise, Eq. 10; the policy query and the
frozen transition model's query in one batched pass); ``dual_m5_shared`` uses the actor's
own weights for ``ŝ_t``; ``dual_m5_two_pass`` runs the frozen transition model as a
separate second pass; ``dual_m5_n8`` is the "w/o distillation" ablation (an 8-step
planner actor); ``dual_m5_latent`` the "w τ^N sampling" ablation (``laplace.uq=latent``).
The recipe's baselines act with their exploration policies, built by the recipe's own
builders with the actor settings of ``torchrl_dual/recipe/config/algo/<algo>.yaml`` and the width
``cfg.hidden``: ``iql_actor`` (``algo=iql``), ``iql_la_m5`` (``algo=iql_la``),
``diffql_n5`` (``algo=diffql``), ``diffql_la_m5`` (``algo=diffql_la``) and ``dacer_n5``
(``algo=dacer``);
``algo=diffuser`` acts as ``planner_n32``.

Weights are untrained: the cost of a forward pass does not depend on the weight values.

Imported by ``latency.py`` and ``collection_speed.py``
(``from benchmarks.speed.latency_candidates import ...``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torchrl.data import Bounded
from torchrl.modules import (
    MLP,
    DiffusionActor,
    NormalParamExtractor,
    ProbabilisticActor,
    TanhNormal,
)

from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import (
    DDPMLastStepActor,
    LaplaceEnsembleActor,
    LinearHeadActor,
    PlannerActor,
    PlannerPolicy,
    ShiftAwareNoise,
    TransitionModel,
    make_dual_policy,
)
from torchrl_dual.modules.exploration import EntropyRegulatedNoise, dacer_target_entropy
from torchrl_dual.recipe import CONFIG_DIR as RECIPE_CONFIG_DIR
from torchrl_dual.recipe.algos.diffql import ActionBox, make_diffusion_actor
from torchrl_dual.recipe.algos.iql import make_iql_actor
from torchrl_dual.recipe.settings.baselines import DiffQLActorSettings, MLPActorSettings
from torchrl_dual.recipe.settings.rules import as_settings

ALGO_CONFIGS = RECIPE_CONFIG_DIR / "algo"


@dataclass
class Config:
    obs_dim: int = 6  # PointMaze: position, velocity, goal
    action_dim: int = 2
    horizon: int = 8  # H; the planner diffuses H + 1 rows (paper, Appendix A)
    hidden: int = 256  # width of the MLP actor and of the planner denoiser
    depth: int = 3  # MLP hidden layers / denoiser residual blocks
    teacher_steps: int = 32  # N of the teacher planner


# ----------------------------------------------------------------------------- builders
def build_mlp_actor(cfg: Config) -> TensorDictModuleBase:
    """TorchRL's Gaussian actor: MLP -> (loc, scale) -> TanhNormal."""
    net = torch.nn.Sequential(
        MLP(
            in_features=cfg.obs_dim,
            out_features=2 * cfg.action_dim,
            num_cells=[cfg.hidden] * cfg.depth,
            activation_class=torch.nn.SiLU,
        ),
        NormalParamExtractor(),
    )
    spec = Bounded(-1.0, 1.0, shape=(cfg.action_dim,))
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": spec.space.low, "high": spec.space.high},
    )


def _planner(cfg: Config, num_steps: int) -> TensorDictModuleBase:
    layout = TrajectoryLayout(cfg.obs_dim, cfg.action_dim, cfg.horizon)
    model = _fitted(TrajectoryDiffusion(layout, num_steps=num_steps, hidden=cfg.hidden,
                                        depth=cfg.depth))  # fmt: skip
    return PlannerPolicy(model, action_low=-1.0, action_high=1.0)


def _fitted(model: TrajectoryDiffusion) -> TrajectoryDiffusion:
    """``model`` with its normalizer fitted on random states and actions (the statistics'
    values do not change the cost)."""
    layout = model.layout
    model.normalizer.fit(torch.randn(512, layout.obs_dim), torch.rand(512, layout.action_dim))
    return model


def build_planner_n32(cfg: Config) -> TensorDictModuleBase:
    """The teacher: ``TrajectoryDiffusion`` sampled with N DDIM steps."""
    return _planner(cfg, cfg.teacher_steps)


def build_planner_n1(cfg: Config) -> TensorDictModuleBase:
    """The distilled student: same architecture, one DDIM step."""
    return _planner(cfg, 1)


def _fit_data(cfg: Config) -> list[TensorDict]:
    """Random states to fit a Laplace posterior on (its values do not change the cost)."""
    return [TensorDict({"observation": torch.randn(512, cfg.obs_dim)}, [512])]


def _dual(
    cfg: Config, transition: str, num_steps: int = 1, uncertainty: str = "laplace"
) -> TensorDictModuleBase:
    """DUAL's acting policy from the library builder (:func:`make_dual_policy`), as the
    recipe assembles it; ``transition`` picks the source of ``ŝ_t``, ``num_steps`` the
    actor's (and the transition model's) sampling steps, ``uncertainty`` the ensemble
    (``laplace.uq``)."""
    layout = TrajectoryLayout(cfg.obs_dim, cfg.action_dim, cfg.horizon)
    model = _fitted(TrajectoryDiffusion(layout, num_steps=num_steps, hidden=cfg.hidden,
                                        depth=cfg.depth))  # fmt: skip
    actor = PlannerActor(model)
    if transition == "shared":
        transition_model = TransitionModel(model, frozen=False)
    else:
        transition_model = TransitionModel.frozen_copy(model)
    spec = Bounded(-1.0, 1.0, shape=(cfg.action_dim,))
    fit_data = _fit_data(cfg)
    if uncertainty == "latent":  # no posterior: M planner latents per call
        return make_dual_policy(
            actor, spec, transition_model=transition_model, uncertainty="latent"
        )
    if transition == "two_pass":  # the generic composition: ŝ_t from its own module
        ensemble = LaplaceEnsembleActor(
            actor, num_samples=5, action_low=-1.0, action_high=1.0, sample_action=False
        )
        ensemble.fit_laplace(fit_data)
        return TensorDictSequential(ensemble, transition_model, ShiftAwareNoise(spec, 0.5))
    policy = make_dual_policy(actor, spec, transition_model=transition_model, shift_weight=0.5)
    policy[0].fit_laplace(fit_data)
    return policy


def build_dual_m5(cfg: Config) -> TensorDictModuleBase:
    """DUAL's online policy as the recipe builds it: one-step planner actor + Laplace
    ensemble (M = 5, Eq. 9) + shift-aware noise (Eq. 10), with the policy query for s_t
    and the frozen transition model's query for (s_(t-1), a_(t-1)) in one batched pass."""
    return _dual(cfg, "paired")


def build_dual_m5_shared(cfg: Config) -> TensorDictModuleBase:
    """As ``dual_m5`` with the actor's own weights as the transition model (Alg. 1's p_θ)."""
    return _dual(cfg, "shared")


def build_dual_m5_two_pass(cfg: Config) -> TensorDictModuleBase:
    """As ``dual_m5`` with the frozen transition model run as a second, separate pass."""
    return _dual(cfg, "two_pass")


def build_dual_m5_n8(cfg: Config) -> TensorDictModuleBase:
    """The "w/o distillation" ablation (``distillation.final_steps=8``): ``dual_m5`` with an
    8-step planner actor (7 DDIM steps, then the Laplace last step) and an 8-step frozen
    transition model, on the plain path (two passes)."""
    return _dual(cfg, "paired", num_steps=8)


def build_dual_m5_latent(cfg: Config) -> TensorDictModuleBase:
    """The "w τ^N sampling" ablation (``laplace.uq=latent``): ``dual_m5`` with the
    :class:`~torchrl_dual.modules.laplace.LatentEnsembleActor` (M = 5 planner latents per
    call, through the actor's MAP weights) in place of the Laplace heads."""
    return _dual(cfg, "paired", uncertainty="latent")


# ------------------------------------------------------------- the recipe's baselines
def _algo_cfg(cfg: Config, algo: str) -> DictConfig:
    """``torchrl_dual/recipe/config/algo/<algo>.yaml``'s ``actor`` (depth, ``N``, activation as the
    recipe runs them) with the width ``--hidden`` (``budget.network_width``), on CPU."""
    actor = OmegaConf.load(ALGO_CONFIGS / f"{algo}.yaml").actor
    actor.hidden = cfg.hidden  # replaces the ${budget.network_width} interpolation
    return OmegaConf.create({"actor": OmegaConf.to_container(actor), "device": "cpu"})


def _spec(cfg: Config) -> Bounded:
    return Bounded(-1.0, 1.0, shape=(cfg.action_dim,))


def build_iql_actor(cfg: Config) -> TensorDictModuleBase:
    """``algo=iql``'s actor and exploration policy: :func:`make_iql_actor` (MLP ``hidden``
    × 2, ReLU, with ``algo/iql.yaml``'s ``actor.distribution``: the Gaussian)."""
    return _iql_actor(cfg, "iql")


def _iql_actor(cfg: Config, algo: str) -> TensorDictModuleBase:
    """``make_iql_actor`` with ``algo``'s config, its ``actor.distribution`` included."""
    actor = _algo_cfg(cfg, algo).actor  # its temperature reads the env: not needed here
    settings = as_settings(MLPActorSettings, actor)
    return make_iql_actor(settings, cfg.obs_dim, _spec(cfg), distribution=actor.distribution)


def build_iql_la_m5(cfg: Config) -> TensorDictModuleBase:
    """``algo=iql_la``'s exploration policy: ``LinearHeadActor.from_actor`` over the IQL
    actor (``algo/iql_la.yaml``), Laplace ensemble M = 5 (Eq. 9) and shift-aware noise
    with λ = 0, from :func:`make_dual_policy`; posterior fitted on random states."""
    head_actor = LinearHeadActor.from_actor(_iql_actor(cfg, "iql_la"))
    policy = make_dual_policy(head_actor, _spec(cfg), num_samples=5, shift_weight=0.0)
    policy[0].fit_laplace(_fit_data(cfg))
    return policy


def _diffusion_actor(cfg: Config, algo: str) -> DiffusionActor:
    actor = as_settings(DiffQLActorSettings, _algo_cfg(cfg, algo).actor)
    return make_diffusion_actor(actor, cfg.obs_dim, cfg.action_dim)


def _clamp(cfg: Config) -> TensorDictModule:
    spec = _spec(cfg)
    box = ActionBox(spec.space.low, spec.space.high)
    return TensorDictModule(box, in_keys=["action"], out_keys=["action"])


def build_diffql_n5(cfg: Config) -> TensorDictModuleBase:
    """``algo=diffql``'s exploration policy: TorchRL ``DiffusionActor`` (``N = 5`` DDPM
    steps, score MLP ``hidden`` × 3, SiLU; :func:`make_diffusion_actor`) then the clamp to
    the action box."""
    return TensorDictSequential(_diffusion_actor(cfg, "diffql"), _clamp(cfg))


def build_dacer_n5(cfg: Config) -> TensorDictModuleBase:
    """``algo=dacer``'s exploration policy: ``diffql_n5``'s actor (``algo/dacer.yaml``),
    then ``EntropyRegulatedNoise`` (``noise_scale · α · ε`` with the yaml's values) and the
    clamp; the entropy estimate runs in the update, not on the action path."""
    settings = OmegaConf.load(ALGO_CONFIGS / "dacer.yaml").dacer
    noise = EntropyRegulatedNoise(
        dacer_target_entropy(cfg.action_dim), settings.noise_scale, settings.init_alpha
    )
    return TensorDictSequential(_diffusion_actor(cfg, "dacer"), noise, _clamp(cfg))


def build_diffql_la_m5(cfg: Config) -> TensorDictModuleBase:
    """``algo=diffql_la``'s exploration policy: ``DDPMLastStepActor`` (the zero-latent
    chain, the score network's last layer as the Laplace layer) over ``diffql_n5``'s
    actor, Laplace ensemble M = 5 and λ = 0 noise, from :func:`make_dual_policy`."""
    last_step = DDPMLastStepActor(_diffusion_actor(cfg, "diffql_la"), latent="zero")
    policy = make_dual_policy(last_step, _spec(cfg), num_samples=5, shift_weight=0.0)
    policy[0].fit_laplace(_fit_data(cfg))
    return policy


BUILDERS: dict[str, Callable[[Config], TensorDictModuleBase]] = {
    "mlp_actor": build_mlp_actor,
    "planner_n32": build_planner_n32,
    "planner_n1": build_planner_n1,
    "dual_m5": build_dual_m5,
    "dual_m5_shared": build_dual_m5_shared,
    "dual_m5_two_pass": build_dual_m5_two_pass,
    "dual_m5_n8": build_dual_m5_n8,
    "dual_m5_latent": build_dual_m5_latent,
    "iql_actor": build_iql_actor,
    "iql_la_m5": build_iql_la_m5,
    "diffql_n5": build_diffql_n5,
    "diffql_la_m5": build_diffql_la_m5,
    "dacer_n5": build_dacer_n5,
}
