"""Pictures for people: the sRGB curve, the one tone-mapping policy, strips and report pages."""

import numpy as np
import pytest
import torch

from mitsvbrdf.viewing import (auto_exposure, pattern_strip, srgb_encode, to_uint8, tonemap,
                               write_html_page)


def test_srgb_curve_is_the_standard_one_for_tensors_and_arrays():
    x = [0.0, 0.002, 0.05, 0.25, 1.0]
    want = [0.0, 12.92 * 0.002, 1.055 * 0.05 ** (1 / 2.4) - 0.055, 1.055 * 0.25 ** (1 / 2.4) - 0.055, 1.0]
    np.testing.assert_allclose(srgb_encode(np.array(x)), want, rtol=1e-12)
    np.testing.assert_allclose(srgb_encode(torch.tensor(x, dtype=torch.float64)).numpy(), want, rtol=1e-12)


def test_tonemap_maps_to_the_display_range():
    x = torch.rand(2, 3, 3, 8, 8) * 5
    y = tonemap(x)
    assert y.min() >= 0 and y.max() <= 1
    assert torch.equal(tonemap(x, exposure=0.0), torch.zeros_like(x))


def test_tonemap_maps_the_99th_percentile_of_the_set_to_white():
    a = np.linspace(0, 100, 1000).reshape(10, 100)
    out = to_uint8(tonemap(a))
    assert out.dtype == np.uint8 and out.shape == a.shape
    p99 = np.percentile(a, 99)
    assert out[a >= p99].min() == 255 and out[a < 0.98 * p99].max() < 255
    assert out[0, 0] == 0


def test_tonemap_with_a_given_exposure_uses_the_srgb_curve():
    out = to_uint8(tonemap(np.array([0.0, 0.5, 0.1]), exposure=0.5))  # -> linear 0, 0.25, 0.05
    np.testing.assert_array_equal(out, [0, 137, 63])


def test_a_black_set_is_black_and_a_mostly_black_one_is_exposed_by_its_maximum():
    assert to_uint8(tonemap(np.zeros((2, 3, 3)))).max() == 0
    a = np.zeros(1000)
    a[0] = 4.0  # the 99th percentile is 0
    assert auto_exposure(a) == pytest.approx(0.25)


def test_nan_shows_black_and_inf_white():
    out = to_uint8(tonemap(torch.tensor([float("nan"), float("inf"), 0.5]), exposure=1.0))
    np.testing.assert_array_equal(out, [0, 255, 188])


def test_per_image_exposure_gives_each_image_its_own():
    imgs = torch.stack([torch.full((3, 4, 4), 2.0), torch.full((3, 4, 4), 0.5)])
    assert auto_exposure(imgs, per_image=True).tolist() == [0.5, 2.0]
    assert auto_exposure(imgs) == pytest.approx(0.5)


def test_pattern_strip_puts_patterns_side_by_side():
    p = torch.zeros(3, 3, 2, 4)
    p[1] = 1.0
    strip = pattern_strip(p)
    assert strip.shape == (2, 12, 3)
    assert strip[:, 4:8].min() == 1.0 and strip[:, :4].max() == 0.0 and strip[:, 8:].max() == 0.0


def test_report_page_escapes_text_and_lists_images_under_captions(tmp_path):
    write_html_page(tmp_path / "r.html", "a <b>", paragraphs=["x & y"], table=(["k", "v"], [["rmse", 0.5]]),
                    images=[("Maps", "maps.png")])
    page = (tmp_path / "r.html").read_text()
    assert "<h1>a &lt;b&gt;</h1>" in page and "<p>x &amp; y</p>" in page
    assert "<td>rmse</td><td>0.5</td>" in page
    assert page.index("<h2>Maps</h2>") < page.index('src="maps.png"')
