"""The SVBRDF container: construction, validation, batch operations, file formats, clear errors."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from mitsvbrdf import imageio
from mitsvbrdf.errors import ImageFileError, MaterialError
from mitsvbrdf.svbrdf import MAP_NAMES, SVBRDF, decode_maps, encode_maps, resample_texels

from conftest import SAMPLES, needs_samples



def _material(size: int = 8, seed: int = 0, batch: int = 1) -> SVBRDF:
    """A random material with a bumpy (unit, z > 0) normal map."""
    g = torch.Generator().manual_seed(seed)
    n = torch.randn(batch, 3, size, size, generator=g) * 0.3
    n[:, 2] = 1.0
    n = n / n.norm(dim=1, keepdim=True)
    return SVBRDF(normal=n, diffuse=torch.rand(batch, 3, size, size, generator=g),
                  roughness=torch.rand(batch, 1, size, size, generator=g),
                  specular=torch.rand(batch, 3, size, size, generator=g))


def _assert_maps_close(a: SVBRDF, b: SVBRDF, atol: float) -> None:
    for k in MAP_NAMES:
        torch.testing.assert_close(getattr(a, k), getattr(b, k), atol=atol, rtol=0)


def _strip(m: SVBRDF) -> np.ndarray:
    """(H, 4W, 3) encoded strip of a single material."""
    e = m.encoded()[0]
    tiles = [e[0:3], e[3:6], e[6:7].expand(3, -1, -1), e[7:10]]
    return torch.cat(tiles, dim=2).permute(1, 2, 0).numpy()


def _cut_in_half(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


# ---- the shared samples --------------------------------------------------------------------------


@needs_samples
@pytest.mark.parametrize("k", range(4))
def test_shared_sample_tiles_load_in_normal_diffuse_roughness_specular_order(k):
    path = SAMPLES / f"{k}_svbrdf.png"
    raw = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255
    tiles = [raw[:, i * 256:(i + 1) * 256] for i in range(4)]
    # The raw first tile is an encoded normal map: near unit length, pointing out of the surface.
    assert np.median(np.abs(np.linalg.norm(tiles[0] * 2 - 1, axis=-1) - 1)) < 0.05
    # The second (diffuse) tile is not: decoded as a normal it is far from unit length.
    assert np.median(np.abs(np.linalg.norm(tiles[1] * 2 - 1, axis=-1) - 1)) > 0.1
    # The third (roughness) tile is grey.
    assert np.array_equal(tiles[2][..., 0], tiles[2][..., 1]) and np.array_equal(tiles[2][..., 0], tiles[2][..., 2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # samples 1 and 3 warn about non-unit normals
        m = SVBRDF.load(path)
    assert m.resolution == (256, 256) and m.batch_size == 1 and m.render is None and m.name == f"{k}_svbrdf"
    torch.testing.assert_close(m.normal.norm(dim=1), torch.ones(1, 256, 256))
    assert m.normal[:, 2].mean() > 0.8 and m.normal[:, 2].min() > 0
    torch.testing.assert_close(m.diffuse[0], torch.from_numpy(tiles[1]).permute(2, 0, 1))
    torch.testing.assert_close(m.roughness[0, 0], torch.from_numpy(tiles[2][..., 0]))
    torch.testing.assert_close(m.specular[0], torch.from_numpy(tiles[3]).permute(2, 0, 1))


@needs_samples
def test_clean_sample_loads_without_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SVBRDF.load(SAMPLES / "0_svbrdf.png", strict=True)


@needs_samples
def test_sample_with_bad_normals_warns_once_with_file_and_counts():
    with pytest.warns(UserWarning) as record:
        SVBRDF.load(SAMPLES / "1_svbrdf.png")
    msgs = [str(w.message) for w in record]
    assert len(msgs) == 1
    assert "1_svbrdf.png" in msgs[0] and "off unit length" in msgs[0] and "z <= 0" in msgs[0]
    assert record[0].filename == __file__  # points at the caller, not into the library


@needs_samples
def test_sample_with_bad_normals_raises_when_strict():
    with pytest.raises(MaterialError, match=r"1_svbrdf\.png.*off unit length"):
        SVBRDF.load(SAMPLES / "1_svbrdf.png", strict=True)


# ---- round trips ---------------------------------------------------------------------------------


def test_strip_png_round_trips_within_8bit_quantisation(tmp_path):
    m = _material()
    m.save(tmp_path / "m.png")
    assert Image.open(tmp_path / "m.png").size == (32, 8)
    back = SVBRDF.load(tmp_path / "m.png")
    _assert_maps_close(back, m, atol=2 / 255)
    assert back.name == "m"


def test_strip_png_round_trips_within_16bit_quantisation(tmp_path):
    m = _material()
    m.save(tmp_path / "m.png", bits=16)
    _assert_maps_close(SVBRDF.load(tmp_path / "m.png"), m, atol=2e-4)


def test_folder_round_trips_within_8bit_quantisation(tmp_path):
    m = _material()
    m.save(tmp_path / "mat")
    assert sorted(p.name for p in (tmp_path / "mat").iterdir()) == sorted(f"{k}.png" for k in MAP_NAMES)
    assert imageio.read_image(tmp_path / "mat" / "roughness.png").shape == (8, 8, 1)
    back = SVBRDF.load(tmp_path / "mat")
    _assert_maps_close(back, m, atol=2 / 255)
    assert back.name == "mat"


def test_layered_exr_round_trips_exactly(tmp_path):
    m = _material()
    m.save(tmp_path / "m.exr")
    names = set(imageio.read_exr_channels(tmp_path / "m.exr"))
    assert names == {"normal.R", "normal.G", "normal.B", "diffuse.R", "diffuse.G", "diffuse.B",
                     "roughness.Y", "specular.R", "specular.G", "specular.B"}
    back = SVBRDF.load(tmp_path / "m.exr")
    for k in MAP_NAMES:
        assert torch.equal(getattr(back, k), getattr(m, k)), k


def test_layered_exr_stores_the_raw_unit_normal(tmp_path):
    m = SVBRDF.constant(normal=(0.6, 0.0, 0.8), size=4)
    m.save(tmp_path / "m.exr")
    ch = imageio.read_exr_channels(tmp_path / "m.exr")
    np.testing.assert_allclose(ch["normal.R"], 0.6, rtol=1e-6)
    np.testing.assert_allclose(ch["normal.B"], 0.8, rtol=1e-6)


def test_folder_of_exr_maps_loads_with_raw_normals(tmp_path):
    m = _material()
    for k, v in m.maps().items():
        imageio.write_exr(tmp_path / "f" / f"{k}.exr", v[0].permute(1, 2, 0).numpy())
    back = SVBRDF.load(tmp_path / "f")
    for k in MAP_NAMES:
        assert torch.equal(getattr(back, k), getattr(m, k)), k


def test_five_tile_strip_keeps_the_render_tile(tmp_path):
    m = _material()
    render = np.random.default_rng(1).integers(0, 256, (8, 8, 3)).astype(np.float32) / 255
    imageio.write_png(tmp_path / "d.png", np.concatenate([render, _strip(m)], axis=1))
    back = SVBRDF.load(tmp_path / "d.png")
    assert back.render is not None and back.render.shape == (1, 3, 8, 8)
    torch.testing.assert_close(back.render[0], torch.from_numpy(render).permute(2, 0, 1), atol=1e-6, rtol=0)
    _assert_maps_close(back, m, atol=2 / 255)


def test_save_writes_the_render_tile_first_when_present(tmp_path):
    m = _material()
    render = torch.rand(1, 3, 8, 8)
    SVBRDF(**m.maps(), render=render).save(tmp_path / "r.png")
    assert Image.open(tmp_path / "r.png").size == (40, 8)
    torch.testing.assert_close(SVBRDF.load(tmp_path / "r.png").render, render, atol=0.5 / 255 + 1e-6, rtol=0)
    SVBRDF(**m.maps(), render=render).save(tmp_path / "n.png", include_render=False)
    assert Image.open(tmp_path / "n.png").size == (32, 8)


def test_layered_exr_keeps_the_render_tile_exactly(tmp_path):
    m = SVBRDF(**_material().maps(), render=torch.rand(1, 3, 8, 8) * 5)
    m.save(tmp_path / "r.exr")
    assert torch.equal(SVBRDF.load(tmp_path / "r.exr").render, m.render)


def test_sixteen_bit_strip_loads_at_full_precision(tmp_path):
    m = _material()
    imageio.write_png(tmp_path / "s16.png", _strip(m), bits=16)
    back = SVBRDF.load(tmp_path / "s16.png")
    for k in ("diffuse", "roughness", "specular"):
        torch.testing.assert_close(getattr(back, k), getattr(m, k), atol=1e-5, rtol=0)  # 8 bits would be 2e-3
    torch.testing.assert_close(back.normal, m.normal, atol=1e-4, rtol=0)


def test_palette_strip_loads_with_the_stored_colours(tmp_path):
    m = SVBRDF.constant(normal=(0, 0, 1), diffuse=(0.8, 0.4, 0.2), roughness=0.6, specular=0.2, size=8)
    codes = np.round(_strip(m) * 255).astype(np.uint8)
    Image.fromarray(codes).convert("P", palette=Image.ADAPTIVE, colors=8).save(tmp_path / "p.png")
    assert Image.open(tmp_path / "p.png").mode == "P"
    back = SVBRDF.load(tmp_path / "p.png")
    _assert_maps_close(back, m, atol=1 / 255)


def test_strip_albedos_load_as_stored_and_are_what_renderers_and_metrics_use(tmp_path):
    """The one albedo convention (module docstring): stored 8-bit codes / 255 are the linear kd / ks
    (no decoding on load), and the encoded form the metrics compare holds them unchanged."""
    from mitsvbrdf.metrics import map_rmse

    codes = {"diffuse": (11, 128, 250), "specular": (11, 11, 11)}
    m = SVBRDF.constant(diffuse=[c / 255 for c in codes["diffuse"]], specular=[c / 255 for c in codes["specular"]],
                        roughness=0.5, size=4)
    imageio.write_png(tmp_path / "s.png", _strip(m))
    back = SVBRDF.load(tmp_path / "s.png")
    for k, c in codes.items():
        assert torch.equal(getattr(back, k)[0, :, 0, 0], torch.tensor(c, dtype=torch.float32) / 255), k
    torch.testing.assert_close(back.encoded()[:, 3:6], back.diffuse, atol=0, rtol=0)
    assert float(map_rmse(back, m)["diffuse"][0]) < 1e-6


def test_srgb_albedo_decodes_diffuse_and_specular_only(tmp_path):
    m = SVBRDF.constant(diffuse=0.5, specular=0.2, roughness=0.5, size=4)
    m.save(tmp_path / "s.exr")
    back = SVBRDF.load(tmp_path / "s.exr", srgb_albedo=True)
    torch.testing.assert_close(back.diffuse, torch.full_like(m.diffuse, ((0.5 + 0.055) / 1.055) ** 2.4))
    torch.testing.assert_close(back.specular, torch.full_like(m.specular, ((0.2 + 0.055) / 1.055) ** 2.4))
    torch.testing.assert_close(back.roughness, m.roughness)


def test_roughness_strip_with_unequal_channels_warns_and_strict_raises(tmp_path):
    strip = _strip(_material())
    strip[:, 16:24, 1] = 0.0  # roughness tile's green channel
    imageio.write_png(tmp_path / "r.png", strip)
    with pytest.warns(UserWarning, match=r"r\.png.*roughness map has 3 channels that differ"):
        m = SVBRDF.load(tmp_path / "r.png")
    torch.testing.assert_close(m.roughness[0, 0], torch.from_numpy(strip[:, 16:24, 0]), atol=0.5 / 255 + 1e-6, rtol=0)
    with pytest.raises(MaterialError, match=r"r\.png.*roughness"):
        SVBRDF.load(tmp_path / "r.png", strict=True)


def test_file_normals_below_the_surface_are_clamped_and_renormalised(tmp_path):
    m = SVBRDF.constant(size=4)
    strip = _strip(m)
    strip[0, 0, :3] = (0.5, 0.5, 0.25)  # encoded (0, 0, -0.5)
    imageio.write_png(tmp_path / "z.png", strip)
    with pytest.warns(UserWarning, match=r"z\.png.*1 with z <= 0"):
        back = SVBRDF.load(tmp_path / "z.png")
    assert back.normal[0, 2].min() > 0
    torch.testing.assert_close(back.normal.norm(dim=1), torch.ones(1, 4, 4))


# ---- bad files -----------------------------------------------------------------------------------


def test_wrong_strip_width_names_the_file_and_the_expected_widths(tmp_path):
    imageio.write_png(tmp_path / "w.png", np.zeros((8, 24, 3)))
    with pytest.raises(MaterialError, match=r"w\.png.*width 32 or 40 for height 8.*got 24x8"):
        SVBRDF.load(tmp_path / "w.png")


def test_truncated_strip_png_is_an_image_file_error(tmp_path):
    _material(32).save(tmp_path / "t.png")
    _cut_in_half(tmp_path / "t.png")
    with pytest.raises(ImageFileError, match=r"t\.png.*truncated"):
        SVBRDF.load(tmp_path / "t.png")


def test_truncated_exr_is_an_image_file_error(tmp_path):
    _material(32).save(tmp_path / "t.exr")
    _cut_in_half(tmp_path / "t.exr")
    with pytest.raises(ImageFileError, match=r"t\.exr.*truncated"):
        SVBRDF.load(tmp_path / "t.exr")


def test_text_file_named_png_is_an_image_file_error(tmp_path):
    (tmp_path / "notes.png").write_text("not an image")
    with pytest.raises(ImageFileError, match=r"notes\.png"):
        SVBRDF.load(tmp_path / "notes.png")


def test_missing_path_is_an_image_file_error(tmp_path):
    with pytest.raises(ImageFileError, match=r"absent\.png.*no such file or folder"):
        SVBRDF.load(tmp_path / "absent.png")


def test_folder_missing_a_map_names_the_folder_and_the_map(tmp_path):
    _material().save(tmp_path / "f")
    (tmp_path / "f" / "roughness.png").unlink()
    with pytest.raises(ImageFileError, match=r"f: missing the roughness map.*diffuse\.png"):
        SVBRDF.load(tmp_path / "f")


def test_folder_with_mismatched_map_sizes_is_a_material_error(tmp_path):
    _material().save(tmp_path / "f")
    imageio.write_png(tmp_path / "f" / "specular.png", np.zeros((4, 4, 3)))
    with pytest.raises(MaterialError, match=r"f: maps differ in size.*specular 4x4"):
        SVBRDF.load(tmp_path / "f")


def test_exr_without_svbrdf_layers_names_the_missing_channels(tmp_path):
    imageio.write_exr(tmp_path / "rgb.exr", np.zeros((4, 4, 3), np.float32))
    with pytest.raises(MaterialError, match=r"rgb\.exr.*lacks channels.*normal\.R"):
        SVBRDF.load(tmp_path / "rgb.exr")


def test_exr_with_nan_maps_is_a_material_error_naming_the_file(tmp_path):
    m = _material()
    m.save(tmp_path / "nan.exr")
    ch = imageio.read_exr_channels(tmp_path / "nan.exr")
    ch["diffuse.G"][2, 3] = np.nan
    imageio.write_exr(tmp_path / "nan.exr", ch)
    with pytest.raises(MaterialError, match=r"nan\.exr.*diffuse map has NaN or Inf at 1 of 64 texels"):
        SVBRDF.load(tmp_path / "nan.exr")


def test_exr_with_roughness_above_one_is_a_material_error_naming_the_file(tmp_path):
    m = _material()
    m.save(tmp_path / "r.exr")
    ch = imageio.read_exr_channels(tmp_path / "r.exr")
    ch["roughness.Y"][0, 0] = 1.5
    imageio.write_exr(tmp_path / "r.exr", ch)
    with pytest.raises(MaterialError, match=r"r\.exr.*roughness map must lie in \[0, 1\].*max 1\.5"):
        SVBRDF.load(tmp_path / "r.exr")


def test_saving_a_batch_to_one_path_is_refused(tmp_path):
    with pytest.raises(MaterialError, match="one material per path.*holds 2"):
        _material(batch=2).save(tmp_path / "x.png")


def test_saving_with_an_unknown_suffix_is_refused(tmp_path):
    with pytest.raises(ImageFileError, match=r"x\.tiff.*\.png.*\.exr.*folder"):
        _material().save(tmp_path / "x.tiff")


# ---- validation in memory ------------------------------------------------------------------------


@pytest.mark.parametrize("change,match", [
    (dict(diffuse=torch.rand(1, 2, 4, 4)), r"diffuse map must be \(B, 3, H, W\).*\(1, 2, 4, 4\)"),
    (dict(roughness=torch.rand(1, 2, 4, 4)), r"roughness map must be \(B, 1, H, W\)"),
    (dict(specular=torch.rand(4, 4)), r"specular map must be \(B, 3, H, W\)"),
    (dict(specular=torch.rand(1, 3, 5, 4)), r"specular map has shape \(1, 3, 5, 4\).*sizes must match"),
    (dict(diffuse=torch.rand(2, 3, 4, 4)), r"diffuse map has shape \(2, 3, 4, 4\).*sizes must match"),
    (dict(diffuse=torch.rand(1, 3, 4, 4, dtype=torch.float64)), "diffuse map is torch.float64.*share dtype"),
    (dict(diffuse=torch.zeros(1, 3, 4, 4, dtype=torch.uint8)), "diffuse map must be floating point"),
])
def test_maps_of_wrong_shape_or_type_are_clear_errors(change, match):
    maps = SVBRDF.constant(size=4).maps()
    maps.update(change)
    with pytest.raises(MaterialError, match=match):
        SVBRDF(**maps)


def test_nan_map_error_counts_the_texels():
    d = torch.full((1, 3, 4, 4), 0.5)
    d[0, :, 1, 1] = float("nan")
    d[0, 0, 2, 2] = float("inf")
    with pytest.raises(MaterialError, match="diffuse map has NaN or Inf at 2 of 16 texels"):
        SVBRDF(**(SVBRDF.constant(size=4).maps() | {"diffuse": d}))


def test_roughness_above_one_error_gives_min_and_max():
    r = torch.full((1, 1, 4, 4), 0.5)
    r[0, 0, 0, 0] = 1.25
    with pytest.raises(MaterialError, match=r"roughness map must lie in \[0, 1\], got min 0\.5, max 1\.25"):
        SVBRDF(**(SVBRDF.constant(size=4).maps() | {"roughness": r}))


def test_values_within_the_range_tolerance_are_accepted():
    SVBRDF(**(SVBRDF.constant(size=4).maps() | {"specular": torch.full((1, 3, 4, 4), 1 + 5e-5)}))


def test_non_unit_normals_error_counts_texels_and_gives_the_worst():
    n = SVBRDF.constant(size=4).normal.clone()
    n[0, :, 1, 2] *= 1.1
    n[0, :, 3, 0] *= 0.95
    worst = r"not unit length at 2 of 16 texels \(worst \|n\| = 1\.1 at batch 0, row 1, column 2\)"
    with pytest.raises(MaterialError, match=worst):
        SVBRDF(**(SVBRDF.constant(size=4).maps() | {"normal": n}))


def test_normals_below_the_surface_are_an_error():
    n = torch.tensor([0.0, 0.6, -0.8]).view(1, 3, 1, 1).expand(1, 3, 4, 4)
    with pytest.raises(MaterialError, match=r"z < 0\) at 16 of 16 texels"):
        SVBRDF(**(SVBRDF.constant(size=4).maps() | {"normal": n}))


def test_render_tile_of_the_wrong_size_is_an_error():
    with pytest.raises(MaterialError, match=r"render tile must be \(B, 3, H, W\)"):
        SVBRDF(**SVBRDF.constant(size=4).maps(), render=torch.rand(1, 3, 5, 5))


def test_check_false_skips_validation_and_validate_catches_it_later():
    maps = SVBRDF.constant(size=4).maps() | {"roughness": torch.full((1, 1, 4, 4), 2.0)}
    m = SVBRDF(**maps, check=False)
    with pytest.raises(MaterialError, match="roughness map must lie in"):
        m.validate()


def test_validation_keeps_gradients():
    leaves = {k: v.clone().requires_grad_() for k, v in _material(4).maps().items()}
    m = SVBRDF(**leaves)
    loss = m.encoded().square().sum() + m.normal[:, 2].sum()
    loss.backward()
    for k, v in leaves.items():
        assert v.grad is not None and torch.isfinite(v.grad).all() and v.grad.abs().sum() > 0, k


def test_unbatched_maps_get_a_batch_dimension():
    m = SVBRDF(normal=torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1).expand(3, 4, 5), diffuse=torch.rand(3, 4, 5),
               roughness=torch.rand(1, 4, 5), specular=torch.rand(3, 4, 5))
    assert m.batch_size == 1 and m.resolution == (4, 5) and m.roughness.shape == (1, 1, 4, 5)


def test_equal_three_channel_roughness_keeps_the_first_channel():
    r = torch.rand(1, 1, 4, 4)
    r3 = r.expand(1, 3, 4, 4) + torch.tensor([0, 0.5 / 255, 0]).view(1, 3, 1, 1)  # within quantisation
    m = SVBRDF(**(SVBRDF.constant(size=4).maps() | {"roughness": r3}))
    assert torch.equal(m.roughness, r)


def test_unequal_three_channel_roughness_is_an_error():
    r = torch.rand(1, 3, 4, 4)
    with pytest.raises(MaterialError, match="roughness map given with 3 channels that differ"):
        SVBRDF(**(SVBRDF.constant(size=4).maps() | {"roughness": r}))


# ---- encoded form, constants and batch operations ------------------------------------------------


def test_encode_decode_round_trip_with_and_without_batch():
    m = _material(6, batch=2)
    enc = m.encoded()
    assert enc.shape == (2, 10, 6, 6) and enc.min() >= 0 and enc.max() <= 1
    torch.testing.assert_close(enc[:, 0:3], (m.normal + 1) / 2)
    torch.testing.assert_close(enc[:, 6:7], m.roughness)
    for t in (enc, enc[1]):
        dec = decode_maps(t)
        assert all(d.ndim == t.ndim for d in dec)
        torch.testing.assert_close(encode_maps(*dec), t)
    _assert_maps_close(SVBRDF.from_encoded(enc), m, atol=1e-6)


def test_decode_renormalises_the_normal():
    enc = SVBRDF.constant(size=2).encoded()
    enc[:, 0:3] = torch.tensor([0.5, 0.5, 0.9]).view(1, 3, 1, 1)  # (0, 0, 0.8) before renormalising
    torch.testing.assert_close(decode_maps(enc)[0], torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, 2, 2))


def test_decode_rejects_the_wrong_channel_count():
    with pytest.raises(MaterialError, match=r"\(B, 10, H, W\).*\(1, 9, 2, 2\)"):
        decode_maps(torch.zeros(1, 9, 2, 2))


def test_constant_material_fills_every_map():
    m = SVBRDF.constant(normal=(0, 1, 1), diffuse=(0.8, 0.5, 0.2), roughness=0.3, specular=0.04, size=(4, 6), batch=2)
    assert m.batch_size == 2 and m.resolution == (4, 6) and m.dtype == torch.float32
    torch.testing.assert_close(m.normal[1, :, 3, 5], torch.tensor([0.0, 2 ** -0.5, 2 ** -0.5]))
    torch.testing.assert_close(m.diffuse[0, :, 0, 0], torch.tensor([0.8, 0.5, 0.2]))
    assert m.roughness.shape == (2, 1, 4, 6) and float(m.roughness[0, 0, 0, 0]) == pytest.approx(0.3)
    torch.testing.assert_close(m.specular, torch.full((2, 3, 4, 6), 0.04))


def test_batch_selection_concatenation_and_iteration():
    a, b = _material(seed=1), _material(seed=2)
    both = SVBRDF.cat([a, b])
    assert len(both) == 2 and both.batch_size == 2
    assert torch.equal(both[1].diffuse, b.diffuse) and torch.equal(both[-1].diffuse, b.diffuse)
    assert both[0:1].batch_size == 1 and both[[1, 0]].batch_size == 2
    assert [s.batch_size for s in both] == [1, 1]
    with pytest.raises(IndexError):
        both[2]
    with pytest.raises(MaterialError, match="different resolutions"):
        SVBRDF.cat([a, _material(4)])


def test_to_detach_and_requires_grad():
    m = _material(4).requires_grad_()
    assert all(t.requires_grad for t in m.maps().values())
    d = m.detach()
    assert not any(t.requires_grad for t in d.maps().values())
    m64 = m.to(torch.float64)
    assert m64.dtype == torch.float64 and m64.device == torch.device("cpu")
    assert all(t.dtype == torch.float64 for t in m64.maps().values())


def test_resizing_down_averages_texel_areas():
    m = SVBRDF.constant(size=4)
    m.diffuse[..., :2] = 0.0
    m.diffuse[..., 2:] = 1.0
    small = m.resized(2)
    assert small.resolution == (2, 2)
    assert torch.allclose(small.diffuse[0, 0], torch.tensor([[0.0, 1.0], [0.0, 1.0]]))


def test_resizing_keeps_unit_normals_and_the_name():
    n = torch.randn(1, 3, 8, 8)
    n[:, 2] = n[:, 2].abs() + 1
    m = SVBRDF(normal=n / n.norm(dim=1, keepdim=True), diffuse=torch.rand(1, 3, 8, 8),
                  roughness=torch.rand(1, 1, 8, 8), specular=torch.rand(1, 3, 8, 8), name="x")
    for size in (4, 12, (6, 10)):
        r = m.resized(size)
        assert torch.allclose(r.normal.norm(dim=1), torch.ones(1, *r.resolution), atol=1e-5)
        assert r.name == "x"
    assert m.resized((6, 10)).resolution == (6, 10)


def test_resizing_to_the_same_size_is_the_material_itself():
    m = SVBRDF.constant(size=4)
    assert m.resized(4) is m


def test_texel_resampling_keeps_the_leading_dimensions():
    images = torch.rand(2, 5, 3, 8, 8)  # (B, P, 3, H, W)
    small = resample_texels(images, (4, 4))
    assert small.shape == (2, 5, 3, 4, 4)
    assert torch.allclose(small[1, 3, 2, 0, 0], images[1, 3, 2, :2, :2].mean())
    assert resample_texels(small, (8, 8)).shape == (2, 5, 3, 8, 8)
    assert resample_texels(images, (8, 8)) is images


def test_resizing_to_no_texels_is_refused():
    with pytest.raises(MaterialError, match="0x0"):
        SVBRDF.constant(size=4).resized(0)
