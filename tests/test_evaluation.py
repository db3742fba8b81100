"""Evaluation of acquisition methods: metrics per material, tables, figures and the HTML index."""

import csv

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.acquisition import Acquisition, FixedAcquisition
from mitsvbrdf.evaluation import Relighting, evaluate, paired, paired_difference, simulated, summarize
from mitsvbrdf.metrics import flat_normal_rmse

from conftest import textured_material


def _oracle(gt):
    """A method that returns the ground truth itself."""
    return Acquisition(torch.zeros(1, 3, 32, 32), torch.zeros(1, 3, *gt.resolution), gt)


def _flat(gt):
    """A method that returns a grey, flat material whatever it sees."""
    h, w = gt.resolution
    return Acquisition(torch.zeros(1, 3, 32, 32), torch.zeros(1, 3, h, w),
                   ms.SVBRDF.constant(diffuse=0.5, roughness=0.5, specular=0.04, size=(h, w)))


@pytest.fixture()
def relight(rig):
    return Relighting.make(rig, n_lights=3, n_edges=2)


def test_perfect_reconstruction_scores_zero_error_and_unit_ssim(rig, tmp_path, relight):
    rows = evaluate({"oracle": _oracle}, [textured_material(16)], rig, tmp_path, relight=relight,
                    figures=False, progress=False)
    r = rows[0]
    assert r["rmse_average"] == 0.0 and r["rerender_rmse"] == 0.0
    assert r["ssim"] == pytest.approx(1.0)


def test_a_worse_method_scores_worse_on_every_headline_metric(rig, tmp_path, relight):
    rows = evaluate({"oracle": _oracle, "flat": _flat}, [textured_material(16, seed=2)], rig, tmp_path,
                    relight=relight, figures=False, progress=False)
    s = {x["method"]: x for x in summarize(rows)}
    assert s["flat"]["rmse_average"] > s["oracle"]["rmse_average"]
    assert s["flat"]["rerender_rmse"] > s["oracle"]["rerender_rmse"]
    assert s["flat"]["ssim"] < s["oracle"]["ssim"]


def test_outputs_tables_figures_and_index(rig, tmp_path, relight):
    mats = [textured_material(16, seed=s) for s in range(2)]
    evaluate({"oracle": _oracle, "flat": _flat}, mats, rig, tmp_path, relight=relight, progress=False)
    with open(tmp_path / "metrics.csv") as f:
        assert len(list(csv.DictReader(f))) == 4
    md = (tmp_path / "summary.md").read_text()
    assert "| oracle |" in md and "Normal" in md and "LPIPS skipped" in md
    flat = sum(float(flat_normal_rmse(m)[0]) for m in mats) / 2
    assert f"A flat normal map scores normal RMSE {flat:.4f}" in md
    assert len(list((tmp_path / "figures").glob("*.png"))) == 2
    assert "figures/material_001.png" in (tmp_path / "index.html").read_text()


def test_the_summary_pairs_every_method_with_the_first(rig, tmp_path, relight):
    mats = [textured_material(16, seed=s) for s in range(2)]
    rows = evaluate({"oracle": _oracle, "flat": _flat}, mats, rig, tmp_path, relight=relight, figures=False,
                    progress=False)
    md = (tmp_path / "summary.md").read_text()
    d = paired_difference(rows, "oracle", "flat")
    assert "| flat | " in md.split("Paired per-material differences against oracle")[1]
    assert f"{d} | 2/2 |" in md


def test_paired_differences_are_the_mean_and_standard_error_over_shared_materials():
    rows = [{"method": m, "material": k, "rmse_average": v}
            for m, vals in (("a", (0.10, 0.20, 0.30)), ("b", (0.12, 0.18, 0.36))) for k, v in zip("xyz", vals)]
    rows.append({"method": "b", "material": "only b", "rmse_average": 9.0})
    d = paired_difference(rows, "a", "b")
    diffs = torch.tensor([0.02, -0.02, 0.06], dtype=torch.float64)
    assert d.n == 3 and d.a_lower == 2
    assert d.mean == pytest.approx(float(diffs.mean()))
    assert d.se == pytest.approx(float(diffs.std() / 3 ** 0.5))


def test_paired_differences_need_a_material_in_common():
    rows = [{"method": "a", "material": "x", "rmse_average": 0.1}, {"method": "b", "material": "y", "rmse_average": 0.1}]
    with pytest.raises(ValueError, match="no material in common"):
        paired_difference(rows, "a", "b")


def test_paired_scores_must_be_equally_long():
    with pytest.raises(ValueError, match="equally long"):
        paired([0.1, 0.2], [0.1])


def test_figure_files_have_portable_names(rig, tmp_path, relight):
    mat = textured_material(16, seed=3)
    mat.name = "procedural:1000000:7"
    evaluate({"oracle": _oracle}, [mat], rig, tmp_path, relight=relight, progress=False)
    assert [p.name for p in (tmp_path / "figures").iterdir()] == ["procedural-1000000-7.png"]
    assert "figures/procedural-1000000-7.png" in (tmp_path / "index.html").read_text()


def test_figures_can_be_limited_to_the_first_materials(rig, tmp_path, relight):
    mats = [textured_material(16, seed=s) for s in range(3)]
    rows = evaluate({"oracle": _oracle}, mats, rig, tmp_path, relight=relight, max_figures=1, progress=False)
    assert len(rows) == 3
    assert [p.name for p in (tmp_path / "figures").iterdir()] == ["material_000.png"]


def test_materials_with_one_name_get_one_row_and_figure_each(rig, tmp_path, relight):
    mats = [textured_material(16, seed=s) for s in range(2)]
    for m in mats:
        m.name = "same"
    rows = evaluate({"oracle": _oracle}, mats, rig, tmp_path, relight=relight, progress=False)
    assert len({r["material"] for r in rows}) == 2
    assert len(list((tmp_path / "figures").glob("*.png"))) == 2


def test_fixed_pattern_baseline_sees_its_patterns(rig, tmp_path, relight):
    seen = {}

    class Reconstructor(torch.nn.Module):
        def forward(self, images, spec):
            seen["shape"] = tuple(images.shape)
            return torch.full((1, 10, *images.shape[-2:]), 0.5)

    method = simulated(FixedAcquisition(ms.pattern_family("monograd"), Reconstructor(), rig, use_spec=False),
                       method="reference")
    cap = method(textured_material(8))
    assert seen["shape"] == (1, 5, 3, 8, 8)
    assert cap.images.shape == (5, 3, 8, 8)


def test_empty_material_set_is_refused(rig, tmp_path):
    with pytest.raises(ValueError, match="no materials"):
        evaluate({"oracle": _oracle}, [], rig, tmp_path, progress=False)


def test_method_returning_another_resolution_is_refused(rig, tmp_path, relight):
    def small(gt):
        return _flat(ms.SVBRDF.constant(size=4))

    with pytest.raises(ValueError, match="returned"):
        evaluate({"small": small}, [textured_material(8)], rig, tmp_path, relight=relight, progress=False)
