"""``compile.compile=true``: the recipe's updates through ``torch.compile`` give the eager
updates' losses and weights to float tolerance over 100 updates (issue 30 item 3).

DUAL's update stands for every learner here: the compiled wrapper is the one every
learner's update goes through, and DUAL's holds IQL's critic terms and Eq. 7's actor.
``test_update_host_reads.py`` checks every learner's update for host reads (what breaks
a compiled graph); ``test_compile.py`` compiles each loss of the package.
"""

from __future__ import annotations

import pytest
import torch

from torchrl_dual.recipe import ALGORITHMS, CONFIG_DIR, ConfigError, O2ORun, compose_checked

TINY = (
    "budget=smoke", "env=frozenlake", "budget.dataset_transitions=500",
    "budget.network_width=16", "budget.batch_size=32", "progress=false", "num_threads=1",
)  # fmt: skip

pytestmark = pytest.mark.long_running(seconds=40)
UPDATES = 100


def _run(tmp_path, cache, algo: str, *extra: str) -> O2ORun:
    cfg = compose_checked(
        CONFIG_DIR,
        [*TINY, f"algo={algo}", f"output_dir={tmp_path}", f"data_cache_dir={cache}", *extra],
    )
    return O2ORun(cfg, ALGORITHMS[algo].learner)


def test_compiled_dual_updates_follow_the_eager_ones(tmp_path):
    cache = tmp_path / "data"
    eager = _run(tmp_path / "eager", cache, "dual")
    compiled = _run(tmp_path / "compiled", cache, "dual", "compile.compile=true")
    assert eager.update.update == eager.learner.update  # the learner's own, eager
    assert compiled.update.update != compiled.learner.update  # the compiled wrapper
    batches = [eager.offline_buffer.sample().clone() for _ in range(UPDATES)]
    for i, batch in enumerate(batches):
        expected, got = eager.update(batch.clone()), compiled.update(batch.clone())
        for name, value in expected.items():
            torch.testing.assert_close(got[name], value, rtol=1e-4, atol=1e-5, msg=f"{i}: {name}")
    assert compiled.updates == eager.updates == UPDATES
    for (name, a), (_, b) in zip(
        eager.learner.actor.named_parameters(), compiled.learner.actor.named_parameters(),
        strict=True,
    ):  # fmt: skip
        torch.testing.assert_close(b, a, rtol=1e-4, atol=1e-5, msg=name)


def test_compile_keys_are_checked(tmp_path):
    with pytest.raises(ConfigError, match="compile.compile_mode"):
        compose_checked(
            CONFIG_DIR, [*TINY, f"output_dir={tmp_path}", "compile.compile_mode=fastest"]
        )
    cfg = compose_checked(CONFIG_DIR, [*TINY, f"output_dir={tmp_path}"])
    assert cfg.compile.compile is False and cfg.compile.compile_mode is None
    assert cfg.compile.cudagraphs is False
