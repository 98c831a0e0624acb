"""``replay=mixed``: TorchRL's ``OfflineToOnlineReplayBuffer`` over the run's offline buffer."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

from torchrl_dual.recipe.o2o.replays import make_mixed_replay


def _run(offline_fraction: float, batch_size: int = 8, n_offline: int = 50) -> SimpleNamespace:
    offline = ReplayBuffer(
        storage=LazyTensorStorage(n_offline), sampler=RandomSampler(), batch_size=batch_size
    )
    offline.extend(TensorDict({"source": torch.zeros(n_offline, 1)}, batch_size=[n_offline]))
    settings = SimpleNamespace(
        online=SimpleNamespace(offline_fraction=offline_fraction, batch_size=batch_size),
        budget=SimpleNamespace(online_frames=20),
    )
    return SimpleNamespace(
        settings=settings, offline_buffer=offline, learner=SimpleNamespace(extra_online_capacity=0)
    )


def test_mixed_batches_split_as_configured_without_a_batch_size_warning():
    run = _run(offline_fraction=0.25)
    replay = make_mixed_replay(run)
    replay.extend(TensorDict({"source": torch.ones(20, 1)}, batch_size=[20]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # TorchRL 0.14 warns on a conflicting batch size
        batch = replay.sample()
    assert batch.shape == (8,)
    assert int((batch["source"] == 0).sum()) == 2  # round(0.25 * 8) offline transitions
    # the offline phase still samples its own default batch from the same storage
    assert run.offline_buffer.sample().shape == (8,)
    assert replay.buffer.offline_buffer.storage is run.offline_buffer.storage


def test_joint_replay_draws_every_offline_and_online_transition_alike():
    """``online.offline_fraction=joint`` (CORL's one buffer): the offline share of a batch
    is N_off / (N_off + N_on) on average, falls as D_online grows, and every stored
    transition is drawn about equally often (uniform over the union)."""
    torch.manual_seed(0)
    run = _run("joint", batch_size=64, n_offline=30)
    run.offline_buffer.storage.set(
        torch.arange(30), TensorDict({"source": torch.arange(30.0)[:, None]}, [30])
    )
    replay = make_mixed_replay(run)
    assert (replay.sample()["source"] < 30).all()  # D_online empty: offline only
    replay.extend(TensorDict({"source": 30.0 + torch.arange(10.0)[:, None]}, batch_size=[10]))
    draws = torch.cat([replay.sample()["source"].flatten() for _ in range(500)])
    assert draws.shape == (500 * 64,)
    assert abs(float((draws < 30).float().mean()) - 30 / 40) < 0.01  # 0.75: 3 sd ≈ 0.0073
    counts = torch.bincount(draws.long(), minlength=40).float()
    expected = draws.numel() / 40  # 800 per transition, sd ≈ 28
    assert float((counts - expected).abs().max()) < 5 * expected**0.5
    replay.extend(TensorDict({"source": 40.0 + torch.zeros(10, 1)}, batch_size=[10]))
    later = torch.cat([replay.sample()["source"].flatten() for _ in range(200)])
    assert abs(float((later < 30).float().mean()) - 30 / 50) < 0.015  # 0.6 once N_on = 20


def test_budget_paper_runs_iql_and_dual_on_corl_s_replay_and_update_ratio(tmp_path):
    """CORL's finetune IQL (settings/references.py, BUDGET_SETTINGS): one buffer and one
    update per env step under budget=paper, for IQL and DUAL only; the other budgets and
    algorithms keep the recipe's 0.5 / 0.5; a command-line value wins."""
    import pytest

    from torchrl_dual.recipe import CONFIG_DIR, compose_checked
    from torchrl_dual.recipe.settings.errors import ConfigError

    def online(*overrides: str) -> tuple:
        cfg = compose_checked(CONFIG_DIR, [*overrides, f"output_dir={tmp_path}"])
        return cfg.online.offline_fraction, cfg.online.utd_ratio

    for algo in ("iql", "dual"):
        assert online("budget=paper", f"algo={algo}") == ("joint", 1.0)
        assert online("budget=default", f"algo={algo}") == (0.5, 0.5)
        assert online("budget=smoke", f"algo={algo}") == (0.5, 0.5)
    assert online("budget=paper", "algo=calql") == (0.5, 0.5)
    assert online("budget=paper", "algo=dual", "online.utd_ratio=0.5") == ("joint", 0.5)
    with pytest.raises(ConfigError, match="online.offline_fraction=joint"):
        online("algo=diffuser", "online.offline_fraction=joint")  # draws its own windows
