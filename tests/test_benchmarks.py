"""The ``benchmarks`` package as a whole (every script has a row in its README) and the
scripts of ``benchmarks/studies/`` and ``benchmarks/robustness/`` (tiny sizes). The
learning suite's tests are in ``tests/test_learning_suite.py``, the speed scripts' in
``tests/test_speed_scripts.py``."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from recipe_runner import run_module

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.long_running(seconds=20)  # starts first under xdist


def test_every_benchmark_script_is_listed_in_the_benchmarks_readme():
    """Each module of ``benchmarks/<folder>/`` has a row in the README's section of its
    folder (``## `<folder>/` ...``), and the top level holds only the packages."""
    folder = REPO / "benchmarks"
    readme = (folder / "README.md").read_text()
    sections = {
        part.split("`", 1)[0]: part for part in readme.split("\n## `")[1:] if "/`" in part[:40]
    }
    scripts = [
        p
        for p in sorted([*folder.rglob("*.py"), *folder.rglob("*.sh")])
        if p.name not in ("__init__.py", "__main__.py") and "results" not in p.parts
    ]
    assert len(scripts) > 30 and not [p for p in scripts if p.parent == folder]
    listed = {  # folder -> the names in the first column of its section's table rows
        name: {n for row in text.splitlines() if row.startswith("| `") for n in
               re.findall(r"`([^`]+)`", row.split(" | ")[0])}
        for name, text in sections.items()
    }  # fmt: skip
    missing = [
        str(p.relative_to(folder))
        for p in scripts
        if p.name not in listed.get(f"{p.parent.name}/", set())
    ]
    assert not missing, f"add a row to benchmarks/README.md for {missing}"


# ---------------------------------------------------------------- studies/
def test_online_reward_counts_the_batches_with_reward_and_the_positive_evaluations(tmp_path):
    from benchmarks.studies import online_reward

    summary = {"history": [
        {"label": "offline", "return": 0.0}, {"label": "online", "return": 0.0},
        {"label": "online", "return": 14.0}, {"label": "online", "return": 0.0},
    ]}  # fmt: skip
    (tmp_path / "results" / "cell" / "dual").mkdir(parents=True)
    (tmp_path / "results" / "cell" / "dual" / "seed3.json").write_text(json.dumps(summary))
    logs = tmp_path / "runs" / "cell" / "dual" / "seed3" / "logs" / "dual" / "scalars" / "online"
    logs.mkdir(parents=True)
    (logs / "reward_per_step.csv").write_text("500,0.0\n1000,0.002\n1500,0.0\n2000,0.01\n")
    records = online_reward.cell_records(tmp_path / "results", tmp_path / "runs", "cell")
    assert records == {"dual": {3: {
        "batches": 4, "batches_with_reward": 2, "first_reward_frames": 1000,
        "evaluations_with_return": 1, "evaluations": 3, "final_return": 0.0,
    }}}  # fmt: skip
    # a JSON that records the batch rewards itself is read without the logs
    summary["online_signals"] = [
        {"frames": 500, "epistemic_share": 0.5, "reward_per_step": 0.0},
        {"frames": 1000, "epistemic_share": 0.5, "reward_per_step": 0.004},
    ]
    (tmp_path / "results" / "cell" / "dual" / "seed3.json").write_text(json.dumps(summary))
    records = online_reward.cell_records(tmp_path / "results", tmp_path / "elsewhere", "cell")
    assert records["dual"][3]["batches"] == 2 and records["dual"][3]["first_reward_frames"] == 1000
    del summary["online_signals"][0]["reward_per_step"]  # resumed across the change: the logs
    (tmp_path / "results" / "cell" / "dual" / "seed3.json").write_text(json.dumps(summary))
    records = online_reward.cell_records(tmp_path / "results", tmp_path / "runs", "cell")
    assert records["dual"][3]["batches"] == 4


def test_update_path_lists_the_files_of_one_dual_update_in_call_order():
    from benchmarks.studies.update_path import files_of_one_update

    files, after = files_of_one_update(["algo=dual"])
    # the run's stepper, the learner, Alg. 1's stepper, DUAL's loss, then Eq. 7's actor
    assert files[:4] == [
        "recipe/o2o/update_step.py", "recipe/algos/dual.py", "trainers/stepper.py",
        "objectives/dual.py",
    ]  # fmt: skip
    assert files.index("objectives/weighted_map_actor.py") > 3
    # the refit count (the learner's after_update) and the replay's step come after
    assert after == ["trainers/hooks.py", "recipe/o2o/replays.py"]
    assert "recipe/o2o/loop.py" not in files + after and "recipe/o2o/run.py" not in files + after


def test_update_path_runs_so2_on_its_balanced_replay_of_offline_and_online_data():
    from benchmarks.studies.update_path import files_of_one_update

    files, after = files_of_one_update(["algo=so2"])  # its replay samples D_online too
    assert "objectives/so2.py" in files and "recipe/o2o/replays.py" in after


def test_smoke_bitwise_names_each_run_and_what_differs(tmp_path):
    from benchmarks.robustness.smoke_bitwise import compare, differences, runs

    assert runs()["dual_calql"] == ["algo=dual", "critic=calql"] and "so2" in runs()
    for side in ("a", "b"):
        scalars = tmp_path / side / "iql" / "logs" / "iql" / "scalars" / "eval"
        scalars.mkdir(parents=True)
        (scalars / "return.csv").write_text("100,1.5\n")
        (tmp_path / side / "iql" / "summary.json").write_text('{"history": [{"return": 1.5}]}')
    assert differences(tmp_path / "a" / "iql", tmp_path / "b" / "iql") == []
    assert compare(tmp_path / "a", tmp_path / "b")
    (tmp_path / "b" / "iql" / "logs" / "iql" / "scalars" / "eval" / "return.csv").write_text(
        "100,1.5000001\n"
    )
    (tmp_path / "b" / "iql" / "summary.json").write_text('{"history": [{"return": 1.4}]}')
    assert differences(tmp_path / "a" / "iql", tmp_path / "b" / "iql") == [
        "summary.json history",
        "logs/iql/scalars/eval/return.csv",
    ]
    assert not compare(tmp_path / "a", tmp_path / "b")


def test_paired_mcnemar_counts_discordant_seeds_and_gives_the_exact_binomial_tail():
    from benchmarks.studies.online_reward import paired_mcnemar

    def runs(found: list[int]) -> dict[int, dict]:
        return {seed: {"batches_with_reward": n} for seed, n in enumerate(found)}

    # 7 of 7 against 0 of 7: every pair discordant one way, p = 2**-7
    test = paired_mcnemar(runs([2, 1, 3, 1, 1, 2, 1]), runs([0] * 7))
    assert (test["better"], test["worse"]) == (7, 0)
    assert test["p_one_sided"] == pytest.approx(1 / 128)
    # concordant seeds do not count; 3 wins and 1 loss: P(Bin(4, 1/2) >= 3) = 5/16
    test = paired_mcnemar(runs([1, 1, 1, 0, 1, 0]), runs([1, 0, 0, 1, 0, 0]))
    assert (test["better"], test["worse"], test["p_one_sided"]) == (3, 1, 5 / 16)
    # only the seeds both ran are paired; no discordant seed gives p = 1
    test = paired_mcnemar(runs([0, 0, 5]), runs([0, 0]))
    assert test["seeds"] == [0, 1] and test["p_one_sided"] == 1.0


# ---------------------------------------------------------------- robustness/: mutmut, kill -9 and resume
def test_mutation_testing_mutates_the_targets_only_and_counts_per_file(monkeypatch):
    """The mutmut table keeps every other package file out, and ``mutmut results`` lines
    are counted per source file (class methods and functions alike)."""
    import subprocess as sp

    import tomllib

    from benchmarks.robustness import mutation_testing

    table = tomllib.loads(
        mutation_testing.mutmut_config(
            ["torchrl_dual/a.py"], ["tests/x"], ["torchrl_dual/a.py", "torchrl_dual/b.py"]
        )
    )["tool"]["mutmut"]
    assert table["do_not_mutate"] == ["torchrl_dual/b.py"]
    assert table["pytest_add_cli_args_test_selection"] == ["tests/x"]
    out = "\n".join(
        [
            "    torchrl_dual.m.a.xǁCǁ__init____mutmut_1: killed",
            "    torchrl_dual.m.a.xǁCǁforward__mutmut_2: survived",
            "    torchrl_dual.m.a.x_helper__mutmut_1: killed",
            "    torchrl_dual.b.x_f__mutmut_1: no tests",
        ]
    )
    monkeypatch.setattr(sp, "run", lambda *a, **k: sp.CompletedProcess(a, 0, stdout=out))
    counts = mutation_testing.results(REPO, {})
    assert counts["torchrl_dual/m/a.py"] == {"killed": 2, "survived": 1}
    assert counts["torchrl_dual/b.py"] == {"no tests": 1}


def test_resume_kill_benchmark_kills_resumes_and_finds_the_runs_equal(tmp_path):
    """``python -m benchmarks.robustness.resume_kill`` on IQL / Frozen-Lake at a tiny
    budget: the run is SIGKILLed after its online evaluation at 100 frames, resumed, and
    ends bitwise as the uninterrupted run (issue 31; the contract test checks every
    algorithm in-process)."""
    out = tmp_path / "resume_kill.json"
    tiny = [
        "env=frozenlake",
        "budget.dataset_transitions=1000",
        "budget.network_width=16",
        "budget.offline_updates=4",
        "budget.online_frames=300",
        "budget.frames_per_batch=50",
        "budget.eval_every=100",
        "budget.eval_episodes=1",
        "budget.checkpoint_every=50",
    ]
    proc = run_module(
        "benchmarks.robustness.resume_kill",
        *("--algo", "iql", "--kill-after", "100", "--kill-delay", "0"),
        *("--out", str(tmp_path / "runs"), "--json", str(out), "--", *tiny),
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    result = json.loads(out.read_text())
    assert result["differences"] == [] and result["entries_compared"] > 100
    assert result["final_frames"] == [300, 300]
    assert 50 <= result["checkpoint_frames_at_kill"] < 300


def test_package_size_counts_code_docstrings_comments_and_blank_lines(tmp_path, capsys):
    from benchmarks.studies import package_size

    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "m.py").write_text(
        '"""Module\ndoc."""\n\nX = 1\n"""X\'s doc."""\n\n\n'
        'class A:\n    """One line."""\n\n    def f(self):  # code\n'
        '        # a comment\n        return "not a docstring"\n'
    )
    kinds = package_size.line_kinds(tmp_path)
    assert (kinds["docstring"], kinds["code"], kinds["comment"], kinds["blank"]) == (4, 4, 1, 4)
    assert kinds["total"] == 13
    package_size.main([str(tmp_path)])
    assert capsys.readouterr().out == "13 lines: 4 code, 4 docstring, 4 blank, 1 comment\n"
    (tmp_path / "n.py").write_text("Y = 2\n")  # a file and a folder holding another: summed
    assert package_size.line_kinds(tmp_path / "n.py", tmp_path / "sub")["code"] == 5
