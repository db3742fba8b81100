"""Image file I/O: PNG (8/16-bit, grey, palette, alpha), JPEG, EXR, previews, and clear errors."""

from __future__ import annotations

import numpy as np
import png
import pytest
from PIL import Image

from mitsvbrdf import imageio
from mitsvbrdf.errors import ImageFileError

RNG = np.random.default_rng(0)


def _cut_in_half(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


# ---- PNG ---------------------------------------------------------------------------------------


def test_png_8bit_rgb_round_trips_within_quantisation(tmp_path):
    a = RNG.random((6, 9, 3))
    imageio.write_png(tmp_path / "a.png", a)
    b = imageio.read_image(tmp_path / "a.png")
    assert b.shape == (6, 9, 3) and b.dtype == np.float32
    np.testing.assert_allclose(b, a, atol=0.5 / 255 + 1e-6)


def test_png_16bit_rgb_keeps_all_16_bits(tmp_path):
    a = RNG.random((6, 9, 3))
    imageio.write_png(tmp_path / "a.png", a, bits=16)
    with open(tmp_path / "a.png", "rb") as f:
        assert png.Reader(file=f).read()[3]["bitdepth"] == 16
    b = imageio.read_image(tmp_path / "a.png")
    np.testing.assert_allclose(b, a, atol=0.5 / 65535 + 1e-7)  # PIL alone would lose the low byte


def test_png_16bit_written_by_pypng_reads_exact_codes(tmp_path):
    codes = RNG.integers(0, 65536, (4, 5, 3), dtype=np.uint16)
    with open(tmp_path / "c.png", "wb") as f:
        png.Writer(5, 4, bitdepth=16, greyscale=False).write(f, codes.reshape(4, -1).tolist())
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "c.png"), codes.astype(np.float32) / 65535)


def test_greyscale_png_stays_one_channel_at_8_and_16_bits(tmp_path):
    a = RNG.random((5, 7))
    for bits in (8, 16):
        imageio.write_png(tmp_path / f"g{bits}.png", a, bits=bits)
        b = imageio.read_image(tmp_path / f"g{bits}.png")
        assert b.shape == (5, 7, 1)
        np.testing.assert_allclose(b[..., 0], a, atol=0.5 / (2 ** bits - 1) + 1e-6)


def test_low_bit_depth_greyscale_png_scales_to_unit_range(tmp_path):
    with open(tmp_path / "g4.png", "wb") as f:
        png.Writer(4, 1, greyscale=True, bitdepth=4).write(f, [[0, 5, 15, 3]])
    np.testing.assert_allclose(imageio.read_image(tmp_path / "g4.png")[0, :, 0], np.array([0, 5, 15, 3]) / 15)


def test_palette_png_reads_as_rgb(tmp_path):
    rgb = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], dtype=np.uint8)
    Image.fromarray(rgb).convert("P", palette=Image.ADAPTIVE, colors=4).save(tmp_path / "p.png")
    assert Image.open(tmp_path / "p.png").mode == "P"
    np.testing.assert_allclose(imageio.read_image(tmp_path / "p.png"), rgb / 255.0)


def test_palette_png_with_transparency_reads_as_rgba(tmp_path):
    rgb = np.array([[[255, 0, 0], [0, 255, 0]]], dtype=np.uint8)
    im = Image.fromarray(rgb).convert("P", palette=Image.ADAPTIVE, colors=2)
    im.save(tmp_path / "p.png", transparency=0)
    b = imageio.read_image(tmp_path / "p.png")
    assert b.shape == (1, 2, 4)
    np.testing.assert_allclose(b[..., :3], rgb / 255.0)


def test_grey_alpha_png_reads_as_rgba_at_8_and_16_bits(tmp_path):
    la = RNG.random((3, 4, 2))
    for bits in (8, 16):
        imageio.write_png(tmp_path / f"la{bits}.png", la, bits=bits)
        b = imageio.read_image(tmp_path / f"la{bits}.png")
        assert b.shape == (3, 4, 4)
        tol = 0.5 / (2 ** bits - 1) + 1e-6
        for c in range(3):
            np.testing.assert_allclose(b[..., c], la[..., 0], atol=tol)
        np.testing.assert_allclose(b[..., 3], la[..., 1], atol=tol)


def test_rgba_png_keeps_alpha(tmp_path):
    a = RNG.random((3, 4, 4))
    imageio.write_png(tmp_path / "a.png", a)
    np.testing.assert_allclose(imageio.read_image(tmp_path / "a.png"), a, atol=0.5 / 255 + 1e-6)


def test_write_png_clips_to_unit_range_and_zeroes_nan(tmp_path):
    imageio.write_png(tmp_path / "c.png", np.array([[-1.0, 0.5, 2.0, np.nan]]))
    np.testing.assert_allclose(imageio.read_image(tmp_path / "c.png")[0, :, 0], [0, 128 / 255, 1, 0])


def test_write_png_takes_uint8_codes_as_is(tmp_path):
    codes = RNG.integers(0, 256, (3, 4, 3), dtype=np.uint8)
    imageio.write_png(tmp_path / "u.png", codes)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "u.png")), codes)


def test_jpeg_reads_as_rgb_in_unit_range(tmp_path):
    Image.fromarray(np.full((8, 8, 3), 200, np.uint8)).save(tmp_path / "a.jpg", quality=95)
    b = imageio.read_image(tmp_path / "a.jpg")
    assert b.shape == (8, 8, 3)
    np.testing.assert_allclose(b, 200 / 255, atol=2 / 255)


# ---- EXR ---------------------------------------------------------------------------------------


def test_exr_float32_rgb_round_trips_exactly(tmp_path):
    a = (RNG.random((5, 7, 3)) * 10).astype(np.float32)
    imageio.write_exr(tmp_path / "a.exr", a)
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "a.exr"), a)


def test_exr_half_round_trips_within_half_precision(tmp_path):
    a = RNG.random((5, 7, 4)).astype(np.float32)
    imageio.write_exr(tmp_path / "a.exr", a, half=True)
    b = imageio.read_image(tmp_path / "a.exr")
    assert b.dtype == np.float32 and b.shape == (5, 7, 4)
    np.testing.assert_allclose(b, a, atol=1e-3)


def test_exr_named_channels_round_trip_exactly(tmp_path):
    chans = {"normal.R": RNG.random((3, 4)), "roughness.Y": RNG.random((3, 4)), "Z": RNG.random((3, 4))}
    chans = {k: v.astype(np.float32) for k, v in chans.items()}
    imageio.write_exr(tmp_path / "c.exr", chans)
    back = imageio.read_exr_channels(tmp_path / "c.exr")
    assert list(back) == sorted(chans)
    for k, v in chans.items():
        np.testing.assert_array_equal(back[k], v)


def test_exr_single_channel_reads_as_one_channel(tmp_path):
    a = RNG.random((4, 5)).astype(np.float32)
    imageio.write_exr(tmp_path / "y.exr", a)
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "y.exr"), a[..., None])


def test_exr_single_layer_reads_as_rgb_in_rgb_order(tmp_path):
    a = RNG.random((4, 5, 3)).astype(np.float32)
    imageio.write_exr(tmp_path / "l.exr", {f"albedo.{c}": a[..., i] for i, c in enumerate("RGB")})
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "l.exr"), a)


def test_exr_rgb_beside_other_channels_reads_rgb_only(tmp_path):
    a = RNG.random((4, 5, 3)).astype(np.float32)
    chans = {c: a[..., i] for i, c in enumerate("RGB")} | {"depth.Z": a[..., 0] * 7}
    imageio.write_exr(tmp_path / "d.exr", chans)
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "d.exr"), a)


def test_exr_grey_alpha_reads_as_rgba(tmp_path):
    y, alpha = RNG.random((2, 3, 4)).astype(np.float32)
    imageio.write_exr(tmp_path / "ya.exr", {"Y": y, "A": alpha})
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "ya.exr"), np.stack([y, y, y, alpha], -1))


def test_exr_arbitrary_channel_names_read_in_alphabetical_order(tmp_path):
    x, y, z = RNG.random((3, 3, 4)).astype(np.float32)
    imageio.write_exr(tmp_path / "xyz.exr", {"Z": z, "X": x, "W": y})
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "xyz.exr"), np.stack([y, x, z], -1))


def test_exr_with_two_unrelated_channels_points_to_read_exr_channels(tmp_path):
    a = np.zeros((2, 2), np.float32)
    imageio.write_exr(tmp_path / "two.exr", {"n.R": a, "d.G": a})
    with pytest.raises(ImageFileError, match=r"two\.exr.*read_exr_channels"):
        imageio.read_image(tmp_path / "two.exr")
