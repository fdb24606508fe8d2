"""The manual reference target: the operator is asked, by reading, to place and remove the tile."""

from __future__ import annotations

from rig.run.backends.reference import ManualReference, ReferenceTarget


def test_the_operator_is_asked_for_each_reading_and_for_the_sample_back() -> None:
    asked: list[str] = []

    def ask(prompt: str) -> str:
        asked.append(prompt)
        return ""

    ref = ManualReference(ask=ask)
    assert isinstance(ref, ReferenceTarget)
    ref.present(25)
    ref.withdraw()
    assert "before point 25" in asked[0] and "reference tile" in asked[0]
    assert "sample back" in asked[1] and len(asked) == 2
