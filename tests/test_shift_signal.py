"""``benchmarks/studies/shift_signal.py``: a DUAL run's shift signal ``d_t`` on its offline data,
online without a shift and under each shift."""

from __future__ import annotations

import json
from pathlib import Path

import torch
from recipe_runner import run_recipe

from benchmarks.studies import shift_signal
from benchmarks.studies.critic_calibration import load_run

REPO = Path(__file__).resolve().parents[1]

TINY = ("budget.offline_updates=10", "budget.online_frames=100", "budget.frames_per_batch=50")
TINY += ("budget.eval_every=100", "budget.eval_episodes=1", "env.max_episode_steps=40")


def test_the_signal_is_eq_10s_distance_on_each_kind_of_transition(tmp_path):
    """Offline: ‖ŝ' − s'‖ of the run's own transition model on the sampled transitions;
    online: the policy's logged d_t equals ‖predict(s_{t-1}, a_{t-1}) − s_t‖ recomputed
    from the same rollout, and the steps after a reset are left out; a shift changes it."""
    run_dir = tmp_path / "run"
    proc = run_recipe(run_dir, tmp_path / "data", "algo=dual", *TINY, cli=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = load_run(run_dir, tmp_path)

    d = shift_signal.offline_distance(run, samples=300, seed=1)
    data = run.data.transitions
    batch = data[torch.randperm(len(data), generator=torch.Generator().manual_seed(1))[:300]]
    by_hand = run.learner.transition.predict(batch["observation"], batch["action"])
    torch.testing.assert_close(d, (by_hand - batch["next", "observation"]).norm(dim=-1))

    torch.manual_seed(5)  # the policy's exploration noise: the same in both rollouts
    online = shift_signal.online_distance(run, "none", steps=120, seed=2)
    # 120 steps of 40-step episodes: 3 resets, whose steps have no previous step
    assert len(online) == 117 and bool((online > 0).all())
    env = shift_signal.make_train_env(run.settings, run.data)
    env.set_seed(2)
    torch.manual_seed(5)
    with shift_signal.set_exploration_type(shift_signal.ExplorationType.RANDOM):
        rollout = env.rollout(120, run.learner.policy, break_when_any_done=False)
    valid = rollout["previous_valid"].reshape(-1)
    predicted = run.learner.transition.predict(
        rollout["previous_observation"][valid], rollout["previous_action"][valid]
    )
    recomputed = (predicted - rollout["observation"][valid]).norm(dim=-1)
    torch.testing.assert_close(online, recomputed, rtol=1e-4, atol=1e-5)
    rotated = shift_signal.online_distance(run, "rotation", steps=120, seed=2)
    assert len(rotated) == 117 and not torch.allclose(rotated, online)

    out = tmp_path / "signal.json"
    argv = [str(run_dir), "--shifts", "mass", "--steps", "60", "--samples", "100"]
    assert shift_signal.main([*argv, "--json", str(out)]) == 0
    table = json.loads(out.read_text())[str(run_dir)]
    assert list(table) == ["offline", "online none", "online mass"]
    assert table["offline"]["n"] == 100 and table["offline"]["vs_offline"] == 1.0
    mass = table["online mass"]
    assert mass["lambda_d"] == 0.5 * mass["mean"]
    assert 0 < mass["policy_std"] < mass["executed_std"]  # λ d_t > 0 adds to σ_θ²
    assert shift_signal.main([str(tmp_path / "nothing")]) == 2
