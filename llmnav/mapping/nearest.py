"""Exact nearest set cells within a reach, dilation and 8-connected labelling, in numpy alone.

The planners ask three things of a grid at every decision: which cells lie within a radius of a set
cell (inflation), the nearest set cell to each cell near one (a frontier's goal band), and the clusters
of set cells. SciPy's `ndimage` answers them, but importing it costs about 0.3 s, most of a drive's
start, and every answer here is needed only out to a small reach. So:

- `nearest_within` is a two-pass Euclidean transform (the separable scheme of Saito and Toriwaki,
  "New algorithms for Euclidean distance transformation of an n-dimensional digitized picture", 1994),
  cut at `reach` cells: the nearest set cell of each column, then the best column within the reach.
  Squared distances are integers, so the answer is exact; equally near cells resolve to the lowest
  column, then the lowest row (what `scipy.ndimage.distance_transform_edt` returns, checked in tests).
- `label8` numbers 8-connected components in raster order of their first cell, as `scipy.ndimage.label`.
"""

from __future__ import annotations

import math

import numpy as np

_FAR = np.iinfo(np.int32).max // 4  # a row index past any grid: "no set cell on this side of the column"


def reach_cells(radius_m: float, resolution_m: float) -> int:
    """Whole cells that surely cover `radius_m` [m] (one spare: the caller's float threshold decides)."""
    return max(0, math.ceil(radius_m / resolution_m)) + 1


def nearest_within(
    mask: np.ndarray, reach: int, carry: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """For each cell, the squared distance [cells²] to the nearest set cell of `mask`, and `carry` there.

    Only set cells up to `reach` cells away in each axis are seen: where none is, the squared distance
    is larger than `reach`² (and the carried value meaningless). `carry` (an integer array of the mask's
    shape, e.g. cluster labels) is read at the chosen nearest cell; None skips that work.
    """
    # Worked on the transpose: a shift across columns is then a shift of contiguous rows (3x faster).
    cells = np.ascontiguousarray(np.asarray(mask, dtype=bool).T)  # [col, row]
    cols, rows = cells.shape
    reach = min(reach, rows + cols)  # every set cell of the grid lies within that
    far = 2 * (reach + 1) ** 2 + 1  # more than any squared distance within the reach
    # Pass 1, along each column: the nearest set row before (or at) and after each cell; ties go to
    # the lower row.
    index = np.arange(rows, dtype=np.int32)[None, :]
    before = np.maximum.accumulate(np.where(cells, index, -_FAR), axis=1)
    after = np.minimum.accumulate(np.where(cells, index, _FAR)[:, ::-1], axis=1)[:, ::-1]
    gap_before, gap_after = index - before, after - index
    gap = np.minimum(gap_before, gap_after)
    # Pass 2, across columns: the best column within the reach. A candidate's key is its squared
    # distance times `span` plus the shift's rank (0 = the lowest column), so one minimum per shift
    # picks the nearest, and among equally near ones the lowest column.
    span = 2 * reach + 1
    # The narrowest integers that hold every key (a missing row plus the widest shift): int16 for the
    # usual reaches halves the memory traffic; a reach as wide as a large grid needs int64.
    top = (far + reach * reach + 1) * span
    dtype = next(t for t in (np.int16, np.int32, np.int64) if top < np.iinfo(t).max)
    key = (np.where(gap <= reach, gap.astype(np.int64) ** 2, far) * span).astype(dtype)
    best = np.full(cells.shape, far * span, dtype=dtype)
    candidate = np.empty(cells.shape, dtype=dtype)
    for rank, shift in enumerate(range(-reach, reach + 1)):
        lo, hi = max(0, -shift), min(cols, cols - shift)  # target columns whose source column exists
        if lo >= hi:
            continue
        into, cand = best[lo:hi], candidate[lo:hi]
        np.add(key[lo + shift : hi + shift], dtype(shift * shift * span + rank), out=cand)
        np.minimum(into, cand, out=into)
    squared, rank_of = np.divmod(best.astype(np.int64), span)
    if carry is None:
        return np.ascontiguousarray(squared.T), None
    column = np.clip(np.arange(cols, dtype=np.int32)[:, None] + rank_of - reach, 0, cols - 1)
    nearest_row = np.clip(np.where(gap_before <= gap_after, before, after), 0, rows - 1)
    row = np.take_along_axis(nearest_row, column, axis=0)  # the chosen column's nearest set row
    return np.ascontiguousarray(squared.T), np.ascontiguousarray(np.asarray(carry)[row, column].T)


def within(mask: np.ndarray, radius_m: float, resolution_m: float) -> np.ndarray:
    """Cells whose centre lies within `radius_m` [m] of a set cell's centre (Euclidean, exact)."""
    if not mask.any() or radius_m < 0:
        return np.zeros(mask.shape, dtype=bool)
    squared, _ = nearest_within(mask, reach_cells(radius_m, resolution_m))
    return inside(squared, radius_m, resolution_m)


def inside(squared: np.ndarray, radius_m: float, resolution_m: float) -> np.ndarray:
    """Which squared cell distances lie within `radius_m` [m].

    The same float steps as thresholding SciPy's distance transform (the integer's square root, times
    the cell side), so both agree to the last cell.
    """
    return np.asarray(np.sqrt(squared.astype(float)) * resolution_m <= radius_m)


def dilate4(mask: np.ndarray) -> np.ndarray:
    """`mask` grown by one cell across edges (outside the grid counts as unset)."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def label8(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """8-connected components of `mask`, numbered 1.. in raster order of their first cell (0: unset)."""
    rows, cols = mask.shape
    cells = np.flatnonzero(mask)
    labels = np.zeros(mask.shape, dtype=np.int32)
    if cells.size == 0:
        return labels, 0
    col = cells % cols
    # Each cell's neighbours later in raster order: right, down-left, down, down-right.
    firsts, seconds = [], []
    for offset, keep in ((1, col < cols - 1), (cols - 1, col > 0), (cols, None), (cols + 1, col < cols - 1)):
        target = cells + offset
        at = np.minimum(np.searchsorted(cells, target), cells.size - 1)
        linked = cells[at] == target
        if keep is not None:
            linked &= keep
        firsts.append(np.flatnonzero(linked))
        seconds.append(at[linked])
    a, b = np.concatenate(firsts), np.concatenate(seconds)
    # Hook the larger root under the smaller, then jump to the roots, until every link joins equals: each
    # component ends under its lowest cell.
    parent = np.arange(cells.size)
    while a.size:
        pa, pb = parent[a], parent[b]
        differ = pa != pb
        if not differ.any():
            break
        np.minimum.at(parent, np.maximum(pa, pb)[differ], np.minimum(pa, pb)[differ])
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    roots, numbered = np.unique(parent, return_inverse=True)
    labels.ravel()[cells] = numbered.astype(np.int32) + 1
    return labels, int(roots.size)
