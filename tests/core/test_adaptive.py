"""The adaptive lattice refinement (links1/tracing/adaptive.py) on analytic images."""
import numpy as np
import pytest

from links1.tracing.adaptive import check_options, render_adaptive
from links1.errors import UsageError

W, H = 16, 12


def image(f):
    """A sample function from an analytic image f(x, y) -> (n,) in [0, 1] (film pixels)."""
    def sample(i, j, step, keys):
        v = f(i / step, j / step)
        return np.stack([v, 0.5 * v, np.zeros_like(v)], axis=1)
    return sample


def half_plane(a, b, c):
    return image(lambda x, y: (a * x + b * y < c).astype(np.float64))


def test_flat_image_is_not_refined():
    vals, n = render_adaptive(image(lambda x, y: np.full(x.shape, 0.7)), (0, 0, W, H), (W, H), 0.0, 4)
    assert np.all(n == 4)
    assert np.all(vals[..., 0] == 0.7) and np.all(vals[..., 1] == 0.35)


def test_vertical_edge_refines_only_its_column():
    depth = 4
    vals, n = render_adaptive(half_plane(1.0, 0.0, 5.3), (0, 0, W, H), (W, H), 0.1, depth)
    refined = n > 4
    assert np.all(refined[:, 5]) and not np.any(np.delete(refined, 5, axis=1))
    # coverage of column 5 is 0.3; the box integral of corner means is within one lattice step
    assert np.all(np.abs(vals[:, 5, 0] - 0.3) <= 2.0 ** -depth)
    assert np.all(vals[:, :5, 0] == 1.0) and np.all(vals[:, 6:, 0] == 0.0)


def test_slanted_edge_refines_exactly_the_pixels_it_crosses():
    a, b, c = 0.37, -1.0, -2.1  # the line y = 0.37 x + 2.1 (misses every lattice point)
    vals, n = render_adaptive(half_plane(a, b, c), (0, 0, W, H), (W, H), 0.1, 3)
    x, y = np.meshgrid(np.arange(W), np.arange(H))
    side = [a * (x + dx) + b * (y + dy) < c for dx in (0, 1) for dy in (0, 1)]
    crossed = np.any(side, axis=0) & ~np.all(side, axis=0)
    assert crossed.sum() > W - 2
    np.testing.assert_array_equal(n > 4, crossed)


def test_threshold_zero_on_a_gradient_refines_to_full_depth():
    for depth in (0, 1, 3):
        vals, n = render_adaptive(image(lambda x, y: 0.01 * x + 0.02 * y), (0, 0, W, H), (W, H), 0.0, depth)
        assert np.all(n == (2 ** depth + 1) ** 2)
        # a linear image: the box integral of corner means is exact (pixel centre value)
        x, y = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        np.testing.assert_allclose(vals[..., 0], 0.01 * x + 0.02 * y, rtol=0, atol=1e-14)


def test_disk_error_falls_with_depth():
    disk = image(lambda x, y: ((x - 7.3) ** 2 + (y - 5.9) ** 2 < 4.1 ** 2).astype(np.float64))
    errs = []
    ref = np.pi * 4.1 ** 2
    for depth in (0, 2, 4, 6):
        vals, n = render_adaptive(disk, (0, 0, W, H), (W, H), 0.05, depth)
        errs.append(abs(vals[..., 0].sum() - ref))
    assert errs[-1] < 0.02 * ref and errs[-1] < errs[1] < errs[0]


def test_tiled_equals_untiled_bit_for_bit():
    def f(x, y):
        return (np.sin(1.7 * x) * np.cos(2.3 * y) > 0.2) * (0.3 + 0.05 * x) + ((x - 8) ** 2 + (y - 6) ** 2 < 9)
    sample = image(f)
    full, nfull = render_adaptive(sample, (0, 0, W, H), (W, H), 0.05, 3)
    for x0, y0, w, h in [(0, 0, 7, 5), (7, 0, 9, 5), (0, 5, 3, 7), (3, 5, 13, 7), (5, 4, 1, 1)]:
        part, npart = render_adaptive(sample, (x0, y0, w, h), (W, H), 0.05, 3)
        assert np.array_equal(part, full[y0:y0 + h, x0:x0 + w])
        assert np.array_equal(npart, nfull[y0:y0 + h, x0:x0 + w])


def test_each_lattice_point_is_evaluated_once():
    seen = []

    def sample(i, j, step, keys):
        seen.append(keys)
        return np.stack([(i / step < 5.3).astype(float)] * 3, axis=1)
    render_adaptive(sample, (0, 0, W, H), (W, H), 0.1, 3)
    keys = np.concatenate(seen)
    assert len(np.unique(keys)) == len(keys)


@pytest.mark.parametrize("t, d", [(-0.1, 2), (float("nan"), 2), (0.1, -1), (0.1, 9), ("x", 2)])
def test_bad_options(t, d):
    with pytest.raises(UsageError, match="adaptive"):
        check_options(t, d)


def test_summed_channels_are_counted_not_refined_on():
    """A count channel (e.g. ray tests per point) that varies wildly takes no part in the
    refinement and is summed over each pixel's distinct lattice points."""
    def sample(i, j, step, keys):
        flat = np.full(len(i), 0.25)
        return np.stack([flat, flat, flat, (i * 7 + j * 13) % 11 + 1.0], axis=1)
    vals, samples, sums = render_adaptive(sample, (0, 0, W, H), (W, H), 0.0, 3, summed=1)
    assert vals.shape == (H, W, 3) and np.all(vals == 0.25)
    assert np.all(samples == 4)
    x, y = np.meshgrid(np.arange(W), np.arange(H))
    S = 8   # lattice steps per pixel at depth 3
    count = lambda i, j: (i * 7 + j * 13) % 11 + 1.0  # noqa: E731
    expect = sum(count((x + dx) * S, (y + dy) * S) for dx in (0, 1) for dy in (0, 1))
    assert np.array_equal(sums[..., 0], expect)


# --- the film's reconstruction filter (FilteredLeaves) ---------------------------------------
from links1.sensor.filters import Filter  # noqa: E402

NON_BOX = [Filter("gaussian"), Filter("tent"), Filter("tent", {"radius": 1.5}), Filter("mitchell"),
           Filter("catmullrom"), Filter("lanczos", {"lobes": 2})]


def interior(f, W=W, H=H):
    """Pixels whose whole filter support lies on the film."""
    b = f.border
    return (slice(b + 1, H - b - 1), slice(b + 1, W - b - 1))


@pytest.mark.parametrize("f", NON_BOX, ids=lambda f: f.describe())
def test_filtered_linear_image_is_its_centre_value(f):
    """A symmetric filter over a linear image gives the pixel-centre value, and the bilinear
    interpolant of the leaves reproduces a linear image exactly, at every depth."""
    for depth in (0, 2):
        vals, n = render_adaptive(image(lambda x, y: 0.01 * x + 0.02 * y + 0.1), (0, 0, W, H), (W, H), 0.0, depth,
                                  rfilter=f)
        x, y = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        ins = interior(f)
        np.testing.assert_allclose(vals[ins][..., 0], (0.01 * x + 0.02 * y + 0.1)[ins], rtol=0, atol=1e-12)


@pytest.mark.parametrize("f", NON_BOX, ids=lambda f: f.describe())
def test_filtered_flat_image_is_flat_up_to_the_film_edge(f):
    vals, n = render_adaptive(image(lambda x, y: np.full(x.shape, 0.7)), (0, 0, W, H), (W, H), 0.0, 3, rfilter=f)
    np.testing.assert_allclose(vals[..., 0], 0.7, rtol=1e-14)
    assert np.all(n == 4)


@pytest.mark.parametrize("f", [Filter("gaussian"), Filter("tent"), Filter("lanczos")], ids=lambda f: f.name)
def test_filtered_edge_matches_the_filtered_step(f):
    """A vertical edge x < c: pixel q is the filter's integral left of c over its integral
    (1-D, numerically with 200001 points, independent of the Gauss-Legendre tables); the
    leaves straddling the edge carry a ramp one lattice step h wide instead of the step, which
    differs from it by h/4 in integral: the error is below h/4 times the filter's largest
    value over its integral (the box integral misses it by 10-20x that)."""
    c, depth = 7.3, 5
    vals, n = render_adaptive(half_plane(1.0, 0.0, c), (0, 0, W, H), (W, H), 0.01, depth, rfilter=f)
    x = np.linspace(-f.radius, f.radius, 200001)
    fx = f.eval(x)
    total = np.trapezoid(fx, x)
    for q in range(f.border + 1, W - f.border - 1):
        expect = np.trapezoid(np.where(x + q + 0.5 < c, fx, 0.0), x) / total
        assert abs(vals[H // 2, q, 0] - expect) < 0.25 * 2.0 ** -depth * np.abs(fx).max() / total, q
    # only the pixels whose corners straddle the edge were refined
    assert np.all(n[:, 7] > 4) and np.all(np.delete(n, 7, axis=1) == 4)


@pytest.mark.parametrize("f", [Filter("gaussian"), Filter("lanczos")], ids=lambda f: f.name)
def test_filtered_tiled_equals_untiled_bit_for_bit(f):
    """Units refine the border pixels their filter reaches exactly as the units that own them."""
    def g(x, y):
        return (np.sin(1.7 * x) * np.cos(2.3 * y) > 0.2) * (0.3 + 0.05 * x) + ((x - 8) ** 2 + (y - 6) ** 2 < 9)
    sample = image(g)
    full = render_adaptive(sample, (0, 0, W, H), (W, H), 0.05, 3, summed=1, rfilter=f)
    assert (full[1] > 4).any()
    for x0, y0, w, h in [(0, 0, 7, 5), (7, 0, 9, 5), (0, 5, 3, 7), (3, 5, 13, 7), (5, 4, 1, 1), (15, 11, 1, 1)]:
        part = render_adaptive(sample, (x0, y0, w, h), (W, H), 0.05, 3, summed=1, rfilter=f)
        for a, b in zip(part, full):
            assert np.array_equal(a, b[y0:y0 + h, x0:x0 + w]), (x0, y0, w, h)


def test_box_filter_is_the_box_integral():
    sample = image(lambda x, y: ((x - 7.3) ** 2 + (y - 5.9) ** 2 < 4.1 ** 2).astype(np.float64))
    a = render_adaptive(sample, (0, 0, W, H), (W, H), 0.05, 3)
    b = render_adaptive(sample, (0, 0, W, H), (W, H), 0.05, 3, rfilter=Filter("box"))
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
