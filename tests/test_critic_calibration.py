"""``benchmarks/studies/critic_calibration.py``: a finished run's critic against its data's
Monte-Carlo returns."""

from __future__ import annotations

import json
from pathlib import Path

import torch
from recipe_runner import run_recipe

from benchmarks.studies import critic_calibration

REPO = Path(__file__).resolve().parents[1]

from torchrl_dual.data import monte_carlo_returns  # noqa: E402

TINY = ("budget.offline_updates=10", "budget.online_frames=100", "budget.frames_per_batch=50")
TINY += ("budget.eval_every=100", "budget.eval_episodes=1", "env.max_episode_steps=50")


def test_a_constant_critic_reads_as_that_constant_against_the_exact_returns(tmp_path):
    """Q set to 2 everywhere (last layer: weights 0, bias 2): the script's Q at the data and
    at the policy's actions is 2, and the underestimated share is that of ``G > 2`` on the
    same transitions; the command line prints one row and writes the JSON."""
    run_dir = tmp_path / "run"
    proc = run_recipe(run_dir, tmp_path / "data", "algo=iql", *TINY, cli=True)  # writes .hydra
    assert proc.returncode == 0, proc.stderr[-2000:]

    run = critic_calibration.load_run(run_dir, tmp_path)  # tmp_path: a work dir of its own
    params = run.learner.critic.loss.qvalue_network_params
    last = max(k for k in params.keys(True, True) if k[-1] == "weight")
    params.set_(last, torch.zeros_like(params.get(last)))
    params.set_((*last[:-1], "bias"), torch.full_like(params.get((*last[:-1], "bias")), 2.0))
    figures = critic_calibration.calibration(run, samples=500, seed=3)

    returns = monte_carlo_returns(run.data.transitions, run.settings.critic.discount).reshape(-1)
    index = torch.randperm(len(returns), generator=torch.Generator().manual_seed(3))[:500]
    assert figures["transitions"] == 500
    assert abs(figures["q_data"] - 2.0) < 1e-6 and abs(figures["q_policy"] - 2.0) < 1e-6
    assert abs(figures["mc_return"] - float(returns[index].mean())) < 1e-5
    assert figures["underestimated"] == float((returns[index] > 2.0).float().mean())

    out = tmp_path / "calibration.json"
    assert critic_calibration.main([str(run_dir), "--samples", "200", "--json", str(out)]) == 0
    saved = json.loads(out.read_text())[str(run_dir)]
    assert saved["transitions"] == 200 and saved["frames"] == 100
    assert -1.0 <= saved["corr_q_mc"] <= 1.0
    assert (run_dir / "checkpoint.pt").is_file()  # read only
    assert critic_calibration.main([str(tmp_path / "nothing")]) == 2
