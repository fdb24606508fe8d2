"""Move-time matrices and the open-path ordering behind ``rig.run.planning.plan`` (angles in degrees, times in seconds).

A path starts at a fixed node (the rig's start pose) and visits every point once; its end is free. The
free end is modelled as a fixed last node at zero cost from everywhere, so one local search serves both
the whole path and a window of it with both ends fixed. The search alternates 2-opt (reverse a stretch)
and Or-opt (move a run of 1-3 points elsewhere, either way round), evaluating every candidate move of a
round at once on the move-time matrix with numpy and applying the best non-overlapping improving moves.

Up to ``MATRIX_LIMIT`` points the matrix is held whole. Beyond, the greedy construction finds each next
point among the nearest candidates of a k-d tree (joint displacements over each axis's speed, the
Chebyshev metric: the time of a long move is its slowest axis's distance over its speed), rebuilt on the
unvisited points whenever half of its points have been visited, and the local search runs on overlapping
windows of ``WINDOW`` points: memory stays bounded and time grows as n log n (``bench/plan_scaling.py``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

MATRIX_LIMIT = 1000
WINDOW = 300
#: Improvements smaller than this (seconds) are rounding noise, not progress.
EPS_S = 1e-9
_CHUNK_ELEMENTS = 4_000_000


def trapezoid_time_s(distance: FloatArray | float, speed: FloatArray | float, accel: FloatArray | float) -> FloatArray:
    """Seconds for a rest-to-rest move over ``distance`` (>= 0) under speed and acceleration limits (same units).

    A triangle (2 sqrt(d / a)) when the move is too short to reach ``speed``, else d / v + v / a.
    """
    d, v, a = (np.asarray(x, dtype=np.float64) for x in (distance, speed, accel))
    # Overflow only happens for speeds so high that the move is a triangle, which inf <= inf still picks.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out: FloatArray = np.where(d * a <= v * v, 2.0 * np.sqrt(d / a), d / v + v / a)
    return out


def _times(d: FloatArray, speed: FloatArray, accel: FloatArray, coordinated: bool) -> FloatArray:
    """Move times (...) in seconds for absolute joint displacements ``d`` (..., k) in degrees."""
    if not coordinated:
        # One axis at a time keeps the temporaries at the size of the result (the matrix is the hot path).
        out: FloatArray = np.zeros(d.shape[:-1])
        for c in range(d.shape[-1]):
            np.maximum(out, trapezoid_time_s(d[..., c], speed[c], accel[c]), out=out)
        return out
    if d.shape[-1] == 0:
        return np.zeros(d.shape[:-1])
    # The path is measured along its longest joint, so every share is at most 1 and the limits cannot
    # overflow (over a unit path, a move of 1e-310 deg divided by it gave inf: "does not move", time 0).
    # A zero share gives no limit (inf); a path with every share zero does not move.
    length = np.max(d, axis=-1)
    still = length <= 0.0
    share = d / np.where(still, 1.0, length)[..., None]
    with np.errstate(divide="ignore"):
        v = np.min(speed / share, axis=-1)
        a = np.min(accel / share, axis=-1)
    t = trapezoid_time_s(np.where(still, 0.0, length), np.where(still, 1.0, v), np.where(still, 1.0, a))
    times: FloatArray = np.where(still, 0.0, t)
    return times


def step_times(src: FloatArray, dst: FloatArray, speed: FloatArray, accel: FloatArray, coordinated: bool) -> FloatArray:
    """Move times (n,) in seconds from each joint row of ``src`` (n, k) to the same row of ``dst``, degrees.

    Independent axes: the slowest axis's trapezoid. Coordinated: one trapezoid over the unit path, whose
    speed and acceleration are the tightest axis limits divided by that axis's share of the move.
    """
    return _times(np.abs(dst - src), speed, accel, coordinated)


def pairwise_times(
    src: FloatArray, dst: FloatArray, speed: FloatArray, accel: FloatArray, coordinated: bool
) -> FloatArray:
    """Move times (n, m) in seconds between every joint row of ``src`` (n, k) and of ``dst`` (m, k), degrees."""
    n, m, k = len(src), len(dst), src.shape[1]
    out = np.zeros((n, m), dtype=np.float64)
    rows = max(1, _CHUNK_ELEMENTS // max(m * k, 1))
    for r0 in range(0, n, rows):
        d = np.abs(src[r0 : r0 + rows, None, :] - dst[None, :, :])
        out[r0 : r0 + rows] = _times(d, speed, accel, coordinated)
    return out


def path_cost(d: FloatArray, path: IntArray) -> float:
    """Sum of the matrix entries along consecutive nodes of ``path``."""
    return float(d[path[:-1], path[1:]].sum())


def _accept(candidates: list[tuple[float, int, int, int, int]], m: int) -> list[tuple[int, int]]:
    """Best-first, the (i, j) of improving moves whose closed position ranges [lo, hi] do not overlap."""
    taken = np.zeros(m, dtype=bool)
    chosen = []
    for _, lo, hi, i, j in sorted(candidates):
        if not taken[lo : hi + 1].any():
            taken[lo : hi + 1] = True
            chosen.append((i, j))
    return chosen


@functools.lru_cache(maxsize=4)
def _lower(size: int) -> npt.NDArray[np.bool_]:
    """Mask of the lower triangle, diagonal included, of a (size, size) matrix (cached: sizes repeat)."""
    mask: npt.NDArray[np.bool_] = np.tri(size, dtype=bool)
    return mask


def _two_opt(d: FloatArray, p: IntArray) -> bool:
    """One round of 2-opt on path ``p`` (ends fixed), in place; whether anything improved."""
    m = len(p)
    if m < 4:
        return False
    q = d[np.ix_(p, p)]
    e = q[np.arange(m - 1), np.arange(1, m)]
    # delta[i-1, j-1] for reversing p[i..j], 1 <= i < j <= m-2: the two edges swapped, the stretch unchanged.
    delta = q[:-2, 1:-1] + q[1:-1, 2:] - e[:-1, None] - e[None, 1:]
    delta[_lower(m - 2)] = np.inf
    best = np.argmin(delta, axis=1)
    gain = delta[np.arange(m - 2), best]
    cands = [
        (float(gain[r]), r, int(best[r]) + 2, r + 1, int(best[r]) + 1) for r in map(int, np.flatnonzero(gain < -EPS_S))
    ]
    moves = _accept(cands, m)
    for i, j in moves:
        p[i : j + 1] = p[i : j + 1][::-1].copy()
    return bool(moves)


def _or_opt(d: FloatArray, p: IntArray, length: int) -> bool:
    """One round of Or-opt moving runs of ``length`` points of ``p`` (ends fixed), in place."""
    m = len(p)
    if m < length + 3:
        return False
    q = d[np.ix_(p, p)]
    e = q[np.arange(m - 1), np.arange(1, m)]
    i = np.arange(1, m - length)  # run p[i .. i+length-1], never an end node
    first, last = i, i + length - 1
    removed = q[i - 1, first] + q[last, i + length] - q[i - 1, i + length]
    j = np.arange(m - 1)  # insert between p[j] and p[j+1]
    # The matrix is symmetric, so q[p_j, run] is a row slice: no gathers for the (runs x edges) tables.
    fwd = q[1 : m - length, :-1] + q[length : m - 1, 1:]
    rev = q[length : m - 1, :-1] + q[1 : m - length, 1:]
    delta = np.minimum(fwd, rev) - e[None, :] - removed[:, None]
    delta[(j[None, :] >= (i - 1)[:, None]) & (j[None, :] <= last[:, None])] = np.inf
    best = np.argmin(delta, axis=1)
    gain = delta[np.arange(len(i)), best]
    cands = []
    for r in np.flatnonzero(gain < -EPS_S):
        s, t = int(i[r]), int(best[r])
        lo, hi = (t, s + length) if t < s else (s - 1, t + 1)
        cands.append((float(gain[r]), lo, hi, s, t))
    moves = _accept(cands, m)
    for s, t in moves:
        run = p[s : s + length].copy()
        if rev[s - 1, t] < fwd[s - 1, t]:
            run = run[::-1]
        if t < s:
            p[t + 1 : s + length] = np.concatenate([run, p[t + 1 : s]])
        else:
            p[s : t + 1] = np.concatenate([p[s + length : t + 1], run])
    return bool(moves)


def improve(d: FloatArray, path: IntArray, max_rounds: int = 100_000) -> IntArray:
    """Local search (2-opt, then Or-opt 1-3) on an open path whose first and last nodes stay; returns a copy."""
    p = np.array(path, dtype=np.intp)
    for _ in range(max_rounds):
        if _two_opt(d, p):
            continue
        if not any(_or_opt(d, p, length) for length in (1, 2, 3)):
            break
    return p


def _greedy(cost_row: Callable[[int], FloatArray], n: int) -> IntArray:
    """Nearest-neighbour order of nodes 1..n from node 0; ``cost_row(node)`` gives times to nodes 1..n."""
    visited = np.zeros(n, dtype=bool)
    order = np.empty(n, dtype=np.intp)
    here = 0
    for step in range(n):
        nxt = int(np.argmin(np.where(visited, np.inf, cost_row(here))))
        visited[nxt] = True
        order[step] = here = nxt + 1
    return order


def _windowed(nodes: FloatArray, order: IntArray, speed: FloatArray, accel: FloatArray, coordinated: bool) -> IntArray:
    """``improve`` applied to overlapping windows of a long order of node ids 1..n (node 0 = start)."""
    p = np.concatenate([[0], order]).astype(np.intp)
    n = len(order)
    for s in range(1, n + 1, WINDOW // 2):
        e = min(s + WINDOW, n + 1)  # window p[s:e]; p[s-1] and p[e] (or the free end) stay
        ids = p[s - 1 : e + 1]
        local = pairwise_times(nodes[ids], nodes[ids], speed, accel, coordinated)
        if e > n:  # free end: a dummy node at zero cost
            local = np.pad(local, ((0, 1), (0, 1)))
        better = improve(local, np.arange(len(local)))
        p[s:e] = ids[better[1 : 1 + (e - s)]]
    return p[1:]


def _greedy_tree(nodes: FloatArray, speed: FloatArray, accel: FloatArray, coordinated: bool) -> IntArray:
    """Nearest-neighbour order of nodes 1..n from node 0 with candidates from a k-d tree (see the module doc)."""
    from scipy.spatial import cKDTree

    n = len(nodes) - 1
    scaled = nodes / speed[None, :]
    visited = np.zeros(n + 1, dtype=bool)
    visited[0] = True
    order = np.empty(n, dtype=np.intp)
    remaining = np.arange(1, n + 1)
    tree = cKDTree(scaled[remaining])
    stale = 0
    here = 0
    for step in range(n):
        k = 8
        while True:
            kk = min(k, len(remaining))
            _, idx = tree.query(scaled[here], k=kk, p=np.inf)
            cand = remaining[np.atleast_1d(idx)]
            cand = cand[~visited[cand]]
            if len(cand) or kk == len(remaining):
                break
            k *= 4
        # The exact move times decide among the tree's candidates.
        times = pairwise_times(nodes[here : here + 1], nodes[cand], speed, accel, coordinated)[0]
        nxt = int(cand[int(np.argmin(times))])
        visited[nxt] = True
        order[step] = here = nxt
        stale += 1
        if stale * 2 >= len(remaining) and step + 1 < n:
            remaining = remaining[~visited[remaining]]
            tree = cKDTree(scaled[remaining])
            stale = 0
    return order


def order_path(
    points: FloatArray, start: FloatArray, speed: FloatArray, accel: FloatArray, coordinated: bool
) -> IntArray:
    """Indices into ``points`` (n, k joint degrees) for a short total move time from ``start`` (k,)."""
    n = len(points)
    if n <= 1:
        return np.arange(n, dtype=np.intp)
    nodes = np.vstack([start[None, :], points])
    whole = (
        np.pad(pairwise_times(nodes, nodes, speed, accel, coordinated), ((0, 1), (0, 1))) if n <= MATRIX_LIMIT else None
    )

    def row(k: int) -> FloatArray:
        if whole is not None:
            return whole[k, 1 : n + 1]
        return pairwise_times(nodes[k : k + 1], nodes[1:], speed, accel, coordinated)[0]

    def search(order: IntArray) -> IntArray:
        # Windows first: cheap, and they leave the whole-matrix rounds only the long-range moves.
        order = _windowed(nodes, order, speed, accel, coordinated)
        if whole is not None:
            order = improve(whole, np.concatenate([[0], order, [n + 1]]))[1:-1]
        return order

    def cost(order: IntArray) -> float:
        path = np.concatenate([[0], order])
        return float(step_times(nodes[path[:-1]], nodes[path[1:]], speed, accel, coordinated).sum())

    best = search(_greedy(row, n) if whole is not None else _greedy_tree(nodes, speed, accel, coordinated))
    identity = np.arange(1, n + 1, dtype=np.intp)
    # Local search from the greedy tour can end worse than the sweep's own order; then try that too.
    if cost(best) > cost(identity):
        alt = search(identity)
        best = alt if cost(alt) < cost(best) else best
    out: IntArray = best - 1
    return out
