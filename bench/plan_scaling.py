"""How planning time grows with the number of points: 10^3 to 10^5 random directions on the four-axis rig.

Prints, per size, the wall time of ``plan_sweep`` (kinematics, ordering, swept-path checks, estimate) and its
ratio to n log n scaled from the smallest size (the anchor, measured in the same run): a ratio that stays
near 1 means the cost grows as n log n. ``--sizes`` changes the sizes.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from rig.instrument.geometry import RigGeometry
from rig.run.config.files import default_axes
from rig.run.planning.plan import plan_sweep


def directions(n: int, seed: int = 0) -> np.ndarray:
    """n random (theta_i, phi_i, theta_o, phi_o) rows in degrees above the horizon."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0, 80, n), rng.uniform(-180, 180, n), rng.uniform(0, 80, n),
                            rng.uniform(-180, 180, n)])  # fmt: skip


def main() -> None:
    """Run the scaling benchmark and print its table."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", default="1000,3000,10000,30000,100000")
    sizes = [int(s) for s in ap.parse_args().sizes.split(",")]
    geometry = RigGeometry()
    axes = default_axes(geometry)
    anchor = None
    print(f"{'points':>8} {'planned':>8} {'split':>6} {'seconds':>9} {'s / (n log n), rel.':>20}")
    for n in sizes:
        rows = directions(n)
        t0 = time.perf_counter()
        plan = plan_sweep(rows, geometry, axes)
        dt = time.perf_counter() - t0
        per = dt / (n * math.log(n))
        anchor = anchor or per
        print(f"{n:8d} {len(plan.points):8d} {plan.split_moves:6d} {dt:9.2f} {per / anchor:20.2f}")


if __name__ == "__main__":
    main()
