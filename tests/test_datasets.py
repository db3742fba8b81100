"""Augmentations keep the reflectance physics right; datasets read strips, folders and the
procedural stream deterministically; bad files give clear errors."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from torch.utils.data import DataLoader

import mitsvbrdf as ms
from mitsvbrdf import imageio
from mitsvbrdf.data import augment as aug
from mitsvbrdf.data.datasets import (MapFolderDataset, ProceduralDataset, StripDataset, collate, collate_svbrdf,
                                     strip_layout, to_svbrdf)
from mitsvbrdf.data.procedural import generate, height_to_normal
from mitsvbrdf.errors import ImageFileError, MaterialError

from conftest import SAMPLES, needs_samples

MAPS = ("normal", "diffuse", "roughness", "specular")
# the square's 8 symmetries as (k, hflip), plus a lone vertical flip
SYMMETRIES = [(k, h, False) for k in range(4) for h in (False, True)] + [(0, False, True), (1, False, True)]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def bumpy() -> dict[str, torch.Tensor]:
    """Two strongly relieved materials (stones, hammered metal) at 24 px: normals far from +z."""
    m = generate(2, size=24, seed=1, families=["stones", "hammered_metal"], bump=3.0)
    assert (m.normal[:, 2] < 0.95).float().mean() > 0.2
    return m.maps()


def _reflectance(maps: dict[str, torch.Tensor], wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """f(wi, wo) n.wi per texel, (B, 3, H, W), for one pair of tangent-frame directions."""
    return ms.brdf(maps["normal"], wi.view(1, 3, 1, 1), wo.view(1, 3, 1, 1), maps["diffuse"], maps["specular"],
                   maps["roughness"], cosine=True, dim=-3)


# ---- augmentation physics ------------------------------------------------------------------------


@pytest.mark.parametrize("k,hflip,vflip", SYMMETRIES)
def test_transformed_material_under_transformed_light_reflects_the_transformed_image(bumpy, k, hflip, vflip):
    wi = torch.nn.functional.normalize(torch.tensor([0.45, 0.3, 0.84]), dim=0)
    wo = torch.nn.functional.normalize(torch.tensor([-0.2, 0.35, 0.91]), dim=0)
    before = _reflectance(bumpy, wi, wo)
    moved = aug.transform_maps(bumpy, k=k, hflip=hflip, vflip=vflip)
    after = _reflectance(moved, aug.transform_directions(wi, k=k, hflip=hflip, vflip=vflip),
                         aug.transform_directions(wo, k=k, hflip=hflip, vflip=vflip))
    torch.testing.assert_close(after, aug.transform_image(before, k=k, hflip=hflip, vflip=vflip), atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("k,hflip,vflip", [(1, False, False), (0, True, False), (0, False, True), (3, True, False)])
def test_moving_normals_as_pixels_only_breaks_that_equality(bumpy, k, hflip, vflip):
    """The control that makes the test above meaningful: skip the vector transform and it fails."""
    wi = torch.nn.functional.normalize(torch.tensor([0.45, 0.3, 0.84]), dim=0)
    wo = torch.nn.functional.normalize(torch.tensor([-0.2, 0.35, 0.91]), dim=0)
    before = _reflectance(bumpy, wi, wo)
    wrong = {key: aug.transform_image(t, k=k, hflip=hflip, vflip=vflip) for key, t in bumpy.items()}
    after = _reflectance(wrong, aug.transform_directions(wi, k=k, hflip=hflip, vflip=vflip),
                         aug.transform_directions(wo, k=k, hflip=hflip, vflip=vflip))
    err = (after - aug.transform_image(before, k=k, hflip=hflip, vflip=vflip)).abs().max()
    assert err > 0.05 * before.abs().max()


@pytest.mark.parametrize("k,hflip,vflip", SYMMETRIES)
def test_normals_of_a_moved_height_field_equal_the_moved_normals(k, hflip, vflip):
    g = torch.Generator().manual_seed(0)
    h = torch.nn.functional.avg_pool2d(torch.rand(1, 1, 20, 20, generator=g), 3, 1, 1)[:, 0] * 0.05
    n_of_moved = height_to_normal(aug.transform_image(h, k=k, hflip=hflip, vflip=vflip))
    moved_n = aug.transform_normal(height_to_normal(h), k=k, hflip=hflip, vflip=vflip)
    torch.testing.assert_close(n_of_moved, moved_n, atol=1e-6, rtol=0)


def test_rotation_by_one_quarter_turns_normals_counter_clockwise():
    n = torch.tensor([1.0, 0.0, 0.0]).view(3, 1, 1).expand(3, 2, 2)  # every normal points right
    out = aug.transform_normal(n, k=1)
    torch.testing.assert_close(out[:, 0, 0], torch.tensor([0.0, 1.0, 0.0]))  # now up
    img = torch.arange(4.0).view(1, 2, 2)  # [[0, 1], [2, 3]]: the top-right 1 goes to the top-left
    assert aug.transform_image(img, k=1)[0, 0, 0] == 1


def test_random_augment_is_reproducible_and_keeps_maps_valid(bumpy):
    one = {k: v[0] for k, v in bumpy.items()}
    a = aug.Augment(crop=16, albedo_jitter=0.2, roughness_jitter=0.3)
    x = a(one, torch.Generator().manual_seed(3))
    y = a(one, torch.Generator().manual_seed(3))
    for k in MAPS:
        assert torch.equal(x[k], y[k]) and x[k].shape[-2:] == (16, 16)
    ms.SVBRDF(**{k: x[k] for k in MAPS}).validate()
    outs = {tuple(a(one, torch.Generator().manual_seed(s))["normal"][:, 0, 0].tolist()) for s in range(12)}
    assert len(outs) > 3  # different draws differ


def test_crop_that_does_not_fit_raises():
    m = generate(1, size=16).maps()
    with pytest.raises(MaterialError, match="does not fit"):
        aug.crop_maps(m, 4, 4, 16)
    with pytest.raises(MaterialError, match="larger"):
        aug.Augment(crop=32)({k: v[0] for k, v in m.items()})


# ---- procedural dataset ----------------------------------------------------------------------------


def test_procedural_item_i_is_material_i_of_the_stream():
    ds = ProceduralDataset(10, size=24, seed=4)
    stream = generate(10, size=24, seed=4)
    item = ds[7]
    torch.testing.assert_close(item["normal"], stream.normal[7], atol=1e-6, rtol=0)
    assert item["index"] == 7 and item["name"] == "procedural:4:7"
    assert torch.equal(ProceduralDataset(10, size=24, seed=4)[7]["diffuse"], item["diffuse"])
    with pytest.raises(IndexError):
        ds[10]


def test_procedural_dataloader_batches_equal_single_items():
    ds = ProceduralDataset(6, size=16, seed=2, augment=aug.Augment())
    batch = next(iter(DataLoader(ds, batch_size=3)))
    assert batch["normal"].shape == (3, 3, 16, 16) and batch["index"].tolist() == [0, 1, 2]
    torch.testing.assert_close(batch["normal"][1], ds[1]["normal"], atol=1e-6, rtol=0)
    svb = next(iter(DataLoader(ds, batch_size=2, collate_fn=collate_svbrdf)))
    assert isinstance(svb, ms.SVBRDF) and svb.batch_size == 2
    ds.set_epoch(1)
    changed = any(not torch.equal(ds[i]["normal"], batch["normal"][i]) for i in range(3))
    assert changed  # a new epoch draws new flips/rotations


# ---- strips ----------------------------------------------------------------------------------------


@needs_samples
def test_shared_samples_load_through_the_strip_dataset_in_tile_order():
    ds = StripDataset(SAMPLES, crop=None)
    assert [p.name for p in ds.paths] == [f"{k}_svbrdf.png" for k in range(4)]  # README/LICENSE ignored
    for k in range(4):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # two samples hold non-unit normals (the loader warns)
            item = ds[k]
        raw = np.asarray(Image.open(SAMPLES / f"{k}_svbrdf.png"), dtype=np.float32) / 255
        tiles = [torch.from_numpy(raw[:, i * 256:(i + 1) * 256]).permute(2, 0, 1) for i in range(4)]
        assert item["normal"][2].mean() > 0.8  # tile 0 decodes to outward normals
        torch.testing.assert_close(item["diffuse"], tiles[1])
        torch.testing.assert_close(item["roughness"], tiles[2][:1])
        torch.testing.assert_close(item["specular"], tiles[3])
        assert item["name"] == f"{k}_svbrdf" and "render" not in item


@needs_samples
def test_shared_samples_batch_through_a_dataloader_with_random_crops():
    ds = StripDataset(SAMPLES, crop=128, augment=aug.Augment())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        svb = next(iter(DataLoader(ds, batch_size=4, collate_fn=collate_svbrdf)))
    assert svb.batch_size == 4 and svb.resolution == (128, 128)


def _ramp_material(size: int) -> ms.SVBRDF:
    """Diffuse red = column / (size - 1), green = row / (size - 1): a crop tells where it came from."""
    m = generate(1, size=size, seed=9)
    t = torch.arange(size, dtype=torch.float32) / (size - 1)
    diffuse = torch.stack([t.view(1, -1).expand(size, size), t.view(-1, 1).expand(size, size),
                           torch.full((size, size), 0.5)]).unsqueeze(0)
    return ms.SVBRDF(normal=m.normal, diffuse=diffuse, roughness=m.roughness, specular=m.specular,
                     render=torch.rand(1, 3, size, size, generator=torch.Generator().manual_seed(0)))


def test_five_tile_288px_strips_give_random_256px_windows_with_their_render(tmp_path):
    full = _ramp_material(288)
    full.save(tmp_path / "a.png", bits=16)
    full.save(tmp_path / "b.png", bits=16)
    ds = StripDataset(tmp_path, crop=256, seed=1)
    assert strip_layout(tmp_path / "a.png") == (5, 288)
    offsets = set()
    for epoch in range(3):
        ds.set_epoch(epoch)
        for i in range(2):
            item = ds[i]
            assert item["normal"].shape == (3, 256, 256) and item["render"].shape == (3, 256, 256)
            left = round(float(item["diffuse"][0, 0, 0]) * 287)
            top = round(float(item["diffuse"][1, 0, 0]) * 287)
            window = aug.crop_maps({**full.maps(), "render": full.render}, top, left, 256)
            for k in (*MAPS, "render"):
                torch.testing.assert_close(item[k], window[k][0], atol=2e-4, rtol=0)
            offsets.add((top, left))
    assert len(offsets) > 2
    again = StripDataset(tmp_path, crop=256, seed=1)
    again.set_epoch(2)
    assert torch.equal(again[1]["normal"], ds[1]["normal"])  # same seed and epoch: same crop


def test_centre_crop_and_four_tile_strips(tmp_path):
    full = _ramp_material(40)
    ms.SVBRDF(**full.maps()).save(tmp_path / "m.png", bits=16)
    item = StripDataset(tmp_path, crop=32, random_crop=False)[0]
    assert round(float(item["diffuse"][0, 0, 0]) * 39) == 4 and "render" not in item


def test_map_folders_load_as_materials(tmp_path):
    mats = generate(2, size=20, seed=3)
    for i in range(2):
        mats[i].save(tmp_path / f"mat{i}")
    (tmp_path / "notes.txt").write_text("not a material")
    ds = MapFolderDataset(tmp_path, crop=16)
    assert len(ds) == 2 and ds[1]["name"] == "mat1" and ds[0]["normal"].shape == (3, 16, 16)
    whole = MapFolderDataset(tmp_path)[0]
    torch.testing.assert_close(whole["diffuse"], mats.diffuse[0], atol=1 / 255, rtol=0)


# ---- bad input ---------------------------------------------------------------------------------------


def test_strip_of_the_wrong_width_is_named_or_skipped(tmp_path):
    imageio.write_png(tmp_path / "good.png", np.full((8, 32, 3), 0.5, np.float32))
    imageio.write_png(tmp_path / "wide.png", np.full((8, 30, 3), 0.5, np.float32))
    with pytest.raises(MaterialError, match="wide.png.*4 or 5 square tiles"):
        StripDataset(tmp_path, crop=None)
    with pytest.warns(UserWarning, match="wide.png"):
        ds = StripDataset(tmp_path, crop=None, skip_bad=True)
    assert [p.name for p in ds.paths] == ["good.png"]
    with pytest.raises(MaterialError, match="wide.png"):  # unchecked, the error comes at load time
        StripDataset(tmp_path, crop=None, check=False)[1]


def test_non_image_file_with_an_image_name_gives_an_image_file_error(tmp_path):
    (tmp_path / "fake.png").write_text("this is text, not a PNG")
    with pytest.raises(ImageFileError, match="fake.png"):
        StripDataset(tmp_path)
    with pytest.raises(ImageFileError, match="fake.png"):
        StripDataset(tmp_path, check=False)[0]
    with pytest.raises(ImageFileError, match="no strip images"):
        StripDataset(_empty(tmp_path))  # README.md and the like are not strips


def _empty(tmp_path: Path) -> Path:
    d = tmp_path / "empty"
    d.mkdir()
    (d / "README.md").write_text("no images here")
    return d


def test_sixteen_bit_and_palette_strips_load_with_their_values(tmp_path):
    m = generate(1, size=8, seed=5)
    m.save(tmp_path / "deep.png", bits=16)
    item = StripDataset(tmp_path, crop=None)[0]
    torch.testing.assert_close(item["diffuse"], m.diffuse[0], atol=1e-4, rtol=0)
    (tmp_path / "deep.png").unlink()
    strip = np.concatenate([np.full((8, 8, 3), v, np.float32) for v in (0.5, 0.2, 0.6, 0.04)], axis=1)
    strip[..., :8, :] = (0.5, 0.5, 1.0)  # normal tile: +z
    Image.fromarray(np.round(strip * 255).astype(np.uint8)).convert("P", palette=Image.Palette.ADAPTIVE,
                                                                     colors=8).save(tmp_path / "pal.png")
    with Image.open(tmp_path / "pal.png") as im:
        assert im.mode == "P"
    item = StripDataset(tmp_path, crop=None)[0]
    torch.testing.assert_close(item["diffuse"], torch.full((3, 8, 8), 0.2), atol=1 / 255, rtol=0)
    torch.testing.assert_close(item["normal"][2], torch.ones(8, 8), atol=1e-3, rtol=0)


def test_collate_rejects_mixed_sizes_and_builds_svbrdfs():
    a = ProceduralDataset(2, size=8)
    b = ProceduralDataset(2, size=12)
    with pytest.raises(MaterialError, match="different sizes"):
        collate([a[0], b[0]])
    batch = collate([a[0], a[1]])
    assert batch["index"].tolist() == [0, 1] and isinstance(to_svbrdf(batch), ms.SVBRDF)
