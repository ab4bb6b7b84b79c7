"""The numpy nearest-cell transform, dilation and labelling give exactly SciPy's answers (SciPy is the reference)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from llmnav.mapping.nearest import dilate4, label8, nearest_within, within

ALL8 = np.ones((3, 3), dtype=bool)
CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)


def _masks(seed: int, count: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    masks = []
    for _ in range(count):
        rows, cols = (int(n) for n in rng.integers(1, 48, 2))
        masks.append(rng.random((rows, cols)) < rng.choice([0.01, 0.05, 0.2, 0.5]))
    return masks


@pytest.mark.parametrize("reach", [0, 1, 3, 7, 12, 100])
def test_nearest_within_matches_scipys_distances_and_its_choice_among_equally_near_cells(reach: int) -> None:
    ties = 0
    for mask in _masks(reach, 120):
        if not mask.any():
            continue
        distance, (rows, cols) = ndimage.distance_transform_edt(~mask, return_indices=True)
        flat = np.arange(mask.size).reshape(mask.shape)  # carried: which cell was chosen
        squared, chosen = nearest_within(mask, reach, carry=flat)
        assert chosen is not None
        seen = distance <= reach
        assert np.array_equal(np.sqrt(squared[seen].astype(float)), distance[seen])
        assert np.array_equal(chosen[seen], (rows * mask.shape[1] + cols)[seen])
        assert (squared[~seen] > reach * reach).all()
        assert np.array_equal(nearest_within(mask, reach)[0][seen], squared[seen])  # without a carry too
        # Cells with several nearest set cells: the case where the choice is a convention.
        set_r, set_c = np.nonzero(mask)
        for r, c in zip(*np.nonzero(seen), strict=True):
            d2 = (set_r - r) ** 2 + (set_c - c) ** 2
            ties += int((d2 == d2.min()).sum() > 1)
    assert reach == 0 or ties > 20  # the comparison really exercised equally near cells


def test_a_reach_wider_than_a_large_grid_is_still_exact() -> None:
    """Past about 800 cells of reach the keys need 64 bits; the reach is cut at the grid's size."""
    mask = np.random.default_rng(3).random((600, 300)) < 0.0005
    distance, (rows, cols) = ndimage.distance_transform_edt(~mask, return_indices=True)
    flat = np.arange(mask.size).reshape(mask.shape)
    squared, chosen = nearest_within(mask, 10_000, carry=flat)
    assert chosen is not None
    assert np.array_equal(np.sqrt(squared.astype(float)), distance)
    assert np.array_equal(chosen, rows * mask.shape[1] + cols)


@pytest.mark.parametrize("radius_m", [0.0, 0.05, 0.35, 0.45, 0.3 + 0.05, 0.88])
def test_within_equals_thresholding_scipys_distance_transform(radius_m: float) -> None:
    for mask in _masks(11, 60):
        if mask.any():
            expected = ndimage.distance_transform_edt(~mask) * 0.05 <= radius_m
        else:
            expected = np.zeros(mask.shape, dtype=bool)
        assert np.array_equal(within(mask, radius_m, 0.05), expected)


def test_dilate4_and_label8_match_scipy() -> None:
    for mask in _masks(5, 200):
        assert np.array_equal(dilate4(mask), ndimage.binary_dilation(mask, structure=CROSS))
        labels, count = label8(mask)
        expected, expected_count = ndimage.label(mask, structure=ALL8)
        assert count == expected_count and np.array_equal(labels, expected)


def test_a_long_winding_component_is_one_label() -> None:
    mask = np.zeros((41, 41), dtype=bool)
    mask[::4, 1:-1] = True  # rungs joined alternately at the right and left ends: one snake
    for k, row in enumerate(range(0, 40, 4)):
        mask[row : row + 5, -2 if k % 2 == 0 else 1] = True
    labels, count = label8(mask)
    assert count == 1 and (labels[mask] == 1).all()
