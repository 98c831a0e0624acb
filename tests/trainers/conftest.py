"""Keeps TorchRL's ConfigStore entries out of the rest of the test session.

``register_configs()`` stores TorchRL's groups (``logger/csv``, ``env/...``, ...) in
Hydra's process-wide ``ConfigStore``; Hydra then validates the recipe's own
``logger/csv.yaml`` against TorchRL's schema of the same name and composing the recipe
fails ("Error merging 'logger/csv' with schema"). Each test here gets the store back as
it found it, so a pytest worker that runs the recipe's tests afterwards is unaffected.
"""

import copy

import pytest
from hydra.core.config_store import ConfigStore


@pytest.fixture(autouse=True)
def _restore_config_store():
    store = ConfigStore.instance()
    saved = copy.deepcopy(store.repo)
    yield
    store.repo = saved
