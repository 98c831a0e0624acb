"""recipes/torchrl_trainer.py: DUAL on PointMaze U-maze (tiny data) through Trainer.train(),
then its offline stages resumed from the trainer's checkpoint."""

import math

from benchmarks.studies.trainer_vs_recipe import load_trainer_script
from tests.recipe_runner import TINY

# the recipe tests' cut-down smoke budget, on PointMaze U-maze
TINY_UMAZE = [*(o for o in TINY if not o.startswith("env=")), "env=pointmaze_umaze"]


def cfg_eval_every(recipe: list[str]) -> int:
    from torchrl_dual.recipe import CONFIG_DIR, compose_checked

    return int(compose_checked(CONFIG_DIR, recipe).budget.eval_every)


def test_script_trains_dual_on_umaze_and_resumes_offline_stages(tmp_path, capsys):
    script = load_trainer_script()
    recipe = [*TINY_UMAZE, f"output_dir={tmp_path / 'run'}"]
    save = tmp_path / "trainer.pt"
    argv = [  # the recipe's command line, plus TorchRL's trainer.* keys
        *recipe,
        "trainer.progress_bar=false",
        f"trainer.save_trainer_file={save}",
        "trainer.save_trainer_interval=1",
    ]
    trainer = script.main(argv)
    score = trainer._modules["normalized_score"].evaluate()["normalized_score"]
    assert capsys.readouterr().out.splitlines()[-1] == (
        f"[dual] TorchRL Trainer: 100 online frames, final normalized score {score:.1f}"
    )
    assert trainer.offline_stages.done == ["planner", "distillation", "actor_critic", "laplace"]
    assert trainer.collected_frames == 100 and trainer._optim_count == 50
    # the refit hook runs once per collected batch, when >= 10 updates passed: 2 batches
    assert trainer.laplace_refit.num_refits == 2
    # the recipe's evaluator, every budget.eval_every frames, its normalized score logged
    scores = trainer._log_dict["eval/normalized_score"]
    assert len(scores) == trainer.collected_frames // cfg_eval_every(recipe) >= 1
    assert all(math.isfinite(score) for score in scores)
    assert len(trainer._log_dict["dual/shift_distance"]) == 2  # one per collected batch
    assert save.exists()

    calls = []
    resumed = script.build_trainer(*script.compose_configs(argv))
    for i, (name, _stage) in enumerate(resumed.offline_stages.stages):
        resumed.offline_stages.stages[i] = (name, lambda n=name: calls.append(n))
    resumed.load_from_file(save)
    teacher, restored = trainer._modules["dual_teacher"], resumed._modules["dual_teacher"]
    for key, value in teacher.state_dict().items():  # the trained planner came back
        if value.is_floating_point():
            assert value.equal(restored.state_dict()[key]), key
    assert resumed.offline_stages.done == trainer.offline_stages.done
    resumed.train()
    assert calls == []  # every offline stage came back finished from the checkpoint
