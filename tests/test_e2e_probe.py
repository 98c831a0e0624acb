"""``benchmarks/speed/e2e_probe.py`` (issue 40, item 4): the recipe end to end on a stand-in
AntMaze data set at ``budget=paper`` sizes with its counts cut, its stage times turned into
rates, and ``budget=paper`` projected from those rates only
(``gpu_projection.project_from_probe``). No timing is asserted."""

from __future__ import annotations

import json

import pytest
from recipe_runner import run_module

from benchmarks.speed import e2e_probe
from benchmarks.speed.gpu_projection import PAPER, project_from_probe

pytestmark = pytest.mark.long_running(seconds=20)


def _value(overrides: list[str], key: str) -> str:
    return next(o.split("=", 1)[1] for o in overrides if o.startswith(key + "="))


@pytest.mark.parametrize("num_envs", [1, 8, 16])
def test_the_probe_keeps_the_paper_s_batch_up_to_a_multiple_of_the_env_count(num_envs):
    overrides = e2e_probe.overrides(e2e_probe.SCALES["probe"], num_envs)
    per_batch = int(_value(overrides, "budget.frames_per_batch"))
    assert per_batch % num_envs == 0 and abs(per_batch - PAPER["frames_per_batch"]) < num_envs
    frames = int(_value(overrides, "budget.online_frames"))
    assert frames == 4 * per_batch
    # nothing but collection and its updates in the timed online phase
    for key in ("budget.eval_every", "budget.laplace_refit_every", "budget.checkpoint_every"):
        assert int(_value(overrides, key)) > frames
    assert _value(overrides, "budget") == "paper" and _value(overrides, "env") == "antmaze"


def test_rates_divide_each_count_by_its_stage_time():
    summary = {
        "config": {
            "budget": {"planner_updates": 100, "distill_updates": [10] * 5,
                       "offline_updates": 200, "online_frames": 50, "eval_episodes": 4},
            "online": {"utd_ratio": 0.5},
        },
        "stage_seconds": {"planner": 4.0, "distillation": 5.0, "actor_critic": 8.0,
                          "laplace": 0.5, "offline_eval": 2.0, "online": 10.0},
    }  # fmt: skip
    rates = e2e_probe.rates(summary, transitions=2000)
    assert rates["planner_updates_per_s"] == 25.0
    assert rates["distill_updates_per_s"] == 10.0
    assert rates["offline_updates_per_s"] == 25.0
    assert rates["laplace_s_per_1k_transitions"] == 0.25
    assert rates["online_s_per_frame"] == 0.2
    assert (rates["evaluation_s"], rates["evaluation_episodes"]) == (2.0, 4)


def test_the_projection_refuses_a_probe_at_another_update_ratio():
    probe = {"measured": {}, "rates": {"online_utd_ratio": 0.5}}  # budget=paper's DUAL: 1.0
    with pytest.raises(ValueError, match="utd_ratio"):
        project_from_probe(probe)


def test_the_probe_runs_the_recipe_and_projects_the_paper_budget(tmp_path):
    pytest.importorskip("h5py", reason="Minari's storage needs h5py")
    out = tmp_path / "probe.json"
    args = ["--scale", "tiny", "--num-envs", "2", "--data", str(tmp_path / "data")]
    proc = run_module("benchmarks.speed.e2e_probe", *args, "--json", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(out.read_text())
    assert "budget.planner_updates=20" in report["overrides"]
    assert all(v > 0 for k, v in report["rates"].items() if k.endswith(("_per_s", "_frame")))
    hours = report["paper_hours"]
    parts = ("planner", "distillation", "actor_critic", "laplace", "online", "evaluation")
    assert hours["total"] == pytest.approx(sum(hours[p] for p in parts))
    # each input names where and when it was measured
    label = hours["inputs"]["online_s_per_frame"]["measured"]
    assert "device=cpu" in label["machine"] and label["date"].startswith("20")
    assert (tmp_path / "data" / ".standin_4x40").exists()  # the data set, written once
