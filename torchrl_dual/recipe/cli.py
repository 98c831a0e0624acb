"""The recipe's command line: check it before Hydra runs, then run the chosen algorithm.

:func:`main` is the program: the ``torchrl-dual`` console script,
``python -m torchrl_dual.recipe`` and ``recipes/o2o.py`` all call it, with the same Hydra
overrides, on the config tree shipped in the package (:data:`CONFIG_DIR`). It calls
:func:`check_command_line` before handing over to Hydra's ``main``; that check composes
the config once itself (:func:`compose_checked`), so Hydra's own composition errors (an
unknown group option, an unknown key, a malformed override) and every
:func:`~torchrl_dual.recipe.validate_config` error end as one ``error:`` line and exit
code 2, before Hydra creates the output directory.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import hydra
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override, OverrideType
from hydra.errors import HydraException, OverrideParseException
from omegaconf import DictConfig, OmegaConf

from torchrl_dual.recipe.o2o.interrupts import signals_as_interrupts
from torchrl_dual.recipe.o2o.run_lock import run_directory_lock
from torchrl_dual.recipe.settings.algos import ALGORITHMS
from torchrl_dual.recipe.settings.errors import ConfigError, UserError, unknown_key, user_errors
from torchrl_dual.recipe.settings.schema import validate_config
from torchrl_dual.recipe.settings.structured import SCHEMA_GROUP

CONFIG_DIR = Path(__file__).resolve().parent / "config"
"""The recipe's Hydra config tree (``config.yaml`` and its groups), shipped in the package."""


def hydra_flags() -> argparse.ArgumentParser:
    """The command line ``@hydra.main`` accepts, as an ``argparse`` parser.

    Hydra-core 1.3's flags, public options only (``tests/recipe/test_entry_points.py``
    checks them against Hydra's own parser): the overrides, and the flags this check
    lets Hydra handle unchecked.
    """
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("overrides", nargs="*")
    for flags, dest in (
        (("--help", "-h"), "help"), (("--hydra-help",), "hydra_help"),
        (("--resolve",), "resolve"), (("--run", "-r"), "run"),
        (("--multirun", "-m"), "multirun"), (("--shell-completion", "-sc"), "shell_completion"),
    ):  # fmt: skip
        parser.add_argument(*flags, dest=dest, action="store_true")
    parser.add_argument("--version", action="version", version=f"Hydra {hydra.__version__}")
    parser.add_argument("--cfg", "-c", choices=["job", "hydra", "all"])
    parser.add_argument(
        "--info", "-i", nargs="?", const="all",
        choices=["all", "config", "defaults", "defaults-tree", "plugins", "searchpath"],
    )  # fmt: skip
    for flags in (("--package", "-p"), ("--config-path", "-cp"), ("--config-name", "-cn"),
                  ("--config-dir", "-cd"), ("--experimental-rerun",)):  # fmt: skip
        parser.add_argument(*flags)
    return parser


# Hydra flags that do not run the task (or run many): Hydra handles them unchecked.
_PASS_THROUGH = ("help", "hydra_help", "cfg", "info", "shell_completion", "multirun")
_OTHER_CONFIG = ("config_path", "config_name", "config_dir", "experimental_rerun")


def run(cfg: DictConfig) -> Any:
    """Validates ``cfg`` and runs its algorithm; returns the finished run.

    Raises :class:`~torchrl_dual.recipe.settings.errors.ConfigError` for a bad config.
    Runs Algorithm 1's loop (``o2o/loop.py``) with the ``algo`` entry's learner
    (``settings/algos.py``; DUAL's is ``algos/dual.py``) and returns the finished
    :class:`~torchrl_dual.recipe.O2ORun`.

    Args:
        cfg (DictConfig): the composed config.

    Returns:
        O2ORun: the finished run.

    Raises:
        ConfigError: ``cfg`` is not valid (the first problem found).
    """
    validate_config(cfg)
    from torchrl_dual.recipe.o2o.loop import run_o2o  # torch: only once the config is valid

    return run_o2o(cfg, ALGORITHMS[cfg.algo].learner)


def _parse(line: str) -> Override:
    try:
        return OverridesParser.create().parse_override(line)
    except (HydraException, OverrideParseException) as err:
        reason = " ".join(str(err).split()).split(" expecting ")[0]
        raise ConfigError(
            None, None, f"malformed override '{line}' ({reason}); write key=value"
        ) from err


def _group_options(config_dir: Path, group: str) -> list[str] | None:
    """The options of config group ``group`` (``None`` if it is not a group)."""
    folder = config_dir / group
    if not folder.is_dir():
        return None
    return sorted(p.stem for p in folder.glob("*.yaml"))


def _options_with_key(config_dir: Path, key: str) -> list[str]:
    """The ``group=option`` choices whose config file defines ``key``.

    E.g. ``critic.bellman_loss`` is ``critic=calql``'s: files of the key's first
    segment's group, and ``_global_`` files of any group (an ``algo`` file sets
    ``actor.*``).
    """
    owners = []
    for path in sorted(config_dir.glob("*/*.yaml")):
        group, text = path.parent.name, path.read_text()
        global_package = "@package _global_" in text.split("\n", 3)[0]
        if not global_package and not key.startswith(f"{group}."):
            continue
        tree = OmegaConf.to_container(OmegaConf.create(text), resolve=False)
        inner = key if global_package else key.removeprefix(f"{group}.")
        if inner in _dotted_keys(tree):
            owners.append(f"{group}={path.stem}")
    return owners


def _dotted_keys(tree: Any, prefix: str = "") -> list[str]:
    """Every key of a nested dict as ``a.b.c`` (groups included)."""
    if not isinstance(tree, dict):
        return []
    keys = []
    for name, value in tree.items():
        dotted = f"{prefix}{name}"
        keys += [dotted, *_dotted_keys(value, f"{dotted}.")]
    return keys


def compose_checked(config_dir: str | Path, overrides: Sequence[str], config_name: str = "config"):
    """Composes ``config_name`` with ``overrides`` as Hydra would and validates it.

    Args:
        config_dir (str or Path): the Hydra config tree (:data:`CONFIG_DIR`).
        overrides (sequence of str): ``key=value`` and ``group=option`` overrides, as on
            the command line.
        config_name (str): the primary config. Defaults to ``"config"``.

    Returns:
        the composed and validated ``DictConfig`` (without the ``hydra`` node).

    Raises:
        ConfigError: a malformed override, an unknown group option or key, anything
            Hydra cannot compose, or any :func:`validate_config` error.

    Examples:
        >>> from torchrl_dual.recipe import CONFIG_DIR
        >>> cfg = compose_checked(CONFIG_DIR, ["algo=iql", "env=frozenlake", "seed=3"])
        >>> cfg.algo, cfg.env.kind, cfg.seed
        ('iql', 'frozenlake', 3)
    """
    config_dir = Path(config_dir).resolve()
    parsed = [_parse(line) for line in overrides]
    parsed = [o for o in parsed if not o.key_or_group.startswith("hydra")]
    groups, keys = [], []
    for override in parsed:
        if override.is_sweep_override():
            raise ConfigError(
                override.key_or_group,
                override.input_line.split("=", 1)[-1],
                "a sweep needs --multirun (-m); write a list as key=[a,b]",
            )
        options = _group_options(config_dir, override.key_or_group)
        (groups if options is not None else keys).append(override)
        if options is None or override.is_delete():
            continue
        value = override.get_value_element_as_str()
        if value not in options:
            raise ConfigError(
                override.key_or_group, value, "unknown option; choose one of " + ", ".join(options)
            )
    with (
        _recipe_composition(config_dir),
        initialize_config_dir(str(config_dir), version_base="1.3"),
    ):
        try:
            cfg = compose(config_name, [o.input_line for o in parsed])
        except HydraException as err:  # say why in our words, else in Hydra's first line
            _explain_keys(config_dir, config_name, groups, keys)
            raise ConfigError(None, None, str(err).splitlines()[0]) from err
    OmegaConf.set_struct(cfg, True)
    return validate_config(cfg)


def _explain_keys(
    config_dir: Path, config_name: str, groups: list[Override], keys: list[Override]
) -> None:
    """Raises the :class:`ConfigError` of the first key override that Hydra refused.

    An unknown key (with the options of the groups that have it) or a ``+key`` that exists
    already; returns if the keys are not what failed. Runs only once a composition failed:
    it composes the groups alone to learn the keys they give.
    """
    try:
        base = compose(config_name, [o.input_line for o in groups])
    except HydraException:
        return
    known = _dotted_keys(OmegaConf.to_container(base, resolve=False))
    for override in keys:
        name = override.key_or_group
        if override.type == OverrideType.CHANGE and name not in known:
            raise unknown_key(name, known, owners=_options_with_key(config_dir, name))
        if override.type == OverrideType.ADD and name in known:
            value = override.get_value_element_as_str()
            raise ConfigError(
                f"+{name}", value, f"{name} exists already; write {name}={value} to change it"
            )


@contextlib.contextmanager
def _recipe_composition(config_dir: Path) -> Iterator[None]:
    """Composes the recipe's config tree on its own, wherever it is called from.

    Within the block it:

    * hides the entries of Hydra's process-wide ``ConfigStore`` named like a group of
      ``config_dir``: Hydra would otherwise validate the recipe's ``logger/csv.yaml``
      against, e.g., TorchRL's ``logger/csv`` schema, stored once
      ``torchrl.trainers.algorithms.configs`` (or
      :func:`torchrl_dual.trainers.register_configs`) ran in the process ("Error merging
      'logger/csv' with schema");
    * hides the recipe's own schemas (``recipe_schema``, stored once a run has typed its
      config): its files do not extend them, and Hydra deep-copies the whole store at each
      composition;
    * sets aside a running Hydra app's ``GlobalHydra`` (``initialize_config_dir`` refuses
      to start inside one), so a Hydra app of the user's can call :func:`compose_checked`.

    Both are as they were afterwards (``tests/trainers/test_configs.py`` composes the recipe
    next to TorchRL's store and inside a running app).
    """
    from hydra.core.config_store import ConfigStore
    from hydra.core.global_hydra import GlobalHydra

    repo = ConfigStore.instance().repo
    ours = {path.name for path in config_dir.iterdir() if path.is_dir()} | {SCHEMA_GROUP}
    hidden = {key: repo.pop(key) for key in list(repo) if key in ours}
    running = GlobalHydra.instance().hydra
    GlobalHydra.instance().hydra = None
    try:
        yield
    finally:
        repo.update(hidden)
        GlobalHydra.instance().hydra = running  # the instance: Hydra may have made a new one


def _debug(overrides: Sequence[str]) -> bool:
    return any(o.replace(" ", "").lower() in ("debug=true", "++debug=true") for o in overrides)


def check_command_line(
    config_dir: str | Path, config_name: str = "config", argv: Sequence[str] | None = None
) -> DictConfig | None:
    """Checks the command line's config; returns it, or exits with 2 and one ``error:`` line.

    Returns the composed config (``None`` for what is left to Hydra unchecked).

    Leaves ``--help``, ``--cfg``, ``--info``, ``--multirun`` and the options that pick
    another config to Hydra; a multirun checks each job's config when it starts.

    Args:
        config_dir (str or Path): the Hydra config tree (:data:`CONFIG_DIR`).
        config_name (str): the primary config. Defaults to ``"config"``.
        argv (sequence of str, optional): the command line's arguments; ``sys.argv[1:]``
            if omitted.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        with contextlib.redirect_stderr(io.StringIO()) as usage:
            args = hydra_flags().parse_args(argv)
    except SystemExit as stop:  # a bad flag: argparse's message, without its usage block
        if not stop.code:  # --version
            raise
        message = usage.getvalue().strip().splitlines()[-1].split(": error: ", 1)[-1]
        with user_errors():
            raise ConfigError(None, None, f"{message}; see --help for the options") from None
    if any(getattr(args, flag) for flag in _PASS_THROUGH + _OTHER_CONFIG):
        return None
    with user_errors(debug=_debug(args.overrides)):
        return compose_checked(config_dir, args.overrides, config_name)


def hydra_task(cfg: DictConfig) -> Any:
    """The body of ``@hydra.main``: :func:`run` with user errors reported as one line.

    Ctrl-C or SIGTERM in the offline or online phase ends the run with a checkpoint and
    one line (:func:`~torchrl_dual.recipe.run_o2o`); anywhere else (while the data and
    networks are built, at the very end) with one line too, its last checkpoint kept.

    Args:
        cfg (DictConfig): the config Hydra composed.

    Returns:
        The finished :class:`~torchrl_dual.recipe.O2ORun`, or ``None`` after an interrupt
        outside the run's phases.
    """
    with user_errors(debug=bool(cfg.get("debug", False))):
        try:
            return run(cfg)
        except KeyboardInterrupt:
            print(
                f"[{cfg.algo}] interrupted; nothing new saved (the last checkpoint in "
                f"{cfg.output_dir}, if any, is kept). Continue with resume=true.",
                flush=True,
            )
            return None


def main() -> None:
    """Runs the recipe for the command line's overrides (``sys.argv``).

    One ``error:`` line and exit code 2 for a bad config or an ``output_dir`` another
    run is writing (:mod:`~torchrl_dual.recipe.o2o.run_lock`, taken before Hydra writes
    its files there), then Hydra's ``main`` on :data:`CONFIG_DIR`.

    Ctrl-C or SIGTERM before the run begins (while the command line is checked and Hydra
    sets up) ends it with one line and exit code 130; within the run, :func:`hydra_task`
    and :func:`~torchrl_dual.recipe.run_o2o` take them.

    Examples:
        ``torchrl-dual budget=smoke``, ``python -m torchrl_dual.recipe algo=iql``,
        ``python recipes/o2o.py env=frozenlake`` (the same program).
    """
    with signals_as_interrupts():  # SIGTERM as Ctrl-C from the start, not only in the run
        try:
            cfg = check_command_line(CONFIG_DIR)  # composition and config errors: exit 2
            with contextlib.ExitStack() as lock:
                if cfg is not None:  # the run's directory, before Hydra writes into it
                    with user_errors(debug=bool(cfg.get("debug", False))):
                        lock.enter_context(run_directory_lock(cfg.output_dir))
                hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="config")(
                    hydra_task
                )()
        except KeyboardInterrupt as stop:  # before hydra_task's run began: nothing saved
            signal_name = stop.args[0] if stop.args else "SIGINT"
            print(
                f"interrupted ({signal_name}) outside the run's steps (while it was set up); "
                "no run state was saved. Start it again.",
                file=sys.stderr,
                flush=True,
            )
            raise SystemExit(130) from None


__all__ = [
    "CONFIG_DIR",
    "UserError",
    "check_command_line",
    "compose_checked",
    "hydra_task",
    "main",
    "run",
]
