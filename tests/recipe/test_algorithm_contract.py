"""One contract over every entry of ``ALGORITHMS`` (issue 28 item 6).

Each algorithm, on Frozen-Lake at a cut-down smoke budget, in-process: it composes and
validates, builds its learner, runs its offline stages and its online updates, is
interrupted (``interrupt_at_frames``) with a checkpoint, resumes from it to the end
(skipping every finished stage, continuing the frame counter and the history), writes
``summary.json``, and its checkpoint restores every module of its learner exactly; the
interrupted and resumed run ends bitwise as the same run never interrupted; and every
optimizer it checkpoints is PyTorch's fused Adam (``objectives/optim.py``).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from recipe_runner import TINY, WALL_CLOCK

from torchrl_dual.checkpoint import state_differences
from torchrl_dual.recipe import ALGORITHMS, CONFIG_DIR, O2ORun, compose_checked, run_o2o

pytestmark = pytest.mark.long_running(seconds=60)  # starts first under xdist


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("contract_data")


def tensors(state) -> dict:
    """The tensors of a (nested) state dict, by dotted name."""
    if isinstance(state, torch.Tensor):
        return {"": state}
    if isinstance(state, dict):
        return {
            f"{k}.{sub}".rstrip("."): v
            for k, value in state.items()
            for sub, v in tensors(value).items()
        }
    if isinstance(state, (list, tuple)):
        return {
            f"{i}.{sub}".rstrip("."): v
            for i, x in enumerate(state)
            for sub, v in tensors(x).items()
        }
    return {}


@pytest.mark.parametrize("algo", sorted(ALGORITHMS))
def test_every_algorithm_runs_checkpoints_resumes_and_restores(algo, cache_dir, tmp_path):
    def cfg(*extra: str, output_dir: Path = tmp_path):
        return compose_checked(
            CONFIG_DIR,
            [*TINY, f"algo={algo}", f"output_dir={output_dir}", f"data_cache_dir={cache_dir}",
             *extra],
        )  # fmt: skip

    entry = ALGORITHMS[algo]
    first = run_o2o(cfg("interrupt_at_frames=50"), entry.learner)
    assert first.frames == 50 and (tmp_path / "checkpoint.pt").exists()
    assert not (tmp_path / "summary.json").exists()  # interrupted, not finished
    offline_stages = [name for name, _ in first.learner.offline_stages()]
    assert set(offline_stages) <= set(first.stages_done)
    for name, module in first.learner.modules().items():  # issue 40: fused Adam, every one
        if isinstance(module, torch.optim.Optimizer):
            assert all(group["fused"] for group in module.param_groups), f"{algo}: {name}"

    second = run_o2o(cfg("resume=true"), entry.learner)
    assert second.frames == 100 and second.updates > first.updates
    assert second.stages_done[: len(first.stages_done)] == first.stages_done
    assert [h["frames"] for h in second.history] == [0, 100]  # offline, then the end
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["algo"] == algo and summary["frames"] == 100

    restored = O2ORun(cfg("resume=true"), entry.learner)  # loads the final checkpoint
    assert restored.frames == 100 and restored.updates == second.updates
    for name, module in second.learner.modules().items():
        want, got = (
            tensors(module.state_dict()),
            tensors(restored.learner.modules()[name].state_dict()),
        )
        assert want.keys() == got.keys(), name
        for key, value in want.items():
            assert torch.equal(got[key], value), f"{name}.{key}"

    # ... and ends bitwise as the run never interrupted (issue 31): its interrupt came at a
    # checkpoint, where both runs start a new collector (the online loop's cut point)
    whole = run_o2o(cfg(output_dir=tmp_path / "whole"), entry.learner)
    assert whole.frames == 100
    differ = state_differences(whole.state(), second.state(), ignore=WALL_CLOCK)
    assert differ == [], f"{algo}: the resumed run differs at {differ[:10]}"
