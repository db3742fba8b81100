"""Export of a material for use elsewhere: a Mitsuba scene, and glTF 2.0 PBR texture maps.

**Mitsuba** (:func:`export_mitsuba_scene`): the four maps as linear EXR (normals as raw tangent-
space vectors, roughness one channel) and ``scene.xml`` with the project's ``svbrdf_ggx`` BSDF on
the sample rectangle, the rig's camera, and point lights; it re-renders the material exactly as
this project models it. Register the plugins before loading it::

    import mitsuba as mi, mitsvbrdf_plugins
    mitsvbrdf_plugins.register()
    image = mi.render(mi.load_file("out/scene.xml"))

**glTF** (:func:`export_gltf`): ``material.gltf`` (a 6 cm quad with the material, buffers embedded)
and PNG maps, converted as follows (glTF metallic-roughness + ``KHR_materials_specular``):

* baseColor = kd (sRGB-encoded PNG, as glTF requires), metallic = 0;
* roughness = r, unchanged: glTF's GGX alpha is roughness^2 as here (G channel of
  metallicRoughness.png, linear);
* specular: F0 = 0.04 * specularColor, so specularColorTexture = ks (sRGB-encoded) with
  specularColorFactor = 25 gives F0 = ks;
* normal = (n + 1) / 2, tangent space with +Y up (glTF's convention, and this project's).

What the conversion cannot carry: glTF's diffuse is weighted by 1 - F(v.h) per light instead of
(1 - ks); its masking is the height-correlated Smith GGX instead of Smith-Schlick with
k = alpha / 2; and its Fresnel is Schlick's power form instead of the spherical-Gaussian one. All
three differ most at grazing angles.
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np

from . import imageio
from .rig import Rig
from .svbrdf import SVBRDF
from .viewing import srgb_encode


def _single(svbrdf: SVBRDF) -> SVBRDF:
    if svbrdf.batch_size != 1:
        raise ValueError(f"export writes one material; got a batch of {svbrdf.batch_size} (index it first)")
    return svbrdf.detach().to("cpu")


def _hwc(t) -> np.ndarray:
    return t[0].permute(1, 2, 0).float().numpy()


def export_mitsuba_scene(svbrdf: SVBRDF, out_dir: str | Path, rig: Rig | None = None,
                         lights: np.ndarray | None = None, intensity: float = 0.01,
                         resolution: int = 256, spp: int = 64) -> Path:
    """Write the maps (EXR) and ``scene.xml`` into ``out_dir``; returns the scene's path.

    ``lights``: (L, 3) point-light positions in metres (default: one at 25 cm above the sample,
    offset towards the camera's side); ``intensity`` in W/sr.
    """
    m = _single(svbrdf)
    rig = rig or Rig.from_scene()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name in ("normal", "diffuse", "roughness", "specular"):
        imageio.write_exr(out / f"{name}.exr", _hwc(getattr(m, name)))
    if lights is None:
        lights = np.array([[0.05, 0.0, 0.25]])
    cam = rig.camera_position_np()
    half = rig.sample_size / 2
    emitters = "\n".join(
        f'    <emitter type="point">\n        <point name="position" x="{p[0]:.6g}" y="{p[1]:.6g}" z="{p[2]:.6g}"/>\n'
        f'        <rgb name="intensity" value="{intensity:.6g}"/>\n    </emitter>' for p in np.asarray(lights))
    h, w = m.resolution
    to_world = " ".join(f"{v:.9g}" for v in rig.sample_to_world().ravel())  # off the origin for a Rig.window
    xml = f"""<!-- Written by mitsvbrdf.export: the material {m.name or ''} on the {rig.sample_size * 100:g} cm sample.
     Needs the project's plugins: import mitsvbrdf_plugins; mitsvbrdf_plugins.register() -->
<scene version="3.0.0">
    <default name="resolution" value="{resolution}"/>
    <default name="spp" value="{spp}"/>
    <integrator type="direct"/>
    <sensor type="perspective">
        <float name="fov" value="{_fov_deg(cam, half):.6g}"/>
        <transform name="to_world">
            <lookat origin="{cam[0]:.9g}, {cam[1]:.9g}, {cam[2]:.9g}" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="$resolution"/>
            <integer name="height" value="$resolution"/>
        </film>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    </sensor>
    <shape type="rectangle" id="sample">
        <transform name="to_world"><matrix value="{to_world}"/></transform>
        <bsdf type="svbrdf_ggx" id="material">
            <!-- {h}x{w} texels, linear values as used by the BRDF -->
            <string name="normal" value="normal.exr"/>
            <string name="diffuse" value="diffuse.exr"/>
            <string name="roughness" value="roughness.exr"/>
            <string name="specular" value="specular.exr"/>
        </bsdf>
    </shape>
{emitters}
</scene>
"""
    path = out / "scene.xml"
    path.write_text(xml)
    return path


def _fov_deg(cam: np.ndarray, half: float) -> float:
    """Field of view that frames the sample square (plus 10%) from the camera."""
    d = float(np.linalg.norm(cam))
    return float(np.degrees(2.0 * np.arctan(1.1 * half * np.sqrt(2.0) / d)))


def export_gltf(svbrdf: SVBRDF, out_dir: str | Path, sample_size: float = 0.06) -> Path:
    """Write glTF PNG maps and ``material.gltf`` (a quad of ``sample_size`` metres) into ``out_dir``."""
    m = _single(svbrdf)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rough = _hwc(m.roughness)[..., 0]
    mr = np.stack([np.zeros_like(rough), rough, np.zeros_like(rough)], -1)
    maps = {"baseColor.png": srgb_encode(_hwc(m.diffuse)), "metallicRoughness.png": mr,
            "normal.png": (_hwc(m.normal) + 1.0) / 2.0, "specularColor.png": srgb_encode(_hwc(m.specular))}
    for name, a in maps.items():
        imageio.write_png(out / name, np.clip(a, 0.0, 1.0))
    path = out / "material.gltf"
    path.write_text(json.dumps(_gltf_document(sample_size), indent=1))
    return path


def _gltf_document(size: float) -> dict:
    h = size / 2
    # glTF UV (0, 0) is the image's top-left: row 0 of the maps, at +y on the sample.
    pos = [(-h, -h, 0.0), (h, -h, 0.0), (h, h, 0.0), (-h, h, 0.0)]
    uv = [(0.0, 1.0), (1.0, 1.0), (1.0, 0.0), (0.0, 0.0)]
    nrm = [(0.0, 0.0, 1.0)] * 4
    tan = [(1.0, 0.0, 0.0, 1.0)] * 4
    idx = [0, 1, 2, 0, 2, 3]
    blobs = [b"".join(struct.pack("<3f", *p) for p in pos), b"".join(struct.pack("<3f", *n) for n in nrm),
             b"".join(struct.pack("<4f", *t) for t in tan), b"".join(struct.pack("<2f", *t) for t in uv),
             struct.pack("<6H", *idx) + b"\0\0"]
    views, offset = [], 0
    for b in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(b)})
        offset += len(b)
    data = b"".join(blobs)
    acc = [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-h, -h, 0.0], "max": [h, h, 0.0]},
           {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
           {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC4"},
           {"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC2"},
           {"bufferView": 4, "componentType": 5123, "count": 6, "type": "SCALAR"}]
    images = ["baseColor.png", "metallicRoughness.png", "normal.png", "specularColor.png"]
    return {
        "asset": {"version": "2.0", "generator": "mitsvbrdf.export"},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": "sample"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TANGENT": 2, "TEXCOORD_0": 3},
                                    "indices": 4, "material": 0}]}],
        "materials": [{
            "name": "mitsvbrdf",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0, "roughnessFactor": 1.0,
                                     "metallicRoughnessTexture": {"index": 1}},
            "normalTexture": {"index": 2},
            "extensions": {"KHR_materials_specular": {"specularFactor": 1.0, "specularColorFactor": [25.0, 25.0, 25.0],
                                                      "specularColorTexture": {"index": 3}}}}],
        "textures": [{"source": i} for i in range(len(images))],
        "images": [{"uri": n} for n in images],
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}],
        "bufferViews": views, "accessors": acc,
    }
