"""clm_core.environ: variables set for a while are put back as they were, set or unset."""

from __future__ import annotations

import os

import pytest

from clm_core import environ


def test_environment_puts_back_values_and_absence(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CLM_T_SET", "before")
    monkeypatch.delenv("CLM_T_UNSET", raising=False)
    with pytest.raises(RuntimeError), environ.environment({"CLM_T_SET": "inside", "CLM_T_UNSET": "inside"}):
        assert os.environ["CLM_T_SET"] == os.environ["CLM_T_UNSET"] == "inside"
        raise RuntimeError("the block fails: the environment is put back all the same")
    assert os.environ["CLM_T_SET"] == "before" and "CLM_T_UNSET" not in os.environ


def test_save_restore_after_someone_else_wrote(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CLM_T_A", "1")
    monkeypatch.delenv("CLM_T_B", raising=False)
    saved = environ.save(["CLM_T_A", "CLM_T_B"])
    assert saved == {"CLM_T_A": "1", "CLM_T_B": None}
    os.environ.update(CLM_T_A="2", CLM_T_B="3")  # what a dask nanny does before it spawns a worker
    environ.restore(saved)
    assert os.environ["CLM_T_A"] == "1" and "CLM_T_B" not in os.environ
