"""The figure of a camera calibration a person looks at: the photon transfer curve, linearity and darks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acquisition.photon_transfer import GAIN_RANGE, PhotonTransfer


def plot_photon_transfer(ptc: PhotonTransfer, path: str | Path, title: str = "") -> Path:
    """Variance against mean (log-log, the fitted shot-noise line), mean against exposure, darks; writes a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    names = sorted({p.plane for p in ptc.points})
    k = 1.0 / ptc.e_per_dn.value
    read_dn2 = (ptc.read_noise_e.value * k) ** 2
    for name in names:
        mine = [p for p in ptc.points if p.plane == name]
        mu = np.array([p.signal_dn for p in mine])
        ok = mu > 0
        axes[0].loglog(mu[ok], np.array([p.shot_variance_dn2 for p in mine])[ok], "o", ms=3, label=name)
        t = np.array([p.exposure_s for p in mine])
        axes[1].plot(t, mu, "o-", ms=3, lw=0.8, label=name)
    span = np.geomspace(max(1.0, 1e-3 * ptc.saturation_dn), ptc.saturation_dn, 50)
    axes[0].loglog(span, k * span, "k-", lw=1,
                   label=f"shot noise: {ptc.e_per_dn.value:.4g} ± {ptc.e_per_dn.std_error:.2g} e-/DN")  # fmt: skip
    axes[0].axhline(read_dn2, color="0.5", ls="--", lw=1,
                    label=f"read noise {ptc.read_noise_e.value:.3g} ± {ptc.read_noise_e.std_error:.2g} e-")  # fmt: skip
    axes[0].axvline(GAIN_RANGE * ptc.saturation_dn, color="tab:red", ls=":", lw=1, label="gain fit ends (70 %)")
    axes[0].axvline(ptc.saturation_dn, color="tab:red", lw=1, label=f"saturation {ptc.saturation_dn:.0f} DN")
    axes[0].set_xlabel("mean signal above dark (DN)")
    axes[0].set_ylabel("temporal variance above dark (DN²)")
    axes[0].set_title("photon transfer curve")
    axes[1].axhline(ptc.saturation_dn, color="tab:red", lw=1)
    axes[1].set_xlabel("exposure (s)")
    axes[1].set_ylabel("mean signal above dark (DN)")
    axes[1].set_title(f"linearity error {ptc.linearity_error_percent:.2f} %")
    times = sorted({p.exposure_s for p in ptc.points})
    dmean = [np.mean([p.dark_mean_dn for p in ptc.points if p.exposure_s == t]) for t in times]
    dvar = [np.mean([p.dark_variance_dn2 for p in ptc.points if p.exposure_s == t]) for t in times]
    axes[2].plot(times, dmean, "o", ms=3, color="tab:blue")
    axes[2].set_xlabel("exposure (s)")
    axes[2].set_ylabel("dark mean (DN)", color="tab:blue")
    twin = axes[2].twinx()
    twin.plot(times, dvar, "s", ms=3, color="tab:orange")
    twin.set_ylabel("dark temporal variance (DN²)", color="tab:orange")
    axes[2].set_title(f"darks: black {ptc.black_level_dn.value:.1f} DN, "
                      f"dark current {ptc.dark_current_e_per_s.value:.3g} e-/s")  # fmt: skip
    for ax in axes[:2]:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title or "camera calibration")
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
