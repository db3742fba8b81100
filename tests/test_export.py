"""Export of materials: a Mitsuba scene that re-renders them, and glTF PBR maps."""

import json
import struct
import base64

import numpy as np
import pytest

from mitsvbrdf import backend, imageio
from mitsvbrdf.export import export_gltf, export_mitsuba_scene
from mitsvbrdf.svbrdf import SVBRDF

from conftest import textured_material


@pytest.fixture(scope="module")
def mi():
    if backend.find_libllvm() is None:  # pragma: no cover - depends on the machine
        pytest.skip("no libLLVM >= 16 for the LLVM backend")
    import mitsvbrdf_plugins

    return mitsvbrdf_plugins.register("llvm_ad_rgb")


def test_mitsuba_scene_carries_the_maps_exactly(mi, tmp_path, rig):
    m = textured_material(8)
    scene = mi.load_file(str(export_mitsuba_scene(m, tmp_path, rig, resolution=16, spp=4)))
    params = mi.traverse(scene)
    for name in ("normal", "diffuse", "roughness", "specular"):
        got = np.array(params[f"sample.bsdf.{name}"])
        want = getattr(m, name)[0].permute(1, 2, 0).numpy()
        np.testing.assert_array_equal(got, want, err_msg=name)


@pytest.mark.parametrize("window", [None, (16, 2, 9, 4)], ids=["whole", "window"])
def test_mitsuba_scene_places_the_sample_where_the_rig_has_it(mi, tmp_path, rig, window):
    r = rig if window is None else rig.window(*window)
    scene = mi.load_file(str(export_mitsuba_scene(textured_material(4), tmp_path, r, resolution=16, spp=4)))
    got = np.array(mi.traverse(scene)["sample.to_world"].matrix.numpy()).reshape(4, 4)
    np.testing.assert_allclose(got, r.sample_to_world(), rtol=1e-6, atol=1e-9)


def test_mitsuba_scene_renders_the_lit_material(mi, tmp_path, rig):
    scene = mi.load_file(str(export_mitsuba_scene(textured_material(8), tmp_path, rig, resolution=16, spp=4)))
    img = np.array(mi.render(scene))
    assert np.isfinite(img).all() and (img >= 0).all()
    assert img[6:10, 6:10].mean() > 0  # the sample fills the centre of the frame


def test_gltf_maps_encode_the_documented_conversion(tmp_path):
    m = textured_material(8)
    export_gltf(m, tmp_path)
    base = imageio.read_image(tmp_path / "baseColor.png")
    lin = np.where(base <= 0.04045, base / 12.92, ((base + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(lin, m.diffuse[0].permute(1, 2, 0).numpy(), atol=0.01)
    mr = imageio.read_image(tmp_path / "metallicRoughness.png")
    np.testing.assert_allclose(mr[..., 1], m.roughness[0, 0].numpy(), atol=0.5 / 255 + 1e-6)
    assert mr[..., 2].max() == 0.0  # dielectric
    nrm = imageio.read_image(tmp_path / "normal.png") * 2 - 1
    np.testing.assert_allclose(nrm, m.normal[0].permute(1, 2, 0).numpy(), atol=1.0 / 255 + 1e-6)


def test_gltf_document_is_self_consistent(tmp_path):
    doc = json.loads(export_gltf(textured_material(8), tmp_path).read_text())
    data = base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1])
    assert len(data) == doc["buffers"][0]["byteLength"]
    for view in doc["bufferViews"]:
        assert view["byteOffset"] + view["byteLength"] <= len(data)
    for image in doc["images"]:
        assert (tmp_path / image["uri"]).exists()
    spec = doc["materials"][0]["extensions"]["KHR_materials_specular"]
    assert spec["specularColorFactor"][0] * 0.04 == pytest.approx(1.0)  # F0 = ks
    # UV (0, 0), the image's top-left, sits at the sample's top-left corner (+y is up)
    uv_view, pos_view = doc["bufferViews"][3], doc["bufferViews"][0]
    uvs = struct.unpack("<8f", data[uv_view["byteOffset"]:uv_view["byteOffset"] + 32])
    pos = struct.unpack("<12f", data[pos_view["byteOffset"]:pos_view["byteOffset"] + 48])
    k = [i for i in range(4) if uvs[2 * i] == 0.0 and uvs[2 * i + 1] == 0.0][0]
    assert pos[3 * k] < 0 and pos[3 * k + 1] > 0


def test_export_refuses_a_batch(tmp_path):
    two = SVBRDF.cat([textured_material(4), textured_material(4, seed=1)])
    with pytest.raises(ValueError, match="batch of 2"):
        export_gltf(two, tmp_path)
