"""The journal's 9-decimal rounding in Python floats gives numpy's bits (``np.round``, as the runner used)."""

import math

import numpy as np
import pytest

from rig.run.measuring.runner import _f


def reference(x: float) -> float:
    return float(np.round(float(x), 9)) + 0.0


@pytest.mark.filterwarnings("ignore:overflow encountered")  # 1.7e308 * 1e9, in numpy both ways
def test_rounding_matches_numpy_bit_for_bit() -> None:
    rng = np.random.default_rng(9)
    values = list(rng.uniform(-360, 360, 20000)) + list(rng.standard_normal(5000) * 1e-9)
    values += list(10.0 ** rng.uniform(-15, 300, 5000) * rng.choice([-1.0, 1.0], 5000))
    # exact halves at the 9th decimal (ties go to even) and their neighbours
    halves = [(k + 0.5) / 1e9 for k in range(-2000, 2000)]
    values += halves + [math.nextafter(h, math.inf) for h in halves] + [math.nextafter(h, -math.inf) for h in halves]
    values += [0.0, -0.0, -1e-12, 1e-10, 2.0**53, -(2.0**60), 1.7e308, -1.7e308, math.inf, -math.inf, math.nan]
    for v in values:
        assert repr(_f(v)) == repr(reference(v)), v
    assert repr(_f(np.float64(-0.0))) == "0.0" and _f(np.float32(0.1)) == reference(np.float32(0.1))


def reference_as_list(a: object) -> list[object]:
    return list(np.atleast_1d(a).tolist())


def test_reading_lists_are_atleast_1d_lists() -> None:
    from rig.run.measuring.runner import _as_list

    def typed(v: object) -> object:
        return [typed(x) for x in v] if isinstance(v, list) else (type(v).__name__, repr(v))

    values: list[object] = [
        np.float64(2.5).reshape(()), np.array(-0.0), np.array([1.0, np.nan, -np.inf]), np.array(5, np.int64),
        np.array([3, 0, 7], dtype=np.int64), np.array([], dtype=np.float64), np.arange(6.0).reshape(2, 3),
        np.array([True, False]), np.float32(0.1), 4.0, 3, [1.0, 2.0], (1, 2),
    ]  # fmt: skip
    for v in values:
        assert typed(_as_list(v)) == typed(reference_as_list(v)), v
