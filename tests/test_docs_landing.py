"""The documentation site's landing page (``docs/index.md``) shows DUAL's update in a
TorchRL loop; its ``python`` block runs and trains."""

from __future__ import annotations

import re
from pathlib import Path

import torch

INDEX = Path(__file__).resolve().parents[1] / "docs" / "index.md"


def test_the_landing_page_snippet_runs_and_updates_both_parts():
    blocks = re.findall(r"^```python\n(.*?)^```$", INDEX.read_text(encoding="utf-8"), re.M | re.S)
    assert len(blocks) == 1, "docs/index.md should show one python snippet"
    torch.manual_seed(0)
    namespace: dict = {}
    exec(compile(blocks[0], str(INDEX), "exec"), namespace)
    loss, terms = namespace["loss"], namespace["terms"]
    assert {"loss_qvalue", "loss_value", "loss_actor"} <= set(terms.keys())
    assert all(torch.isfinite(terms[key]).all() for key in ("loss_qvalue", "loss_actor"))
    # the critic's steps moved it away from its target copy (which follows at tau = 0.005)
    q, target = loss.qvalue_network_params, loss.target_qvalue_network_params
    gap = max(
        (a - b).abs().max().item()
        for a, b in zip(q.values(True, True), target.values(True, True), strict=True)
    )
    assert 0 < gap
    assert namespace["stepper"].actor_optimizer.state, "the actor optimizer never stepped"
