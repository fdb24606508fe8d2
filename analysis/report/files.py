"""What the report's figures hand back, without matplotlib: the written files, the slices and the coverage.

Apart from the modules that draw, so that the process that writes the page (and unpickles these from the
process that drew them) never loads matplotlib, one of ``gonio analyze``'s costliest imports.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.intp]
#: Coverage grid cells (degrees) in theta_h, theta_d and phi_d.
CELL_THETA_DEG, CELL_PHI_D_DEG = 10.0, 20.0


@dataclass(frozen=True)
class FigureFile:
    """A written figure: its PNG, its SVG (or None) and a one-line caption."""

    name: str
    png: Path
    svg: Path | None
    caption: str


@dataclass(frozen=True)
class Slice:
    """The samples (indices) in the plane of incidence at ``theta_i_deg`` +- ``tol_deg``."""

    theta_i_deg: float
    tol_deg: float
    index: IntArray


@dataclass(frozen=True)
class Coverage:
    """Occupied cells of coarse grids over (theta_h, theta_d) and (theta_h, phi_d), with the cell sizes (deg)."""

    occupied_hd: npt.NDArray[np.bool_]
    occupied_hp: npt.NDArray[np.bool_]
    cell_theta_deg: float = CELL_THETA_DEG
    cell_phi_d_deg: float = CELL_PHI_D_DEG

    @property
    def fraction_hd(self) -> float:
        """Fraction of (theta_h, theta_d) cells holding at least one sample."""
        return float(self.occupied_hd.mean())

    @property
    def fraction_hp(self) -> float:
        """Fraction of (theta_h, phi_d) cells holding at least one sample."""
        return float(self.occupied_hp.mean())

    def text(self) -> str:
        """One sentence for the report."""
        c, p = self.cell_theta_deg, self.cell_phi_d_deg
        hd, hp = self.occupied_hd, self.occupied_hp
        return (f"{int(hd.sum())} of {hd.size} (theta_h, theta_d) cells of {c:g}° x {c:g}° hold a sample "
                f"({self.fraction_hd:.0%}); {int(hp.sum())} of {hp.size} (theta_h, phi_d) cells of {c:g}° x {p:g}° "
                f"({self.fraction_hp:.0%}).")  # fmt: skip


@dataclass(frozen=True)
class Figures:
    """Every figure of the report, the slices they drew and the coverage numbers."""

    files: tuple[FigureFile, ...]
    slices: tuple[Slice, ...]
    coverage: Coverage
