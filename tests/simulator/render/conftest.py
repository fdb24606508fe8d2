"""Fixtures of the render tests: variants are chosen by the tests, whatever the calling shell exports."""

from __future__ import annotations

import pytest

from model.mitsuba import variant as mv


@pytest.fixture(autouse=True)
def _no_override(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests choose variants themselves, whatever the calling shell exports."""
    monkeypatch.delenv(mv.ENV_VAR, raising=False)
