"""The numpy pass of the HDR merge (small images) gives the compiled pass's bits, on random brackets."""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np
import pytest

import acquisition.hdr.prepared as prepared_module
import acquisition.hdr.saturation as saturation_module
from acquisition.frame import Frame
from acquisition.hdr.kernel import _top_counts, run_compiled
from acquisition.hdr.merge import BELOW_BLACK_SIGMA, HdrImage, merge_linear
from acquisition.hdr.prepared import _Prepared
from acquisition.hdr.small import run_small, top_counts
from acquisition.noise import SensorNoise

NOISE = SensorNoise()  # black 512, 14-bit, full well 15000 DN


def bracket(rng: np.random.Generator, shape: tuple[int, ...], n_frames: int, dtype: Any) -> list[Frame]:
    """Random frames from black to clipped: dark pixels, saturated ones, some saturated in every frame."""
    scene = np.exp(rng.uniform(np.log(1.0), np.log(5e6), shape))
    scene.flat[rng.choice(scene.size, max(1, scene.size // 10), replace=False)] = 1e9  # clipped everywhere
    scene.flat[rng.choice(scene.size, max(1, scene.size // 10), replace=False)] = 0.0  # no light at all
    frames = []
    for k in range(n_frames):
        t = 0.001 * 4.0 ** rng.uniform(0, 5) if k else 0.001
        counts = NOISE.black_level_dn + scene * t + rng.normal(0.0, 3.0, shape)
        data = np.clip(np.round(counts), 0, 15871).astype(dtype)
        frames.append(Frame(data, "linear", t, gain=float(rng.choice([1.0, 2.0])), black_level=NOISE.black_level_dn,
                            white_level=15871))  # fmt: skip
    return frames


def darks_for(rng: np.random.Generator, frames: list[Frame], kind: str) -> dict[float, Any] | None:
    """No darks, one uint16 dark frame per exposure, two averaged, or float master darks with NaN pixels."""
    if kind == "none":
        return None
    shape = frames[0].shape
    out: dict[float, Any] = {}
    for f in frames:
        def dark(f: Frame = f) -> Frame:
            data = np.round(NOISE.black_level_dn + rng.normal(0.0, 3.0, shape)).astype(np.uint16)
            return Frame(data, "linear", f.exposure_s, gain=f.gain, black_level=NOISE.black_level_dn, white_level=15871)

        if kind == "frame":
            out[f.exposure_s] = [dark()]
        elif kind == "two":
            out[f.exposure_s] = [dark(), dark()]
        elif kind == "level":
            out[f.exposure_s] = float(NOISE.black_level_dn + rng.normal(0.0, 1.0))
        else:
            master = NOISE.black_level_dn + rng.normal(0.0, 2.0, shape).astype(np.float32)
            master.flat[rng.choice(master.size, 2, replace=False)] = np.nan
            out[f.exposure_s] = master
    return out


def merged(frames: list[Frame], darks: dict[float, Any] | None, weighting: str, compiled: bool,
           monkeypatch: pytest.MonkeyPatch) -> HdrImage:  # fmt: skip
    """merge_linear through the compiled pass (every image counts as large) or the numpy pass (as small)."""
    with monkeypatch.context() as m:
        limit = 0 if compiled else 1 << 30
        m.setattr(prepared_module, "NUMPY_BELOW", limit)
        m.setattr(saturation_module, "NUMPY_BELOW", limit)
        return merge_linear(frames, NOISE, darks=darks, weighting=weighting)  # type: ignore[arg-type]


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("weighting", ["auto", "sum", "inverse_variance"])
@pytest.mark.parametrize("darks", ["none", "frame", "two", "level", "master"])
@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_the_numpy_pass_merges_to_the_compiled_passes_bits(
    weighting: str, darks: str, dtype: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = np.random.default_rng(zlib.crc32(f"{weighting} {darks} {np.dtype(dtype).str}".encode()))
    kinds = set()
    for trial in range(6):
        shape = ((7, 5, 3), (16, 16), (3, 9, 3), (1, 1, 3), (12, 12, 3), (2, 2))[trial]
        # One frame (its own path), two, and up to nine (past the compiled pass's padding of eight).
        frames = bracket(rng, shape, (1, 2, 1, int(rng.integers(3, 10)), 9, 1)[trial], dtype)
        dk = darks_for(rng, frames, darks)
        fast = merged(frames, dk, weighting, False, monkeypatch)
        slow = merged(frames, dk, weighting, True, monkeypatch)
        for name in ("radiance", "variance", "flags", "frames_used"):
            assert same_bits(getattr(fast, name), getattr(slow, name)), (trial, name)
        assert fast.metadata == slow.metadata
        kinds |= set(np.unique(fast.flags).tolist())
    assert {0, 1, 2} <= kinds  # unflagged, saturated in every frame, dark


def test_a_mixed_weighting_decision_is_the_same_on_both_passes(monkeypatch: pytest.MonkeyPatch) -> None:
    # High read noise and a dim scene: the auto weighting picks the inverse-variance pass on both.
    noise = SensorNoise(read_noise_e=40.0)
    rng = np.random.default_rng(3)
    scene = np.exp(rng.uniform(np.log(20.0), np.log(2e4), (12, 12, 3)))
    frames = [Frame(np.clip(np.round(noise.black_level_dn + scene * t + rng.normal(0, 10, scene.shape)), 0, 15871)
                    .astype(np.uint16), "linear", t, black_level=noise.black_level_dn, white_level=15871)
              for t in (0.001, 0.004, 0.016, 0.064)]  # fmt: skip
    images = []
    for compiled in (False, True):
        with monkeypatch.context() as m:
            m.setattr(prepared_module, "NUMPY_BELOW", 0 if compiled else 1 << 30)
            images.append(merge_linear(frames, noise))
    assert images[0].metadata["weighting"] == "inverse_variance"
    assert images[0].metadata == images[1].metadata
    assert same_bits(images[0].radiance, images[1].radiance) and same_bits(images[0].variance, images[1].variance)


@pytest.mark.parametrize("with_maps", [False, True])
def test_the_inverse_variance_pass_weighted_by_any_signal_gives_the_same_bits(with_maps: bool) -> None:
    # Signals the merge never passes too: negative, zero, NaN and huge weights' levels.
    rng = np.random.default_rng(7 + with_maps)
    n, k = 500, 5
    data = tuple(rng.integers(400, 16000, n).astype(np.uint16) for _ in range(k))
    maps = tuple(rng.normal(512, 3, n).astype(np.float32) for _ in range(k)) if with_maps else None
    expo = rng.uniform(0.001, 0.3, k)
    prep = _Prepared(data=data, offmaps=maps, off_s=rng.normal(512, 1, k), thr_raw=rng.uniform(8000, 16500, k),
                     expo=expo, shot=expo / 4.0, cvar=rng.uniform(0.5, 3.0, k), shortest=int(np.argmin(expo)),
                     longest=int(np.argmax(expo)), dark_thr=4.0)  # fmt: skip
    signal = rng.normal(0.0, 1e5, n)
    signal[:20] = [np.nan, 0.0, -0.0, 1e300, -1e300] * 4
    for iv, sig in ((False, None), (True, signal), (True, None)):
        small = run_small(prep, iv, sig if sig is not None or not iv else prep.run(False)[0].astype(np.float64))
        compiled = run_compiled(prep, iv, sig if sig is not None or not iv else prep.run(False)[0].astype(np.float64))
        for a, b in zip(small, compiled, strict=True):
            assert same_bits(a, b)


def test_the_plateau_count_gives_the_compiled_counts_and_sums() -> None:
    rng = np.random.default_rng(11)
    for _ in range(20):
        ints = rng.integers(0, 16384, int(rng.integers(1, 3000))).astype(np.uint16)
        ints[: ints.size // 3] = ints.max()
        lo, mid = int(rng.integers(0, 16384)), int(rng.integers(0, 16384))
        assert top_counts(ints, lo, mid) == _top_counts(ints, lo, mid)
        floats = (rng.normal(1e4, 3e3, int(rng.integers(1, 3000)))).astype(np.float32)
        floats[::7] = np.nan
        flo, fmid = float(rng.uniform(0, 1e4)), float(rng.uniform(0, 2e4))
        got, want = top_counts(floats, flo, fmid), _top_counts(floats, flo, fmid)
        assert got[:2] == want[:2] and np.float64(got[2]).tobytes() == np.float64(want[2]).tobytes()


def test_below_black_is_flagged_beside_nan_pixels() -> None:
    # Frames below their black level in one corner, a master dark with NaN pixels: every pixel more than
    # BELOW_BLACK_SIGMA standard errors below zero is flagged, whatever the NaN radiances beside it.
    rng = np.random.default_rng(5)
    shape = (6, 6, 3)
    frames = []
    for t in (0.01, 0.04):
        data = NOISE.black_level_dn + 2e4 * t + rng.normal(0.0, 3.0, shape)
        data[:2, :2] = NOISE.black_level_dn - 40.0
        frames.append(Frame(np.round(data).astype(np.uint16), "linear", t, black_level=NOISE.black_level_dn,
                            white_level=15871))  # fmt: skip
    master = np.full(shape, float(NOISE.black_level_dn), np.float32)
    master[3, 3] = np.nan
    img = merge_linear(frames, NOISE, darks={0.01: master, 0.04: master})
    assert np.isnan(img.radiance).any()
    with np.errstate(invalid="ignore"):
        expected = (img.radiance < -BELOW_BLACK_SIGMA * np.sqrt(img.variance)) & (img.flags & 1 == 0)
    assert expected[:2, :2].all() and np.array_equal(img.below_black, expected)


@pytest.mark.parametrize("darks", ["none", "level"])
def test_a_raw_mosaic_with_a_black_level_per_site_merges_to_the_same_bits(
    darks: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Per-site black levels become per-pixel float32 offset maps: the map path of both passes, and (with
    # mean dark levels for some frames only) a frame reading the shared zero map beside frames with maps.
    rng = np.random.default_rng(9)
    blacks = (500.0, 512.0, 520.0, 530.0)
    frames = []
    for k, t in enumerate((0.001, 0.004, 0.016)):
        data = np.round(512.0 + rng.uniform(0, 2e6, (10, 12)) * t + rng.normal(0.0, 3.0, (10, 12)))
        frames.append(Frame(np.clip(data, 0, 15871).astype(np.uint16), "raw", t, cfa_pattern="RGGB",
                            black_level=blacks if k != 1 else 512.0, white_level=15871))  # fmt: skip
    dk = None if darks == "none" else {0.004: 511.5, 0.001: 512.0, 0.016: 512.5}
    for weighting in ("auto", "sum", "inverse_variance"):
        fast = merged(frames, dk, weighting, False, monkeypatch)
        slow = merged(frames, dk, weighting, True, monkeypatch)
        for name in ("radiance", "variance", "flags", "frames_used"):
            assert same_bits(getattr(fast, name), getattr(slow, name)), (weighting, name)
        assert fast.metadata == slow.metadata
