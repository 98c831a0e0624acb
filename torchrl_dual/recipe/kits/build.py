"""What every run asks of its env kit, whatever ``env.kind`` it is.

Algorithm 1 line 1: :func:`make_offline_dataset`, :func:`make_train_env`,
:class:`TrainEnvFactory`, :func:`make_evaluator`, :func:`projected_policy`.

The table of kits, :data:`~torchrl_dual.recipe.settings.envs.ENV_KITS`, names the
kits' builders (:mod:`~torchrl_dual.recipe.kits.pointmaze`,
:mod:`~torchrl_dual.recipe.kits.frozenlake`, :mod:`~torchrl_dual.recipe.kits.minari_families`)
next to each kind's ``env.*`` schema.

``env.shift`` (a :data:`~torchrl_dual.envs.SHIFTS` name, ``none`` by default) changes
the dynamics of the online env and of the evaluation env, never of the env the offline
data comes from (the data and its cache entry do not depend on it). With a shift the
evaluator reports the score under the shift (``normalized_score``, what a run is judged
on) and without it (``normalized_score_unshifted``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual.data import OfflineDataset, validate_transitions
from torchrl_dual.data.cache import default_cache_dir
from torchrl_dual.envs import vectorized_env
from torchrl_dual.recipe.settings.envs import ENV_KITS, EnvKit
from torchrl_dual.recipe.settings.errors import UserError, warn
from torchrl_dual.recipe.settings.structured import RecipeSettings
from torchrl_dual.transforms import PreviousTransition

Evaluator = Callable[[nn.Module], dict[str, float]]
"""``policy -> {"return": ..., "normalized_score": ..., ...}`` under deterministic actions
(``normalized_score`` is NaN when the data set has no reference returns)."""


def env_kit(settings: RecipeSettings) -> EnvKit:
    """The :class:`EnvKit` of ``env.kind``."""
    return ENV_KITS[settings.env.kind]


def make_offline_dataset(settings: RecipeSettings) -> OfflineDataset:
    """``D_offline`` from the cache (or generated and cached), checked (Alg. 1 line 1)."""
    data = env_kit(settings).load_data(settings)
    try:
        validate_transitions(data.transitions)
    except ValueError as err:
        cache = settings.data_cache_dir
        cache = cache if cache is not None else default_cache_dir()
        raise UserError(
            "data_cache_dir",
            cache,
            f"the cached offline data of env={settings.env.name} is invalid: {err} Delete its "
            "entry in the cache to regenerate it.",
        ) from err
    warn_if_batches_exceed_data(settings, len(data))
    return data


def warn_if_batches_exceed_data(settings: RecipeSettings, transitions: int) -> None:
    """Warns when an update's batch is larger than ``D_offline``.

    One ``warning:`` line when an update draws more transitions (``online.batch_size``)
    or windows (``planner.batch_size``) than ``D_offline`` holds: sampled with
    replacement, such a batch repeats the data many times over at a cost that grows with
    its size. A batch size equal to ``budget.batch_size`` is named as that key, which
    the sections take by default.
    """
    for section in ("online", "planner"):
        batch = getattr(settings.get(section), "batch_size", 0)
        if batch <= transitions:
            continue
        name = (
            "budget.batch_size" if batch == settings.budget.batch_size else f"{section}.batch_size"
        )
        warn(
            f"{name}={batch} exceeds the {transitions} transitions of the offline data: "
            f"drawn with replacement, a batch holds each about {batch / transitions:.0f} "
            f"times and every update pays for all {batch}; lower it to at most {transitions}"
        )
        return


def projected_policy(settings: RecipeSettings, policy: nn.Module) -> nn.Module:
    """``policy`` followed by the env kit's ``action_projection``, or ``policy`` itself.

    The projection gives the executed action the replay buffer stores, e.g.
    Frozen-Lake's one-hot argmax.
    """
    projection = env_kit(settings).action_projection
    if projection is None:
        return policy
    return TensorDictSequential(
        policy, TensorDictModule(projection, in_keys=["action"], out_keys=["action"])
    )


def make_train_env(settings: RecipeSettings, data: OfflineDataset | None = None) -> EnvBase:
    """The online env with :class:`PreviousTransition`, which carries ``(s_{t-1}, a_{t-1})``.

    The policy turns them into ``d_t`` of Eq. (10). ``data`` is ``D_offline`` when the
    caller has it (kits whose env depends on it read it otherwise).
    """
    return env_kit(settings).make_env(settings, data).append_transform(PreviousTransition())


def make_collection_env(
    settings: RecipeSettings, data: OfflineDataset | None, env: EnvBase
) -> EnvBase:
    """The env ``collector=single`` steps: the online env, or ``N`` copies of it as one batch.

    With ``collector.num_envs = N > 1``, ``N`` more copies of ``env``
    (:func:`make_train_env`) are stepped as one batch ``[N]``
    (:func:`~torchrl_dual.envs.vectorized_env`: one Gymnasium vector env, each copy with
    the kit's Gymnasium wrappers, the transforms once over the batch).
    """
    num_envs = getattr(settings.collector, "num_envs", 1)
    if num_envs == 1:
        return env
    return vectorized_env(lambda: make_train_env(settings, data), num_envs)


class TrainEnvFactory:
    """``() -> env``: the online env of ``settings`` (with ``PreviousTransition``), picklable.

    It holds the run's settings and the offline data set without its
    transitions (:meth:`~torchrl_dual.data.OfflineDataset.without_transitions`), so a
    spawned worker process (or a Ray actor) receives a few kilobytes rather than the run's
    offline data; kits whose env depends on the data (the Minari kits' observation
    normalization and reward scale) find it in that description. Without ``data`` they
    read the data set again in each worker.

    Args:
        settings (RecipeSettings): the run's settings.
        data (OfflineDataset, optional): the run's ``D_offline``.

    Examples:
        >>> import pickle
        >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked
        >>> settings = RecipeSettings.of(compose_checked(CONFIG_DIR, ["budget=smoke"]))
        >>> factory = pickle.loads(pickle.dumps(TrainEnvFactory(settings)))
        >>> env = factory()
        >>> "previous_observation" in env.reset().keys()
        True
    """

    def __init__(self, settings: RecipeSettings, data: OfflineDataset | None = None) -> None:
        self.settings = settings
        self.data = None if data is None else data.without_transitions()

    def __call__(self) -> EnvBase:
        """A fresh online env built from the stored settings and data (in a worker process)."""
        return make_train_env(self.settings, self.data)


def check_dims(env: EnvBase, data: OfflineDataset, name: Any = None) -> None:
    """Fails when the data set and the env disagree on observation or action size."""
    obs_dim = env.observation_spec["observation"].shape[-1]
    action_dim = env.action_spec.shape[-1]
    if (data.obs_dim, data.action_dim) != (obs_dim, action_dim):
        raise UserError(
            None if name is None else "env",
            name,
            f"the offline data has observation/action dims ({data.obs_dim}, "
            f"{data.action_dim}) but the env has ({obs_dim}, {action_dim}). Regenerate the "
            "data for this env (delete its cache entry) or pick the matching env.",
        )


def make_evaluator(settings: RecipeSettings, data: OfflineDataset) -> Evaluator:
    """Deterministic evaluation returning the mean return and the normalized score."""
    return env_kit(settings).make_evaluator(settings, data)
