"""The matrix field: kernels, full (separable) field, lazy field, sampling, surface pre-pass."""

from __future__ import annotations

import numpy as np
import pytest

from planbench.errors import InvalidConfigError
from planbench.field import Kernels, KernelSpec, full_field, lazy_field, surface_grid
from planbench.field.reference import brute_force_field, dense_field, fft_field, window_sums
from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime.backend import have_numba

NEEDS_NUMBA = pytest.mark.skipif(not have_numba(), reason="numba not installed")
BACKENDS = ["numpy", pytest.param("numba", marks=NEEDS_NUMBA)]
RES = 0.05


def random_grid(rng: np.random.Generator, shape: tuple[int, int, int], outside: float) -> OccupancyGrid:
    """Probabilistic occupancy in [0, 1], mostly low with a few near-certain cells."""
    data = rng.random(shape) ** 3
    return OccupancyGrid(data, origin=[0.3, -0.2, 0.1], resolution=RES, outside=outside)


def points_around(rng: np.random.Generator, grid: OccupancyGrid, n: int, beyond: float) -> np.ndarray:
    """Points inside, on the border of and up to ``beyond`` [m] outside the grid."""
    lo, hi = grid.origin - beyond, grid.upper + beyond
    pts = rng.uniform(lo, hi, (n, 3))
    # exact cell centres, grid faces and corners too
    pts[:4] = grid.origin + (np.array([[0, 0, 0], [1, 2, 3], [4, 0, 2], [2, 3, 1]]) + 0.5) * RES
    pts[4] = grid.origin
    pts[5] = grid.upper
    pts[6] = grid.upper - [RES / 2, 0.0, RES / 4]
    return pts


# --- kernels ------------------------------------------------------------------------------


def test_linear_profile_values_and_sign():
    k = Kernels.from_cells(7, 5, resolution=RES, profile="linear", taper="linear")
    c = 3
    s = np.arange(-c, c + 1)
    expected = -np.sign(s) * (c + 1 - np.abs(s)) / (c + 1)
    np.testing.assert_allclose(k.along, expected)
    assert k.along[c + 1] < 0 < k.along[c - 1]  # an obstacle on +x pushes towards -x
    np.testing.assert_allclose(k.across, [1 / 3, 2 / 3, 1, 2 / 3, 1 / 3])


@pytest.mark.parametrize("profile", ["linear", "gaussian", "inverse-power", lambda d: np.exp(-d / 0.1)])
def test_profiles_are_antisymmetric_and_decay(profile):
    k = Kernels.from_cells(11, resolution=RES, profile=profile, gain=2.0)
    c = k.half_length
    assert k.along[c] == 0.0
    np.testing.assert_array_equal(k.along, -k.along[::-1])
    mag = -k.along[c + 1 :]
    assert np.all(mag > 0) and np.all(np.diff(mag) < 0)


@pytest.mark.parametrize("taper", ["linear", "gaussian", "constant"])
def test_tapers_are_symmetric(taper):
    k = Kernels.from_cells(5, 9, resolution=RES, taper=taper)
    np.testing.assert_array_equal(k.across, k.across[::-1])
    assert k.across[4] == 1.0 and np.all(k.across > 0)
    assert np.all(np.diff(k.across[4:]) <= 0)


def test_dense_kernel_is_outer_product_with_roles_permuted():
    k = Kernels.from_cells(5, 3, resolution=RES)
    kx, ky, kz = (k.dense(a) for a in "xyz")
    assert kx.shape == (5, 3, 3) and ky.shape == (3, 5, 3) and kz.shape == (3, 3, 5)
    np.testing.assert_allclose(ky, np.transpose(kx, (1, 0, 2)))
    np.testing.assert_allclose(kz, np.transpose(kx, (1, 2, 0)))
    assert kx.sum() == pytest.approx(0.0, abs=1e-15)


def test_spec_converts_metres_to_cells():
    k = KernelSpec(reach=0.2, width=0.1, profile="gaussian").build(RES)
    assert len(k.along) == 9 and len(k.across) == 5
    assert k.reach == pytest.approx(0.2) and k.support == 4
    assert len(KernelSpec(reach=0.125).build(RES).along) == 7  # 2.5 cells rounds up to 3


@pytest.mark.parametrize(
    "length, width, match",
    [
        (4, None, "odd"),
        (1, None, ">= 3"),
        (5, 2, "width must be odd"),
        (5.0, None, "whole number"),
    ],
)
def test_bad_sizes_raise_clear_errors(length, width, match):
    with pytest.raises(InvalidConfigError, match=match):
        Kernels.from_cells(length, width, resolution=RES)


def test_bad_settings_raise_clear_errors():
    with pytest.raises(InvalidConfigError, match="reach 0.02 m is under half a cell"):
        KernelSpec(reach=0.02).build(RES)
    with pytest.raises(InvalidConfigError, match="unknown kernel profile 'cubic'.*linear"):
        KernelSpec(profile="cubic").build(RES)
    with pytest.raises(InvalidConfigError, match="taper"):
        KernelSpec(taper="round").build(RES)
    with pytest.raises(InvalidConfigError, match="gain"):
        KernelSpec(gain=0.0).build(RES)
    with pytest.raises(InvalidConfigError, match="finite values >= 0"):
        KernelSpec(profile=lambda d: -d).build(RES)
    with pytest.raises(InvalidConfigError, match="antisymmetric"):
        Kernels(along=[1.0, 0.0, 1.0], across=[1.0, 1.0, 1.0])
    grid = OccupancyGrid(np.zeros((4, 4, 4)), [0, 0, 0], 0.1)
    with pytest.raises(InvalidConfigError, match="KernelSpec.build"):
        full_field(grid, Kernels.from_cells(3, resolution=RES))
    with pytest.raises(InvalidConfigError, match="float32 or float64"):
        full_field(grid, Kernels.from_cells(3, resolution=0.1), dtype=np.int32)


# --- full == lazy == brute force -----------------------------------------------------------

CASES = [  # (length, width, profile, taper, outside)
    (5, 5, "linear", "linear", 0.0),
    (7, 3, "gaussian", "constant", 1.0),
    (3, 7, "inverse-power", "gaussian", 0.3),
    (9, 5, lambda d: 1.0 / (d + 0.02), "linear", 1.0),
]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("length, width, profile, taper, outside", CASES)
def test_full_equals_lazy_equals_brute_force(backend, length, width, profile, taper, outside):
    rng = np.random.default_rng(length * 10 + width)
    grid = random_grid(rng, (9, 7, 8), outside)
    kernels = Kernels.from_cells(length, width, resolution=RES, profile=profile, taper=taper)
    pts = points_around(rng, grid, 60, beyond=(kernels.support + 2) * RES)
    expected = brute_force_field(grid, kernels, pts)
    assert np.abs(expected).max() > 0.1  # the comparison is not between zeros

    field = full_field(grid, kernels, np.float64, backend=backend)
    np.testing.assert_allclose(field.sample(pts, backend=backend), expected, rtol=0, atol=1e-9)
    lazy = lazy_field(grid, kernels, pts, backend=backend)
    np.testing.assert_allclose(lazy, expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("outside", [0.0, 1.0])
def test_field_at_cell_centres_is_the_window_sum(backend, outside):
    rng = np.random.default_rng(1)
    grid = random_grid(rng, (6, 5, 7), outside)
    kernels = Kernels.from_cells(5, 3, resolution=RES, profile="gaussian")
    field = full_field(grid, kernels, np.float64, backend=backend)
    cells = np.stack(np.meshgrid(*map(np.arange, grid.shape), indexing="ij"), -1).reshape(-1, 3)
    expected = window_sums(grid, kernels, cells).T.reshape(3, *grid.shape)
    np.testing.assert_allclose(field.grid_view, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("outside", [0.0, 0.5, 1.0])
def test_separable_equals_dense_and_fft_correlation(backend, outside):
    rng = np.random.default_rng(2)
    grid = random_grid(rng, (12, 10, 11), outside)
    kernels = Kernels.from_cells(7, 5, resolution=RES, profile="gaussian", taper="gaussian")
    field = full_field(grid, kernels, np.float64, margin=0, backend=backend)
    np.testing.assert_allclose(field.components, dense_field(grid, kernels), rtol=0, atol=1e-12)
    np.testing.assert_allclose(field.components, fft_field(grid, kernels), rtol=0, atol=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
def test_float32_matches_float64(backend):
    rng = np.random.default_rng(3)
    grid = random_grid(rng, (10, 9, 8), 1.0)
    grid32 = OccupancyGrid(grid.data.astype(np.float32), grid.origin, RES, grid.outside)
    kernels = Kernels.from_cells(7, resolution=RES)
    f64 = full_field(grid, kernels, np.float64, backend=backend)
    f32 = full_field(grid32, kernels, np.float32, backend=backend)
    assert f32.components.dtype == np.float32
    np.testing.assert_allclose(f32.components, f64.components, rtol=0, atol=1e-5)
    pts = points_around(rng, grid, 20, beyond=0.2)
    np.testing.assert_allclose(lazy_field(grid32, kernels, pts, backend=backend), f64.sample(pts), rtol=0, atol=1e-5)


def test_margin_zero_agrees_inside_and_fades_outside():
    rng = np.random.default_rng(4)
    grid = random_grid(rng, (12, 12, 12), 0.0)
    kernels = Kernels.from_cells(5, resolution=RES)
    exact = full_field(grid, kernels, np.float64)
    bare = full_field(grid, kernels, np.float64, margin=0)
    assert exact.exact and not bare.exact and bare.components.shape == (3, 12, 12, 12)
    inner = grid.origin + rng.uniform(0.5 * RES, 11.5 * RES, (20, 3))
    np.testing.assert_allclose(bare.sample(inner), exact.sample(inner), rtol=0, atol=1e-12)
    assert np.all(bare.sample(grid.origin - RES) == 0.0)


# --- behaviour ------------------------------------------------------------------------------


def wall_grid(outside: float = 0.0, x_cells: int = 24, yz: int = 13) -> OccupancyGrid:
    """A two-cell-thick wall filling the y-z plane at the +x end of the grid."""
    data = np.zeros((x_cells, yz, yz))
    data[-2:] = 1.0
    return OccupancyGrid(data, [0.0, 0.0, 0.0], RES, outside)


@pytest.mark.parametrize("backend", BACKENDS)
def test_wall_on_plus_x_pushes_towards_minus_x(backend):
    grid = wall_grid()
    kernels = Kernels.from_cells(9, 5, resolution=RES)
    p = np.array([[20.5, 6.5, 6.5]]) * RES  # two cells in front of the wall, centred across it
    for f in (
        full_field(grid, kernels, backend=backend).sample(p, backend=backend),
        lazy_field(grid, kernels, p, backend=backend),
    ):
        assert f[0, 0] < 0
        assert f[0, 1] == pytest.approx(0.0, abs=1e-6) and f[0, 2] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("profile", ["linear", "gaussian"])
def test_field_decays_monotonically_away_from_a_flat_wall(profile):
    grid = wall_grid()
    kernels = Kernels.from_cells(15, 5, resolution=RES, profile=profile)
    x = np.linspace(21.5, 10.0, 200) * RES  # from the wall's front cell outwards, past the reach
    pts = np.stack([x, np.full_like(x, 6.5 * RES), np.full_like(x, 6.5 * RES)], axis=1)
    fx = full_field(grid, kernels, np.float64).sample(pts)[:, 0]
    assert np.all(fx <= 0)
    assert np.all(np.diff(-fx) <= 1e-12) and -fx[0] > -fx[len(fx) // 2] > 0
    centres = (np.arange(21, 13, -1) + 0.5)[:, None] * RES * np.ones(3)
    centres[:, 1:] = 6.5 * RES
    at_cells = -full_field(grid, kernels, np.float64).sample(centres)[:, 0]
    assert np.all(np.diff(at_cells[:-1]) < 0)  # strictly, cell to cell within the reach
    assert at_cells[-2] > 0 == at_cells[-1]
    np.testing.assert_array_equal(fx[x < 13.5 * RES], 0.0)  # beyond the reach: exactly zero


@pytest.mark.parametrize("backend", BACKENDS)
def test_symmetric_scene_gives_a_symmetric_field(backend):
    data = np.zeros((15, 13, 11))
    data[3:5, 4:9, 2:9] = 1.0
    data[10:12, 4:9, 2:9] = 1.0  # mirror image of the first block in x
    grid = OccupancyGrid(data, [0, 0, 0], RES)
    kernels = KernelSpec(reach=0.2, width=0.15, profile="gaussian").build(RES)
    F = full_field(grid, kernels, np.float64, backend=backend).grid_view
    np.testing.assert_allclose(F[0], -F[0][::-1], atol=1e-12)  # x mirrored: F_x flips sign
    np.testing.assert_allclose(F[1], F[1][::-1], atol=1e-12)
    np.testing.assert_allclose(F[2], F[2][::-1], atol=1e-12)
    assert F[0][7, 6, 5] == pytest.approx(0.0, abs=1e-12)  # the mid-plane: pushes cancel


@pytest.mark.parametrize("backend", BACKENDS)
def test_far_from_every_obstacle_the_field_is_exactly_zero(backend):
    data = np.zeros((30, 10, 10))
    data[2, 5, 5] = 0.7
    grid = OccupancyGrid(data, [0, 0, 0], RES)
    kernels = Kernels.from_cells(7, resolution=RES)  # reach 3 cells
    far = np.array([[7.5, 5.5, 5.5], [25.0, 2.0, 8.0], [100.0, -50.0, 3.0]]) * RES
    near = np.array([[4.5, 5.5, 5.5]]) * RES
    field = full_field(grid, kernels, np.float64, backend=backend)
    for f in (field.sample(far, backend=backend), lazy_field(grid, kernels, far, backend=backend)):
        assert np.all(f == 0.0)
    assert field.sample(near)[0, 0] > 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_uniform_occupancy_and_far_outside_a_walled_grid_give_zero(backend):
    grid = OccupancyGrid(np.ones((6, 6, 6)), [0, 0, 0], RES, outside=1.0)
    kernels = Kernels.from_cells(5, resolution=RES)
    pts = np.array([[0.15, 0.15, 0.15], [0.0, 0.3, 0.1], [-2.0, 5.0, 1.0]])
    assert np.all(full_field(grid, kernels, backend=backend).components == 0.0)
    assert np.all(lazy_field(grid, kernels, pts, backend=backend) == 0.0)


def test_walled_grid_pushes_inwards():
    grid = OccupancyGrid(np.zeros((10, 10, 10)), [0, 0, 0], RES, outside=1.0)
    f = lazy_field(grid, Kernels.from_cells(7, resolution=RES), np.array([[0.05, 0.25, 0.25]]))
    assert f[0, 0] > 0 and abs(f[0, 1]) < 1e-9


# --- surface pre-pass -----------------------------------------------------------------------


def test_surface_keeps_the_shell_of_a_solid_block():
    data = np.zeros((9, 9, 9))
    data[2:7, 2:7, 2:7] = 1.0
    surf = surface_grid(OccupancyGrid(data, [0, 0, 0], RES)).data
    shell = data.copy()
    shell[3:6, 3:6, 3:6] = 0.0
    np.testing.assert_array_equal(surf, shell)


def test_surface_keeps_thin_walls_and_respects_outside():
    data = np.zeros((5, 5, 5))
    data[2] = 1.0  # a one-cell wall spanning the grid
    assert np.array_equal(surface_grid(OccupancyGrid(data, [0, 0, 0], RES)).data, data)
    full = OccupancyGrid(np.ones((4, 4, 4)), [0, 0, 0], RES, outside=1.0)
    assert np.all(surface_grid(full).data == 0.0)  # walled in on every side: nothing is a surface
    open_ = OccupancyGrid(np.ones((4, 4, 4)), [0, 0, 0], RES, outside=0.0)
    assert surface_grid(open_).data[0, 1, 1] == 1.0 and surface_grid(open_).data[1, 1, 1] == 0.0


def test_surface_on_probabilistic_grid_scales_by_the_freest_neighbour():
    data = np.full((3, 3, 3), 0.8)
    data[1, 1, 0] = 0.2
    surf = surface_grid(OccupancyGrid(data, [0, 0, 0], RES, outside=1.0)).data
    assert surf[1, 1, 1] == pytest.approx(0.8 * (1 - 0.2))


@pytest.mark.parametrize("outside", [0.0, 1.0])
@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_the_lazy_surface_pass_gives_the_field_of_the_surface_grid(outside, backend):
    """``lazy_field(..., surface=True)`` reads each cell through the surface pass: the same field
    as the pass over the whole grid, for binary and probabilistic grids, walled in or not."""
    from planbench.field.surface import surface_grid

    if backend == "numba":
        pytest.importorskip("numba")
    rng = np.random.default_rng(3)
    solid = np.zeros((14, 12, 10))
    solid[3:10, 2:9, 4:8] = 1.0  # a solid block: its inside is no surface
    for data in (solid, solid * rng.uniform(0.2, 1.0, solid.shape)):
        grid = OccupancyGrid(data, np.array([0.1, -0.2, 0.0]), 0.02, outside)
        kernels = KernelSpec(reach=0.08).build(0.02)
        points = rng.uniform(grid.origin - 0.05, grid.upper + 0.05, (200, 3))
        want = lazy_field(surface_grid(grid), kernels, points, backend=backend)
        got = lazy_field(grid, kernels, points, backend=backend, surface=True)
        assert np.abs(want).max() > 0 and np.allclose(got, want, atol=1e-9)
        assert not np.allclose(lazy_field(grid, kernels, points, backend=backend), want)  # the pass matters
