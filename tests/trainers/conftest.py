"""Keeps TorchRL's ConfigStore entries out of the rest of the test session.

``register_configs()`` stores TorchRL's groups (``logger/csv``, ``env/...``, ...) in
Hydra's process-wide ``ConfigStore``; Hydra then validates the recipe's own
``logger/csv.yaml`` against TorchRL's schema of the same name and composing the recipe
fails ("Error merging 'logger/csv' with schema"). Each test here gets the store back as
it found it (less the groups a test added; Hydra's own ``hydra`` entries, stored once per
process, are kept), so a pytest worker that runs the recipe's tests afterwards is
unaffected.
"""

import pytest
from hydra.core.config_store import ConfigStore


@pytest.fixture(autouse=True)
def _restore_config_store():
    store = ConfigStore.instance()
    before = set(store.repo)
    yield
    for key in set(store.repo) - before - {"hydra"}:
        del store.repo[key]
