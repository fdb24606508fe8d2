"""No test depends on the machine's speed: Hypothesis runs without a per-example deadline in every profile."""

from hypothesis import settings


def test_hypothesis_has_no_deadline_in_the_loaded_profile() -> None:
    assert settings().deadline is None


def test_hypothesis_has_no_deadline_in_any_registered_profile() -> None:
    for name in ("default", "ci"):
        assert settings.get_profile(name).deadline is None, name
