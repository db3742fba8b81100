"""SVBRDF container and files: formats, round trips, the shared samples, and clear errors."""

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import mitsvbrdf as ms
from mitsvbrdf import imageio
from mitsvbrdf.errors import ImageFileError, MaterialError

from conftest import textured_material

SAMPLES = Path(__file__).resolve().parents[2] / "shared" / "data" / "svbrdf_samples"
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "materials" / "artificial_0.png"


def test_bundled_example_loads_as_a_256px_material():
    m = ms.SVBRDF.load(EXAMPLE)
    assert m.resolution == (256, 256) and m.batch_size == 1
    assert m.normal[:, 2].mean() > 0.8 and m.render is None


@pytest.mark.skipif(not SAMPLES.is_dir(), reason="shared samples not present")
@pytest.mark.parametrize("k", range(4))
def test_shared_samples_load_with_the_right_tile_order(k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # samples 1 and 3 warn about non-unit normals (tested below)
        m = ms.SVBRDF.load(SAMPLES / f"{k}_svbrdf.png")
    assert m.normal[:, 2].mean() > 0.8  # the first tile decodes to outward normals
    raw = np.asarray(Image.open(SAMPLES / f"{k}_svbrdf.png"), dtype=np.float32) / 255
    torch.testing.assert_close(m.roughness[0, 0], torch.from_numpy(raw[:, 512:768, 0]))
    torch.testing.assert_close(m.diffuse[0], torch.from_numpy(raw[:, 256:512]).permute(2, 0, 1))


def test_sample_with_non_unit_normals_warns_and_strict_raises():
    path = SAMPLES / "1_svbrdf.png"
    if not path.is_file():
        pytest.skip("shared samples not present")
    with pytest.warns(UserWarning, match="1_svbrdf.png"):
        m = ms.SVBRDF.load(path)
    torch.testing.assert_close(m.normal.norm(dim=1), torch.ones(1, 256, 256))
    with pytest.raises(MaterialError, match="1_svbrdf.png"):
        ms.SVBRDF.load(path, strict=True)


@pytest.mark.parametrize("name", ["m.png", "m.exr", "m_folder"])
def test_round_trip_through_every_format(tmp_path, name):
    m = textured_material(8)
    m.save(tmp_path / name)
    back = ms.SVBRDF.load(tmp_path / name)
    tol = 0 if name.endswith(".exr") else 2 / 255
    for k in ("normal", "diffuse", "roughness", "specular"):
        torch.testing.assert_close(getattr(back, k), getattr(m, k), atol=tol + 1e-6, rtol=0)


def test_five_tile_strip_keeps_the_render_tile(tmp_path):
    m = textured_material(8)
    render = torch.rand(1, 3, 8, 8)
    ms.SVBRDF(**m.maps(), render=render).save(tmp_path / "d.png")
    back = ms.SVBRDF.load(tmp_path / "d.png")
    assert back.render.shape == (1, 3, 8, 8)
    torch.testing.assert_close(back.render, render, atol=1 / 255, rtol=0)


def test_encode_decode_round_trip():
    m = textured_material(6)
    enc = m.encoded()
    assert enc.shape == (1, 10, 6, 6) and enc.min() >= 0 and enc.max() <= 1
    back = ms.SVBRDF.from_encoded(enc)
    torch.testing.assert_close(back.normal, m.normal)
    torch.testing.assert_close(ms.encode_maps(*ms.decode_maps(enc[0])), enc[0])


def test_sixteen_bit_and_palette_pngs_load(tmp_path):
    m = textured_material(8)
    enc = m.encoded()[0]
    strip = torch.cat([enc[0:3], enc[3:6], enc[6:7].expand(3, -1, -1), enc[7:10]], dim=2).permute(1, 2, 0).numpy()
    imageio.write_png(tmp_path / "s16.png", strip, bits=16)
    back = ms.SVBRDF.load(tmp_path / "s16.png")
    torch.testing.assert_close(back.diffuse, m.diffuse, atol=1e-4, rtol=0)
    Image.fromarray((strip * 255).round().astype(np.uint8)).convert("P", palette=Image.ADAPTIVE).save(tmp_path / "p.png")
    pal = ms.SVBRDF.load(tmp_path / "p.png")
    assert pal.resolution == (8, 8)


def test_constant_material_and_batch_operations():
    a = ms.SVBRDF.constant(diffuse=(0.8, 0.5, 0.2), roughness=0.3, size=(4, 6))
    assert a.diffuse.shape == (1, 3, 4, 6) and a.roughness.shape == (1, 1, 4, 6)
    both = ms.SVBRDF.cat([a, a])
    assert len(both) == 2 and both[1].batch_size == 1


def test_validation_keeps_gradients():
    d = torch.full((1, 3, 4, 4), 0.5, requires_grad=True)
    m = ms.SVBRDF(normal=ms.SVBRDF.constant(size=4).normal, diffuse=d, roughness=torch.full((1, 1, 4, 4), 0.5),
                  specular=torch.full((1, 3, 4, 4), 0.04))
    m.diffuse.sum().backward()
    assert d.grad is not None


@pytest.mark.parametrize("change,match", [
    (dict(diffuse=torch.rand(1, 2, 4, 4)), r"diffuse map must be \(B, 3, H, W\)"),
    (dict(specular=torch.rand(1, 3, 5, 4)), "sizes must match"),
    (dict(diffuse=torch.full((1, 3, 4, 4), float("nan"))), "NaN"),
    (dict(roughness=torch.full((1, 1, 4, 4), 1.5)), r"roughness map must lie in \[0, 1\]"),
    (dict(normal=torch.full((1, 3, 4, 4), 0.9)), "not unit length"),
    (dict(normal=torch.tensor([0.0, 0.0, -1.0]).view(1, 3, 1, 1).expand(1, 3, 4, 4)), "z < 0"),
])
def test_bad_maps_are_clear_errors(change, match):
    maps = ms.SVBRDF.constant(size=4).maps()
    maps.update(change)
    with pytest.raises(MaterialError, match=match):
        ms.SVBRDF(**maps)


def test_wrong_strip_width_names_the_file(tmp_path):
    imageio.write_png(tmp_path / "w.png", np.zeros((8, 24, 3)))
    with pytest.raises(MaterialError, match=r"w\.png.*4 or 5 square tiles"):
        ms.SVBRDF.load(tmp_path / "w.png")


def test_truncated_png_and_exr_are_clear_errors(tmp_path):
    m = textured_material(16)
    for name in ("t.png", "t.exr"):
        m.save(tmp_path / name)
        data = (tmp_path / name).read_bytes()
        (tmp_path / name).write_bytes(data[: len(data) // 2])
        with pytest.raises(ImageFileError, match=name.replace(".", r"\.")):
            ms.SVBRDF.load(tmp_path / name)


def test_text_file_named_png_and_missing_paths_are_clear_errors(tmp_path):
    (tmp_path / "notes.png").write_text("not an image")
    with pytest.raises(ImageFileError, match="notes.png"):
        ms.SVBRDF.load(tmp_path / "notes.png")
    with pytest.raises(ImageFileError, match="no such file"):
        ms.SVBRDF.load(tmp_path / "absent.png")
    (tmp_path / "folder").mkdir()
    with pytest.raises(ImageFileError, match="missing the normal map"):
        ms.SVBRDF.load(tmp_path / "folder")


def test_folder_with_mismatched_map_sizes_is_a_clear_error(tmp_path):
    textured_material(8).save(tmp_path / "f")
    imageio.write_png(tmp_path / "f" / "specular.png", np.zeros((4, 4, 3)))
    with pytest.raises(MaterialError, match="differ in size"):
        ms.SVBRDF.load(tmp_path / "f")


def test_saving_a_batch_to_one_path_is_refused(tmp_path):
    with pytest.raises(MaterialError, match="one material"):
        ms.SVBRDF.cat([textured_material(4), textured_material(4)]).save(tmp_path / "x.png")


def test_exr_images_round_trip_exactly(tmp_path):
    a = np.random.default_rng(0).random((5, 7, 3)).astype(np.float32) * 10
    imageio.write_exr(tmp_path / "a.exr", a)
    np.testing.assert_array_equal(imageio.read_image(tmp_path / "a.exr"), a)
