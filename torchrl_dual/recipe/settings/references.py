"""What each critic's reference implementation uses on each Minari family, in one place.

A run on a published family (``env.kind``: ``antmaze``, ``locomotion``, ``adroit``) takes
the settings its critic's reference uses there, as the paper's protocol does ("following
exactly the O2O benchmark of CORL", Appendix A). Two tables, one concept:

* :data:`REWARD_TRANSFORMS`: the reward transform ``r' = scale·r + shift`` of each
  reference, used where ``env.reward_scale`` / ``env.reward_shift`` are ``null``
  (:func:`reward_transform`);
* :data:`BUDGET_SETTINGS`: what a budget's protocol sets per algorithm (``budget=paper``:
  CORL's one-buffer replay and one update per env step for IQL and DUAL);
* :data:`REFERENCE_SETTINGS`: every other setting that differs from the recipe's default
  there, read by the config through the ``${reference:<key>,<default>}`` interpolation
  (``critic/calql.yaml``, ``algo/calql.yaml``, the families' ``env/*.yaml``): the value of
  ``<key>`` in the table for the run's ``env.kind`` and ``critic.name``, else ``<default>``.
  A key set on the command line replaces the interpolation, so it always wins.

IQL's family presets (expectile, temperature: CORL's) sit in each ``env/*.yaml`` as
``env.critic_expectile`` / ``env.actor_temperature``, because every algorithm on the IQL
critic reads them. DUAL trains on the IQL critic (Eq. 6) with CORL's IQL settings; on
``critic=calql`` it takes Cal-QL's rows like the ``calql`` baseline. Sources, with the
files they come from, are in docs/reproducing.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from omegaconf import DictConfig, OmegaConf

if TYPE_CHECKING:
    from torchrl_dual.recipe.settings.envs import MinariSettings

REWARD_TRANSFORMS: dict[str, dict[str, tuple[float | str, float]]] = {
    "antmaze": {"iql": (1.0, -1.0), "so2": (1.0, -1.0), "calql": (10.0, -5.0)},
    "locomotion": {"iql": ("returns", 0.0), "so2": ("returns", 0.0), "calql": (1.0, 0.0)},
    "adroit": {"iql": (1.0, 0.0), "so2": (1.0, 0.0), "calql": (1.0, 0.0)},
}
"""``env.kind`` -> ``critic.name`` -> ``(reward_scale, reward_shift)`` of that critic's
reference on that family, used where ``env.reward_scale`` / ``env.reward_shift`` are null.
The IQL critic (``iql``, ``dual``, and every algorithm on ``critic=iql``) takes CORL's IQL
(``algorithms/finetune/iql.py`` ``modify_reward``: AntMaze ``r - 1``, locomotion
``T / (max - min return)``, Adroit unchanged); Cal-QL its reference's (CORL's
``configs/finetune/cal_ql/antmaze/*.yaml`` and the authors' scripts: ``10 r - 5`` on
AntMaze; Adroit ``reward_scale: 1.0``, ``reward_bias: 0.0``; it normalizes no MuJoCo
reward); SO2 keeps IQL's (its MuJoCo-only reference gives no AntMaze or Adroit setting).
A transformed reward trains the critic only: evaluation scores the env's own reward."""

REFERENCE_SETTINGS: dict[str, dict[str, dict[str, Any]]] = {
    "antmaze": {
        "calql": {
            # the authors' scripts/run_antmaze.sh: --qf_arch=256-256-256-256,
            # --cql.cql_lagrange=True --cql.cql_target_action_gap=0.8 (CORL's configs agree on
            # the multiplier, and use 5 hidden layers)
            "critic.depth": 4,
            "critic.lagrange_gap": 0.8,
            # is_sparse_reward: an episode that never reaches the goal is bounded by
            # r_fail / (1 - γ), r_fail = 10·0 - 5 after the reward transform
            "critic.sparse_failure_reward": -5.0,
            # JaxCQL normalizes no state (CORL's Cal-QL: normalize: false)
            "env.normalize_observations": False,
        },
    },
    "adroit": {
        "calql": {
            # CORL's configs/finetune/cal_ql/{door,hammer,pen,relocate}/cloned_v1.yaml (the
            # authors ran the binary Adroit tasks only): cql_alpha 1.0, q_n_hidden_layers 3,
            # no multiplier, normalize: false; its TanhGaussianPolicy has 3 hidden layers
            "critic.depth": 3,
            "critic.min_q_weight": 1.0,
            "actor.depth": 3,
            "env.normalize_observations": False,
        },
    },
}
"""``env.kind`` -> ``critic.name`` -> ``{dotted config key: value}``: the settings of the
critic's reference on that family where they differ from the recipe's defaults (Cal-QL on
AntMaze: the authors' code; on Adroit's cloned data: CORL's). Read through the
``reference`` interpolation (:func:`reference_setting`)."""

_CORL_FINETUNE_IQL = {
    # CORL's algorithms/finetune/iql.py (commit eeeeef2): ReplayBuffer(buffer_size) is
    # loaded with the D4RL data (load_d4rl_dataset), every online step appends its
    # transition (add_transition; buffer_size 10M in configs/finetune/iql/*: nothing is
    # evicted) and replay_buffer.sample draws np.random.randint(0, size): one buffer,
    # every offline and online transition equally likely ...
    "online.offline_fraction": "joint",
    # ... and the loop `for t in range(offline_iterations + online_iterations)` does one
    # env step and one trainer.train(batch) per online iteration: 1 update per env step
    "online.utd_ratio": 1.0,
}
BUDGET_SETTINGS: dict[str, dict[str, dict[str, Any]]] = {
    "paper": {"iql": dict(_CORL_FINETUNE_IQL), "dual": dict(_CORL_FINETUNE_IQL)},
}
"""``budget.name`` -> ``algo`` -> ``{dotted config key: value}``: what a budget's protocol
sets for an algorithm, read through the same ``reference`` interpolation (and before
:data:`REFERENCE_SETTINGS`). ``budget=paper`` runs IQL and DUAL (which the paper runs on
CORL's IQL, Appendix A) with CORL's offline-to-online replay and update ratio; the other
budgets keep the recipe's own (``online.offline_fraction`` 0.5, ``online.utd_ratio`` 0.5,
``algo/*.yaml``)."""

RESOLVER = "reference"
"""The OmegaConf resolver name: ``${reference:critic.depth,2}``."""


def reference_setting(key: str, default: Any, *, _root_: DictConfig) -> Any:
    """The reference value of ``key`` for the run (the ``reference`` resolver).

    The value for the run's ``budget.name`` and ``algo`` in :data:`BUDGET_SETTINGS`,
    else for its ``env.kind`` and ``critic.name`` in :data:`REFERENCE_SETTINGS`, else
    ``default``.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> register_reference_resolver()
        >>> cfg = OmegaConf.create({"env": {"kind": "antmaze"}, "critic": {"name": "calql",
        ...     "depth": "${reference:critic.depth,2}", "lagrange_gap": "${reference:critic.lagrange_gap,null}"}})
        >>> cfg.critic.depth, cfg.critic.lagrange_gap
        (4, 0.8)
        >>> cfg.env.kind = "pointmaze"
        >>> cfg.critic.depth, cfg.critic.lagrange_gap
        (2, None)
        >>> cfg = OmegaConf.create({"algo": "dual", "budget": {"name": "paper"},
        ...     "online": {"utd_ratio": "${reference:online.utd_ratio,0.5}"}})
        >>> cfg.online.utd_ratio
        1.0
        >>> cfg.budget.name = "default"
        >>> cfg.online.utd_ratio
        0.5
    """
    budget = OmegaConf.select(_root_, "budget.name", default=None)
    algo = OmegaConf.select(_root_, "algo", default=None)
    protocol = BUDGET_SETTINGS.get(budget, {}).get(algo, {})
    if key in protocol:
        return protocol[key]
    kind = OmegaConf.select(_root_, "env.kind", default=None)
    critic = OmegaConf.select(_root_, "critic.name", default=None)
    return REFERENCE_SETTINGS.get(kind, {}).get(critic, {}).get(key, default)


def register_reference_resolver() -> None:
    """Registers :func:`reference_setting` as ``${reference:...}``.

    Idempotent; done when :mod:`torchrl_dual.recipe.settings` is imported.
    """
    if not OmegaConf.has_resolver(RESOLVER):
        OmegaConf.register_new_resolver(RESOLVER, reference_setting)


def reward_transform(env: MinariSettings, critic: str) -> tuple[float | str, float]:
    """``(reward_scale, reward_shift)`` of a Minari family's run.

    The ``env`` section's ``reward_scale`` / ``reward_shift`` where set, else
    :data:`REWARD_TRANSFORMS` for the ``critic`` (``critic.name``).

    Examples:
        >>> from types import SimpleNamespace
        >>> env = SimpleNamespace(kind="antmaze", reward_scale=None, reward_shift=None)
        >>> reward_transform(env, "calql")
        (10.0, -5.0)
        >>> env.reward_shift = -1.0
        >>> reward_transform(env, "calql")
        (10.0, -1.0)
    """
    preset_scale, preset_shift = REWARD_TRANSFORMS[env.kind][critic]
    scale, shift = env.reward_scale, env.reward_shift
    return (
        preset_scale if scale is None else (scale if scale == "returns" else float(scale)),
        float(preset_shift if shift is None else shift),
    )
