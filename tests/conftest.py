"""Fixtures shared by test modules."""

from __future__ import annotations

import pytest
from pointclm.training.realistic import SceneBank


@pytest.fixture(scope="module")
def bank(tmp_path_factory: pytest.TempPathFactory) -> SceneBank:
    """A saved and reloaded scene bank of two bunny scenes ("bunny" is the packaged model: no
    data folder needed)."""
    built = SceneBank.build(["bunny"], 2, seed=0, workers=1)
    path = tmp_path_factory.mktemp("bank") / "bank.npz"
    built.save(path)
    return SceneBank.load(path)
