"""The recipe's config schema and :func:`validate_config`, run before any data or network.

The schema of a composed config is put together from tables: the top-level keys
(:class:`RunSettings`), ``budget`` (:class:`BudgetSettings`), ``env`` (the schema of its
``ENV_KITS`` entry), the sections of the chosen ``algo`` (its ``ALGORITHMS`` entry),
``critic`` (its ``CRITICS`` entry), ``replay`` (its ``REPLAYS`` entry), ``collector`` (its
``COLLECTORS`` entry) and ``logger`` (its ``LOGGERS`` entry).
Every key is checked against its rule, then the combinations across keys, then what the
env and the machine must provide (a goal cell of the maze, a Minari data set on disk, the
device, the logger's package, a usable output_dir). Nothing before those last checks
imports torch or TorchRL, so a bad value is reported in well under a second.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.algo_common import Algorithm
from torchrl_dual.recipe.settings.algos import ALGORITHMS
from torchrl_dual.recipe.settings.envs import ENV_KITS, EnvKit
from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.loggers import LOGGERS, check_logger
from torchrl_dual.recipe.settings.o2o import COLLECTORS, REPLAYS, check_output_dir
from torchrl_dual.recipe.settings.parts import CRITICS
from torchrl_dual.recipe.settings.rules import (
    Choice,
    Flag,
    Integer,
    IntegerList,
    Maybe,
    Text,
    check_section,
    dotted_keys,
    key,
    read_value,
)


@dataclass
class RunSettings:
    """``config.yaml``'s own keys (the groups are checked by their own schemas)."""

    algo: str = key(
        Text(),
        "the algorithm (the `ALGORITHMS` entry, looked up when `validate_config` runs), chosen "
        "with `algo=<name>` (default `dual`), and its settings, from `algo/<name>.yaml`: `dual` "
        "or a baseline, `iql`, `iql_la`, `diffql`, `diffql_la`, `diffuser`, `dacer`, `edis`, "
        "`calql`, `so2` ([Algorithms](recipe.md#algorithms-critics-and-env-kits))",
    )
    seed: int = key(
        Integer(0, 2**32 - 1), "seeds torch, NumPy, Python, data generation and the envs"
    )
    device: str = key(
        Text(),
        "torch device of the networks and updates (`cuda` on a GPU), and of the acting policy "
        "unless `collector.device` says otherwise; data generation and envs run on the CPU",
    )
    num_threads: int = key(Integer(1), "`torch.set_num_threads` for the CPU")
    output_dir: str = key(
        Text(), "where the run writes its metrics, plot, checkpoint and Hydra's `.hydra/`"
    )
    resume: bool = key(
        Flag(),
        "continue the run in `output_dir` from its checkpoint "
        "([Checkpoint and resume](recipe.md#checkpoint-and-resume))",
    )
    interrupt_at_frames: Any = key(
        Maybe(Integer(0)),
        "test aid: after this many online frames, save and stop as Ctrl-C would (`null`: never)",
    )
    interrupt_at_offline_updates: Any = key(
        Maybe(Integer(1)),
        "test aid: after this many offline updates (the planner's, distillation's and "
        "actor-critic updates, all stages' loops counted together), save within the stage and "
        "stop as Ctrl-C would (`null`: never)",
    )
    progress: bool = key(
        Flag(),
        "tqdm progress bars; with `false` (the learning suite's runs, a log file) the run prints "
        "a line when each stage starts and ends and every 10 % of the actor-critic updates",
    )
    data_cache_dir: Any = key(
        Maybe(Text()),
        "where generated offline data sets are cached; `null`: `$TORCHRL_DUAL_CACHE`, else "
        "`~/.cache/torchrl_dual`",
    )
    offline_cache: Any = key(
        Maybe(Text()),
        "a directory where runs differing only in online keys share their offline phase (the "
        "first saves it, the later ones load it); `null`: never shared "
        "([Shared offline phases](recipe.md#shared-offline-phases-offline_cache))",
    )
    debug: bool = key(
        Flag(),
        "print the traceback of a user error before its `error:` line (as `HYDRA_FULL_ERROR=1` "
        "does)",
    )


COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
"""``torch.compile``'s modes (``compile.compile_mode``; ``null`` is ``default``)."""


@dataclass
class CompileSettings:
    """``config.yaml``'s ``compile``: TorchRL sota-implementations' keys."""

    compile: bool = key(
        Flag(),
        "`torch.compile` each gradient update of the learner (TorchRL sota-implementations' "
        "key), on any device: the losses trace whole, the backward passes and optimizer steps "
        "are their own graphs; the same losses and weights as eager to float tolerance "
        "(`tests/recipe/test_compile_recipe.py`). Worth it on a GPU "
        "([benchmarks](benchmarks.md#dual-on-a-gpu): 2x on an H200); not on the CPU (0.85x "
        "eager). May change on resume",
    )
    compile_mode: Any = key(
        Maybe(Choice(COMPILE_MODES)), "`torch.compile`'s mode; `null`: `default`"
    )
    cudagraphs: bool = key(
        Flag(),
        "`device=cuda` only: each update captured once per phase (offline, online) and batch "
        "shape by tensordict's `CudaGraphModule` and replayed with each new batch (the "
        "library's update composition: 32x eager on an H200, "
        "[benchmarks](benchmarks.md#dual-on-a-gpu)); the optimizers are made `capturable`. "
        "Refused for `diffuser` and `dacer`, whose updates do what a replay cannot (sample "
        "their own windows; a Python schedule); `tests/recipe/test_graph_safe_updates.py` "
        "checks on the CPU that every other update is graph-safe (the same kernels every call, "
        "no Python state, reads its batch). The acting policy is not captured. Not yet run on "
        "a GPU in the recipe (`benchmarks/speed/gpu_check.sh` is the prepared check). May "
        "change on resume",
    )


@dataclass
class BudgetSettings:
    """``budget/*.yaml``: how much data, computation and evaluation a run gets."""

    name: str = key(
        Text(),
        "the budget, chosen with `budget=<name>` (default `default`): `smoke` runs every step "
        "in well under a minute with small networks to check the plumbing (the tests use it; "
        "its numbers mean nothing), `default` is sized for 5 to 10 minutes of one CPU core for "
        "DUAL on PointMaze U-maze (measured times in [results.md](results.md)), its split (few "
        "planner and distillation updates, many actor-critic updates) chosen by measurement, "
        "`paper` is the paper's scale (Appendix A, CORL settings: 1M offline and 1M online "
        "steps; use a GPU). Used in `output_dir` and the learning suite's results",
    )
    dataset_transitions: int = key(
        Integer(1), "offline transitions generated (cached after the first run: `data_cache_dir`)"
    )
    network_width: int = key(
        Integer(1),
        "hidden width of the planner's denoiser and of the critics (`planner.hidden` and "
        "`critic.hidden` read it)",
    )
    batch_size: int = key(
        Integer(1),
        "windows per planner update and transitions per actor-critic update "
        "(`planner.batch_size`, `online.batch_size`, `augment.batch_size` and "
        "`replay.ratio_batch_size` read it)",
    )
    planner_updates: int = key(Integer(0), "diffusion planner updates")
    distill_updates: list = key(
        IntegerList(1),
        "updates of each halving round of progressive distillation (32→16→8→4→2→1): one entry "
        "per round, `log2(planner.num_steps / distillation.final_steps)` entries",
    )
    offline_updates: int = key(Integer(0), "actor + critic updates in the offline phase")
    online_frames: int = key(Integer(0), "environment steps in the online phase")
    frames_per_batch: int = key(
        Integer(1),
        "the collector's batch between update blocks, in env steps over all envs: a multiple "
        "of `collector.num_envs`, and of `collector.num_workers` with `collector=multi_sync` or "
        "`collector=ray collector.sync=true`",
    )
    laplace_refit_every: int = key(
        Integer(1), "gradient updates between Laplace refits (and `augment.every`'s default)"
    )
    eval_every: int = key(Integer(1), "online frames between evaluations")
    eval_episodes: int = key(
        Integer(1),
        "episodes per evaluation (Frozen-Lake does not read it: it is evaluated exactly)",
    )
    checkpoint_every: int = key(
        Integer(1),
        "online frames between checkpoints "
        "([Checkpoint and resume](recipe.md#checkpoint-and-resume))",
    )
    offline_checkpoint_every: int = key(
        Integer(1),
        "offline updates (the planner's, distillation's and actor-critic loops counted together) "
        "between checkpoints within a stage. May change on resume",
    )


def _choice(cfg: DictConfig, path: str, table: dict, what: str) -> Any:
    """The table entry a selector key (``env.kind``, ``critic.name``, ...) picks."""
    group, name = path.split(".") if "." in path else (None, path)
    node = cfg if group is None else cfg.get(group)
    if not isinstance(node, DictConfig):
        raise ConfigError(group, node, f"must be a group of keys ({what})")
    if name not in node:
        raise ConfigError(None, None, f"missing key '{path}' ({what})")
    value = read_value(node, name, path)
    complaint = Choice(tuple(table)).complaint(value)
    if complaint is not None:
        raise ConfigError(path, value, complaint)
    return table[value]


def config_sections(cfg: DictConfig) -> dict[str, type]:
    """Each section of ``cfg`` and the schema that checks it, from the selector keys.

    ``env`` (its ``ENV_KITS`` entry's), ``budget``, the chosen algorithm's sections,
    ``critic``, ``replay``, ``collector``, ``logger`` and ``compile``. A selector naming
    no table entry raises :class:`ConfigError` (``collector.num_workers`` with
    ``collector=single`` and ``collector.num_envs`` with the others too).
    """
    return _selection(cfg)[2]


def _selection(cfg: DictConfig) -> tuple[Algorithm, EnvKit, dict[str, type]]:
    """The ``algo`` entry, the ``env.kind`` kit and :func:`config_sections`' sections."""
    entry = _choice(cfg, "algo", ALGORITHMS, "the algorithm")
    algorithm = entry.settings
    kit = _choice(cfg, "env.kind", ENV_KITS, "which environment kit builds the env and data")
    critic_schema = _choice(cfg, "critic.name", CRITICS, "the critic").settings
    replay_schema, _ = _choice(cfg, "replay.name", REPLAYS, "the online replay")
    collector = _choice(cfg, "collector.name", COLLECTORS, "the online collector")
    for name, why in collector.misplaced.items():  # before the key checks call it unknown
        if name in cfg.collector:
            raise ConfigError(
                f"collector.{name}", cfg.collector[name], f"collector={cfg.collector.name} {why}"
            )
    logger = _choice(cfg, "logger.backend", LOGGERS, "the TorchRL logger backend")
    return (
        entry,
        kit,
        {
            "env": kit.settings,
            "budget": BudgetSettings,
            **algorithm.sections,
            "critic": critic_schema,
            "replay": replay_schema,
            "collector": collector.settings,
            "logger": logger.settings,
            "compile": CompileSettings,
        },
    )


def validate_config(cfg: DictConfig) -> DictConfig:
    """Checks a composed recipe config; raises :class:`ConfigError` on the first problem.

    Returns ``cfg`` itself, for chaining.

    Args:
        cfg (DictConfig): the composed config.

    Returns:
        DictConfig: ``cfg`` itself.

    Raises:
        ConfigError: an unknown choice or key, a value its rule refuses, a failed cross-key
            check, or what the machine lacks for it (a package, a data set, a device).
    """
    entry, kit, sections = _selection(cfg)
    algorithm = entry.settings
    known = dotted_keys(RunSettings, "")
    for name, schema in sections.items():
        known += [name, *dotted_keys(schema, name)]
    check_section(RunSettings, cfg, "", known, skip=sections)
    for name, schema in sections.items():
        if name not in cfg:
            raise ConfigError(None, None, f"missing config group '{name}'")
        check_section(schema, cfg[name], name, known)
    if cfg.critic.name not in algorithm.critics:
        raise ConfigError(
            "critic", cfg.critic.name, f"{cfg.algo} supports {', '.join(algorithm.critics)}"
        )
    algorithm.check(cfg)
    COLLECTORS[cfg.collector.name].check(cfg)
    if cfg.compile.cudagraphs and entry.no_cuda_graph is not None:
        raise ConfigError(
            "compile.cudagraphs", True, f"not for algo={cfg.algo}: {entry.no_cuda_graph}"
        )
    # What the env and the machine must provide (the only checks that import the
    # library: a goal cell of the maze, a Minari data set on disk, the device).
    if kit.check is not None:
        kit.check(cfg)
    check_machine(cfg)
    return cfg


def check_device(path: str, value: str) -> None:
    """``value`` names a torch device the recipe can use on this machine."""
    import torch  # the device check needs it; every other check runs without it

    try:
        device = torch.device(value)
    except (RuntimeError, ValueError) as err:
        raise ConfigError(path, value, "not a torch device; use cpu, cuda or cuda:N") from err
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(path, value, f"CUDA is not available here; use {path}=cpu")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise ConfigError(path, value, f"this machine has {torch.cuda.device_count()} GPUs")
    if device.type not in ("cpu", "cuda"):
        raise ConfigError(path, value, "the recipe runs on cpu or cuda")


def check_machine(cfg: DictConfig) -> None:
    """What the config asks of the machine and the file system."""
    check_device("device", cfg.device)
    if cfg.compile.cudagraphs and not str(cfg.device).startswith("cuda"):
        raise ConfigError(
            "compile.cudagraphs",
            True,
            f"CUDA graphs replay CUDA kernels: needs device=cuda (device={cfg.device}); "
            "compile.compile=true works on any device",
        )
    if cfg.collector.device is not None:
        check_device("collector.device", cfg.collector.device)
    check_logger(cfg)
    check_output_dir(cfg.output_dir, cfg.resume)
    for name in ("data_cache_dir", "offline_cache"):
        if cfg[name] is not None and Path(cfg[name]).is_file():
            raise ConfigError(name, cfg[name], "is a file, not a directory")
