"""``logger=csv | tensorboard | wandb`` (``torchrl_dual/recipe/o2o/loggers.py``) and the end-of-run
plot with DUAL's online signals (``torchrl_dual/recipe/o2o/plots.py``).

Three in-process DUAL runs at a cut-down smoke budget on PointMaze: a CSV run, and a
TensorBoard and a W&B run that are each interrupted after the first collected batch and
resumed. Each backend's own files are read back (TensorBoard's event files, the W&B
offline run's transaction log) and must hold the CSV run's scalar names; resuming keeps
the TensorBoard directory and the W&B run id. W&B runs offline only (``WANDB_MODE``).
"""

from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path

import pytest
from test_diffql import CONFIG_DIR, POINTMAZE
from test_diffql import FAST as DIFFQL_FAST

from torchrl_dual.recipe import ConfigError, compose_checked, run
from torchrl_dual.recipe.o2o.plots import plot_learning_curve
from torchrl_dual.recipe.settings.loggers import LOGGERS

# the smoke budget cut further (test_diffql's FAST) on short PointMaze episodes
FAST = [*DIFFQL_FAST, *POINTMAZE]


@pytest.fixture(scope="module", autouse=True)
def wandb_offline(tmp_path_factory):
    """W&B never goes online and writes nothing outside the test's directories."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("WANDB_MODE", "offline")
        patch.setenv("WANDB_SILENT", "true")
        patch.setenv("WANDB_DIR", str(tmp_path_factory.mktemp("wandb_dir")))
        patch.setenv("WANDB_CONFIG_DIR", str(tmp_path_factory.mktemp("wandb_config")))
        patch.setenv("WANDB_CACHE_DIR", str(tmp_path_factory.mktemp("wandb_cache")))
        yield


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("logger_data")


def overrides(logger: str, output_dir: Path, cache_dir: Path, *extra: str) -> list[str]:
    return [
        "algo=dual",
        f"logger={logger}",
        "budget=smoke",
        f"output_dir={output_dir}",
        f"data_cache_dir={cache_dir}",
        "progress=false",
        "num_threads=1",
        *FAST,
        *extra,
    ]


def interrupted_and_resumed(logger: str, output_dir: Path, cache_dir: Path):
    """The run stopped after its first batch of 50 frames, then resumed: both run objects."""
    first = run(
        compose_checked(
            CONFIG_DIR, overrides(logger, output_dir, cache_dir, "interrupt_at_frames=50")
        )
    )
    assert first.frames == 50 and not (output_dir / "learning_curve.png").exists()
    return first, run(
        compose_checked(CONFIG_DIR, overrides(logger, output_dir, cache_dir, "resume=true"))
    )


@pytest.fixture(scope="module")
def csv_run(tmp_path_factory, cache_dir):
    out = tmp_path_factory.mktemp("csv")
    return out, run(compose_checked(CONFIG_DIR, overrides("csv", out, cache_dir)))


@pytest.fixture(scope="module")
def tensorboard_runs(tmp_path_factory, cache_dir):
    out = tmp_path_factory.mktemp("tensorboard")
    return out, *interrupted_and_resumed("tensorboard", out, cache_dir)


@pytest.fixture(scope="module")
def wandb_runs(tmp_path_factory, cache_dir):
    out = tmp_path_factory.mktemp("wandb")
    return out, *interrupted_and_resumed("wandb", out, cache_dir)


def csv_scalars(out: Path) -> dict[str, list[tuple[int, float]]]:
    """``{name: [(step, value), ...]}`` from the CSV logger's files."""
    root = out / "logs" / "dual" / "scalars"
    return {
        str(path.relative_to(root).with_suffix("")): [
            (int(step), float(value))
            for step, value in (line.split(",") for line in path.read_text().split())
        ]
        for path in root.rglob("*.csv")
    }


def assert_same_series(got: list[tuple[int, float]], expected: list[tuple[int, float]]) -> None:
    """The same steps and (to float32 precision) the same values."""
    assert [step for step, _ in got] == [step for step, _ in expected]
    assert [v for _, v in got] == pytest.approx([v for _, v in expected], rel=1e-6)


def wandb_records(path: Path):
    """The protobuf records of a W&B transaction log (``run-<id>.wandb``): LevelDB's log
    format (32 KiB blocks of ``crc32 | length | type | data`` chunks) after a 7-byte header."""
    from wandb.proto import wandb_internal_pb2

    data, pos, block, record = path.read_bytes(), 7, 32768, b""
    assert data[:4] == b":W&B"
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # a block's tail too short for a header is padding
            pos += block - pos % block
            continue
        _, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        chunk = data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        record = chunk if kind in (1, 2) else record + chunk  # FULL, FIRST | MIDDLE, LAST
        if kind in (1, 4):
            parsed = wandb_internal_pb2.Record()
            parsed.ParseFromString(record)
            yield parsed


# ----------------------------------------------------------------------------- the scalars
def test_tensorboard_logs_the_csv_runs_scalars_into_one_directory_across_a_resume(
    csv_run, tensorboard_runs
):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    (csv_out, _), (out, _, _) = csv_run, tensorboard_runs
    expected = csv_scalars(csv_out)
    logs = out / "logs" / "dual"
    event_files = sorted(p.relative_to(logs) for p in logs.rglob("events.out.tfevents.*"))
    assert len(event_files) == 2 and all(p.parent == Path(".") for p in event_files)
    events = EventAccumulator(str(logs))
    events.Reload()
    assert set(events.Tags()["scalars"]) == set(expected)
    for name in ("online/shift_distance", "online/epistemic_std", "eval/normalized_score"):
        logged = [(e.step, e.value) for e in events.Scalars(name)]
        # the same steps; the same values up to the interrupt (a resumed run's collector
        # starts a new episode, so the CSV run's second batch differs)
        assert [step for step, _ in logged] == [step for step, _ in expected[name]]
        assert_same_series(logged[:1], expected[name][:1])


def test_wandb_logs_the_csv_runs_scalars_and_a_resume_keeps_the_run_id(csv_run, wandb_runs):
    (csv_out, _), (out, first, resumed) = csv_run, wandb_runs
    run_id = first.logger.experiment.id
    assert resumed.logger.experiment.id == run_id
    # the same run's transaction log before and after the resume, under output_dir/logs
    logs = sorted((out / "logs" / "wandb").glob("offline-run-*/run-*.wandb"))
    assert [p.name for p in logs] == [f"run-{run_id}.wandb"] * 2
    names, shift_distance, run_ids = set(), [], set()
    for path in logs:
        for record in wandb_records(path):
            kind = record.WhichOneof("record_type")
            if kind == "run":
                run_ids.add(record.run.run_id)
                assert record.run.config.update  # the resolved config is the run's config
            if kind == "history":
                # a key with "/" is stored split at the slashes
                row = {
                    item.key or "/".join(item.nested_key): json.loads(item.value_json)
                    for item in record.history.item
                }
                names.update(row)
                if "online/shift_distance" in row:
                    step, value = row["online/step"], row["online/shift_distance"]
                    shift_distance.append((int(step), float(value)))
    assert run_ids == {run_id}
    # TorchRL's WandbLogger adds one "<prefix>/step" axis per prefix; W&B its "_" keys
    logged = {n for n in names if not n.startswith("_") and not n.endswith("/step")}
    assert logged == set(csv_scalars(csv_out))
    # one row per batch, the step counter carried over; the plot's series is the logged one
    assert_same_series(
        shift_distance, [(s["frames"], s["shift_distance"]) for s in resumed.online_signals]
    )
    assert [step for step, _ in shift_distance] == [50, 100]


def test_a_logger_backend_without_its_package_names_the_pip_command(tmp_path, monkeypatch):
    missing = dataclasses.replace(LOGGERS["wandb"], package="torchrl_dual_no_such_package")
    monkeypatch.setitem(LOGGERS, "wandb", missing)
    with pytest.raises(ConfigError) as err:
        compose_checked(CONFIG_DIR, ["logger=wandb", f"output_dir={tmp_path}"])
    assert str(err.value) == (
        "logger.backend=wandb: needs the torchrl_dual_no_such_package package "
        "(pip install 'torchrl-dual[wandb]')"
    )


# ----------------------------------------------------------------------------- the plot
def png_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels from the PNG's IHDR chunk."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def test_the_plot_has_the_score_and_the_online_signals_logged_per_batch(csv_run, tmp_path):
    out, result = csv_run
    scalars = csv_scalars(out)
    # one record per collected batch, the values DUAL logged as online/<signal>
    assert [s["frames"] for s in result.online_signals] == [50, 100]
    names = ("epistemic_std", "epistemic_share", "shift_distance", "exploration_std")
    for name in (*names, "reward_per_step"):
        series = [(s["frames"], s[name]) for s in result.online_signals]
        assert_same_series(series, scalars[f"online/{name}"])
    assert all(s["exploration_std"] > 0 for s in result.online_signals)
    for s in result.online_signals:  # the share is the epistemic part of the executed variance
        assert 0 <= s["epistemic_share"] <= 1
    # 120 dpi: 6 x 4 inches for the score, 2 inches more per signal panel (four panels)
    assert png_size(out / "learning_curve.png") == (720, 1440)
    score_only = plot_learning_curve(result.history, tmp_path / "score.png", signals=[])
    assert png_size(score_only) == (720, 480)
    # summary.json carries them too (the learning suite's per-run JSON and plots)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["online_signals"] == result.online_signals


def test_the_online_signals_cover_the_whole_online_phase_across_a_resume(wandb_runs, csv_run):
    (out, first, resumed), (_, uninterrupted) = wandb_runs, csv_run
    assert [s["frames"] for s in first.online_signals] == [50]
    assert [s["frames"] for s in resumed.online_signals] == [50, 100]  # from the checkpoint
    # the first batch's record is the checkpoint's (an uninterrupted run's first batch)
    assert resumed.online_signals[0] == first.online_signals[0]
    assert resumed.online_signals[0] == pytest.approx(uninterrupted.online_signals[0])
    assert png_size(out / "learning_curve.png") == (720, 1440)  # four signal panels


# ----------------------------------------------------------------------------- offline_cache
def test_a_shared_offline_phase_keeps_the_runs_own_wandb_run(tmp_path):
    """A run loading a shared offline phase (``offline_cache``) takes the snapshot's logger
    counters but logs on to its own W&B run; the snapshot stores no W&B files."""
    from torchrl_dual.recipe.o2o.loggers import make_logger
    from torchrl_dual.recipe.o2o.offline_cache import OfflinePhaseCache
    from torchrl_dual.recipe.settings.loggers import WandbSettings

    cfg = WandbSettings(backend="wandb", project="p", entity=None, mode="offline")
    first = make_logger(cfg, tmp_path / "first" / "logs", "dual")
    first.log_scalar("planner/loss_diffusion", 1.0, step=60)
    snapshot = first.state_dict()
    first.shutdown()
    cache = OfflinePhaseCache(tmp_path / "cache", {"seed": 0}, "v1")
    cache.save({"logger": snapshot}, tmp_path / "first" / "logs")
    assert not (cache.directory / "logs" / "wandb").exists()

    own = make_logger(cfg, tmp_path / "second" / "logs", "dual")
    loaded = make_logger(cfg, tmp_path / "second" / "logs", "dual", snapshot, previous=own)
    assert loaded.experiment.id == own.experiment.id != snapshot["local"]["id"]
    assert loaded.state_dict()["local"]["step_registry"] == {"planner/step": 60}
    assert Path(loaded.state_dict()["log_dir"]) == (tmp_path / "second" / "logs").resolve()
    loaded.shutdown()
