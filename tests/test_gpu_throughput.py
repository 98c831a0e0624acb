"""``benchmarks/speed/gpu_throughput.py`` at tiny sizes on the CPU: every figure measured, the
JSON written, the projection built from the rates, and merged reports."""

from __future__ import annotations

import json
import math

import pytest

from benchmarks.speed import gpu_throughput


def test_a_tiny_eager_run_writes_every_figure_and_the_paper_projection(tmp_path):
    out = tmp_path / "gpu.json"
    gpu_throughput.main(["--device", "cpu", "--tiny", "--modes", "eager", "--json", str(out)])
    report = json.loads(out.read_text())
    for name in (*gpu_throughput.UPDATES, *gpu_throughput.ACTING):
        assert report["results"][name]["eager"]["per_second"] > 0, name
        assert report["best_modes"][name] == "eager"
    hours = report["paper_hours"]
    rate = report["results"]["actor_critic"]["eager"]["per_second"]
    assert hours["actor_critic"] == pytest.approx(1_000_000 / rate / 3600)
    # budget=paper's DUAL: CORL's one update per env step, 1M online as 1M offline updates
    assert hours["online_updates"] == pytest.approx(hours["actor_critic"])
    assert report["provenance"]["host"] and report["provenance"]["commit"] != "?"
    parts = sum(v for k, v in hours.items() if k != "total")
    assert math.isclose(hours["total"], parts)


def test_figures_from_several_runs_merge_into_one_projection(tmp_path):
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    common = ["--device", "cpu", "--tiny", "--modes", "eager"]
    gpu_throughput.main([*common, "--only", "planner", "act_b1", "--json", str(first)])
    assert json.loads(first.read_text())["paper_hours"] is None  # incomplete
    gpu_throughput.main(
        [*common, "--only", "distillation", "actor_critic", "act_b64", "laplace",
         "--json", str(second)]
    )  # fmt: skip
    merged = gpu_throughput.main(["--merge", str(first), str(second)])
    assert merged["paper_hours"]["total"] > 0
    assert set(merged["best_modes"]) == {*gpu_throughput.UPDATES, *gpu_throughput.ACTING}


def test_a_mode_that_cannot_run_is_reported_not_raised():
    results = gpu_throughput.measure_all(
        gpu_throughput.TINY, "cpu", ("cudagraphs",), steps=1, warmup=0, only=("planner",)
    )
    assert "needs a CUDA device" in results["planner"]["cudagraphs"]["error"]
    assert gpu_throughput.best(results, "planner") == (
        None,
        pytest.approx(float("nan"), nan_ok=True),
    )


def test_the_compile_mode_reaches_torch_compile_and_the_report(tmp_path, monkeypatch):
    modes = []

    def recording_compile(fn, mode=None):
        modes.append(mode)
        return fn

    monkeypatch.setattr(gpu_throughput.torch, "compile", recording_compile)
    out = tmp_path / "gpu.json"
    gpu_throughput.main(
        ["--device", "cpu", "--tiny", "--modes", "compile", "--only", "planner", "act_b1",
         "--compile-mode", "max-autotune-no-cudagraphs", "--json", str(out)]
    )  # fmt: skip
    assert modes == ["max-autotune-no-cudagraphs"] * 2
    assert json.loads(out.read_text())["compile_mode"] == "max-autotune-no-cudagraphs"
