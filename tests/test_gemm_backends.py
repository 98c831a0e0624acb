"""``benchmarks/speed/gemm_backends.py``: MKL's log is read into shapes and times, and the two
GEMM backends are compared on the same products (no timing is asserted)."""

from __future__ import annotations

import json

import pytest
import torch
from recipe_runner import run_module

from benchmarks.speed import gemm_backends

LOG = """\
MKL_VERBOSE oneMKL 2024.0 Update 2 Product build 20240605 for Intel(R) 64 architecture
MKL_VERBOSE SGEMM(N,N,256,256,256,0x1,0x2,256,0x3,256,0x4,0x5,256) 900.00us CNR:OFF Dyn:0
GEMM_TRACE_BEGIN
MKL_VERBOSE SGEMM(N,N,256,256,256,0x1,0x2,256,0x3,256,0x4,0x5,256) 400.00us CNR:OFF Dyn:0
MKL_VERBOSE SGEMM(T,N,256,256,6,0x1,0x2,6,0x3,6,0x4,0x5,256) 20.00us CNR:OFF Dyn:0
MKL_VERBOSE SGEMM(N,N,256,256,256,0x1,0x2,256,0x3,256,0x4,0x5,256) 1.20ms CNR:OFF Dyn:0
MKL_VERBOSE SGEMM_BATCH(T,N,0x1,0x2,0x3,0x4,0x5,0x6,0x7,0x8,0x9,0xa,0xb,0xc,0xd) 0.5ms CNR:OFF
MKL_VERBOSE SSYRK(U,N,4,4,0x1,0x2,4,0x3,0x4,4) 3.00us CNR:OFF Dyn:0
GEMM_TRACE_END 10.0
MKL_VERBOSE SGEMM(N,N,256,256,256,0x1,0x2,256,0x3,256,0x4,0x5,256) 900.00us CNR:OFF Dyn:0
"""


def test_trace_counts_only_the_gemms_between_the_markers_per_update():
    traced = gemm_backends.parse_trace(LOG.splitlines(), updates=2)
    assert traced["ms_per_update"] == 10.0
    assert traced["gemm_calls_per_update"] == 2.0  # 4 GEMMs (not SSYRK) over 2 updates
    assert traced["gemm_ms_by_shape"] == pytest.approx(
        {"NN 256x256x256": 0.8, "batched": 0.25, "TN 256x256x6": 0.01}
    )
    assert list(traced["gemm_ms_by_shape"]) == ["NN 256x256x256", "batched", "TN 256x256x6"]
    assert traced["mkl_header"].startswith("oneMKL 2024.0")


def test_operands_compute_the_logged_product_shape():
    x, w = gemm_backends.shape_operands("TN 144x256x32")  # m=144, n=256, k=32
    assert (x @ w.T).shape == (256, 144)


@pytest.mark.skipif(
    not (torch.backends.mkl.is_available() and torch.backends.mkldnn.is_available()),
    reason="needs PyTorch with MKL and oneDNN",
)
def test_backends_agree_before_they_are_timed():
    out = gemm_backends.compare_backends(["NN 16x8x4", "batched"], rounds=1, reps=2)
    for row in out.values():
        assert row["max_relative_difference"] < 1e-5
        assert row["ratio"] == pytest.approx(row["mkl_us"] / row["onednn_us"])


@pytest.mark.skipif(not torch.backends.mkl.is_available(), reason="MKL_VERBOSE needs MKL")
def test_script_traces_a_recipe_update_and_writes_json(tmp_path):
    out = tmp_path / "gemm.json"
    args = (
        "--algo",
        "iql",
        "--updates",
        "2",
        "--rounds",
        "1",
        "--reps",
        "1",
        "--update-rounds",
        "1",
    )
    proc = run_module("benchmarks.speed.gemm_backends", *args, "--json", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(out.read_text())
    assert result["gemm_calls_per_update"] > 0
    assert 0 < sum(result["gemm_ms_by_shape"].values()) < result["ms_per_update"]
    assert "projected update" in proc.stdout
    assert 0 < result["floor_ms_per_update"] and len(result["floor_ms_per_update_rounds"]) == 1
