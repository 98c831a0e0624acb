"""Shared fixtures and mock factories of the torchrl-dual test suite.

The ``make_*`` fixtures return factories (in the spirit of TorchRL's ``_create_mock_*``)
that build tiny networks (``hidden=32``, ``depth=1``) and ``[batch, H + 1]`` window
TensorDicts, so each test builds exactly what it needs in milliseconds.
"""

from __future__ import annotations

import fcntl
import os
import sys
import tempfile
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from torchrl_dual.diffusion import (
    NoiseSchedule,
    TrajectoryDiffusion,
    TrajectoryLayout,
    WindowReplayBuffer,
)

# ``tests/`` holds no ``__init__.py``; make ``import toy`` work from any test directory.
sys.path.insert(0, str(Path(__file__).parent))
from toy import bimodal_transitions, identity_statistics  # noqa: E402

HIDDEN = 32
DEPTH = 1


def pytest_configure(config: pytest.Config) -> None:
    # The suite runs on 2 shared CPU cores: with a busy neighbour, intra-op threading
    # makes a tiny nn.Linear ~100x slower. TORCHRL_DUAL_TEST_THREADS overrides.
    torch.set_num_threads(int(os.environ.get("TORCHRL_DUAL_TEST_THREADS", "1")))


def expected_seconds(item: pytest.Item) -> float:
    """The ``long_running(seconds=...)`` mark of ``item``'s file (0 without one)."""
    mark = item.get_closest_marker("long_running")
    return 0.0 if mark is None else float(mark.kwargs["seconds"])


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The longest files first, the others in collection order (a stable sort).

    ``-n 2 --dist loadfile`` (with ``--no-loadscope-reorder``, in pyproject's ``addopts``)
    hands whole files to the workers in this order, so the files that take minutes start
    at once and the many short ones fill the other worker around them; xdist's default
    order (most tests first) started the one-test, three-minute distillation file last.
    """
    items.sort(key=lambda item: -expected_seconds(item))


@pytest.fixture(scope="module")
def ray_exclusive():
    """Holds a machine-wide file lock for a whole test module that starts or joins a Ray
    cluster: under xdist two such modules on two workers would see each other's cluster
    (``address="auto"`` finds it) and share its CPUs. The second waits for the first."""
    with open(Path(tempfile.gettempdir()) / "torchrl_dual_ray_tests.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture
def seeded() -> int:
    """Seeds torch's global generator with 0 (use with ``pytest.mark.usefixtures``)."""
    torch.manual_seed(0)
    return 0


# ----------------------------------------------------------------------------- factories
def create_mock_layout(obs_dim: int = 3, action_dim: int = 2, horizon: int = 4) -> TrajectoryLayout:
    return TrajectoryLayout(obs_dim=obs_dim, action_dim=action_dim, horizon=horizon)


def create_mock_model(
    layout: TrajectoryLayout | None = None,
    *,
    num_steps: int = 4,
    fit: bool = True,
    seed: int = 0,
    denoiser: nn.Module | None = None,
) -> TrajectoryDiffusion:
    """A tiny planner; with ``fit`` its normalizer holds non-trivial statistics, without
    it the identity (mean 0, std 1, declared fitted: :func:`toy.identity_statistics`)."""
    layout = layout or create_mock_layout()
    with torch.random.fork_rng():  # seeded weights, global generator left as it was
        torch.manual_seed(seed)
        model = TrajectoryDiffusion(
            layout, denoiser, num_steps=num_steps, hidden=HIDDEN, depth=DEPTH
        )
    if fit:
        gen = torch.Generator().manual_seed(seed + 1)
        obs = torch.randn(256, layout.obs_dim, generator=gen) * 3.0 + 1.5
        act = torch.rand(256, layout.action_dim, generator=gen) * 2.0 - 1.0
        model.normalizer.fit(obs, act)
    else:
        identity_statistics(model.normalizer)
    return model


def create_mock_windows(
    layout: TrajectoryLayout | None = None,
    *,
    batch: int = 8,
    seed: int = 0,
    observation_key="observation",
    action_key="action",
) -> TensorDict:
    """A ``[batch, H + 1]`` TensorDict of random windows under the given keys."""
    layout = layout or create_mock_layout()
    gen = torch.Generator().manual_seed(seed)
    td = TensorDict(batch_size=[batch, layout.length])
    td.set(observation_key, torch.randn(batch, layout.length, layout.obs_dim, generator=gen))
    td.set(action_key, torch.rand(batch, layout.length, layout.action_dim, generator=gen))
    return td


class PointMassOracle(nn.Module):
    """The exact ``v`` for a data distribution that is a point mass at ``c``.

    With ``x_0 = c`` almost surely, ``E[x_0 | z_t] = c``, so ``ε = (z − α_t·c)/σ_t``
    and ``v = α_t·ε − σ_t·c``. Defined for ``t > 0``, which is all a sampler queries.
    """

    def __init__(self, c: torch.Tensor, schedule: NoiseSchedule) -> None:
        super().__init__()
        self.register_buffer("c", c)
        self.schedule = schedule

    def forward(self, z: torch.Tensor, t: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        alpha, sigma = self.schedule(t.to(z.dtype))
        alpha, sigma = alpha[..., None, None], sigma[..., None, None]
        eps = (z - alpha * self.c) / sigma
        return alpha * eps - sigma * self.c


class FixedOutput(nn.Module):
    """A stand-in denoiser that returns a preset tensor (e.g. the true ``v``)."""

    def __init__(self) -> None:
        super().__init__()
        self.value: torch.Tensor | None = None

    def forward(self, z: torch.Tensor, t: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.value


def create_toy_setup(
    *, horizon: int = 4, batch_size: int = 64, num_steps: int = 2, num_episodes: int = 200
) -> tuple[TrajectoryDiffusion, WindowReplayBuffer]:
    """A tiny planner with a normalizer fitted on ``toy.bimodal_transitions`` and its windows."""
    data = bimodal_transitions(num_episodes=num_episodes, length=12, seed=0)
    layout = TrajectoryLayout(obs_dim=1, action_dim=1, horizon=horizon)
    model = create_mock_model(layout, num_steps=num_steps, fit=False)
    model.normalizer.fit(data["observation"], data["action"])
    return model, WindowReplayBuffer(data, horizon=horizon, batch_size=batch_size)


def check_td_steady(before: TensorDictBase, after: TensorDictBase) -> None:
    """Like TorchRL's ``_check_td_steady``: same keys, same values, nothing written."""
    assert set(before.keys(True, True)) == set(after.keys(True, True))
    for key in before.keys(True, True):
        assert torch.equal(before.get(key), after.get(key)), f"{key!r} was modified"


def train(loss_module: nn.Module, sample, num_updates: int, *, lr: float = 1e-3) -> list[float]:
    """Plain Adam loop on the sum of the ``loss_*`` entries; returns the loss history."""
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=lr)
    history = []
    for _ in range(num_updates):
        out = loss_module(sample())
        loss = sum(v for k, v in out.items() if k.startswith("loss_"))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        history.append(loss.detach().item())
    return history


def check_draws_follow_the_data(loss_fn, windows, keys: tuple[str, ...]) -> None:
    """``loss_fn`` makes its random draws where ``windows`` live: under a ``torch.device``
    default-device block (``meta``, standing in for an accelerator) CPU windows give the
    same CPU outputs ``keys`` as outside it, with the same seed."""
    torch.manual_seed(4)
    expected = loss_fn(windows)
    torch.manual_seed(4)
    with torch.device("meta"):
        out = loss_fn(windows)
    for key in keys:
        assert out[key].device == torch.device("cpu"), key
        torch.testing.assert_close(out[key], expected[key], msg=key)


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture
def make_layout():
    return create_mock_layout


@pytest.fixture
def make_model():
    return create_mock_model


@pytest.fixture
def make_windows():
    return create_mock_windows


@pytest.fixture
def make_toy_setup():
    return create_toy_setup


@pytest.fixture
def draws_follow_the_data():
    return check_draws_follow_the_data


@pytest.fixture
def td_steady():
    return check_td_steady


@pytest.fixture
def run_adam():
    return train


@pytest.fixture
def point_mass_oracle():
    return PointMassOracle


@pytest.fixture
def fixed_output_denoiser():
    return FixedOutput
