"""Networks: shapes, ranges, per-pixel independence of G_p, parameter counts, network files."""

import pytest
import torch

from mitsvbrdf.nets import (Initializer, LearnedPattern, LightingPredictor, NAFBlock, NetworkFileError, PointPredictor,
                            SVBRDFPredictor, diffuse_ratio, load_network, parameter_count, save_network,
                            with_diffuse_ratio)


@pytest.fixture(autouse=True)
def _threads(one_torch_thread):
    torch.manual_seed(0)


def test_fresh_nafblock_is_the_identity():
    x = torch.randn(2, 8, 16, 16)
    assert torch.equal(NAFBlock(8)(x), x)


@pytest.mark.parametrize("size", [32, 64])
def test_lighting_predictor_outputs_patterns_and_inverse_maps(size):
    out = LightingPredictor(width=4)(torch.rand(2, 3, size, size), torch.rand(2, 1, 32, 32))
    assert out.patterns.shape == (2, 4, 3, 32, 32)
    assert out.patterns.min() >= 0 and out.patterns.max() <= 1
    assert out.normal.shape == (2, 3, size, size) and out.roughness.shape == (2, 1, size, size)
    assert torch.allclose(out.normal.norm(dim=1), torch.ones(2, size, size), atol=1e-5)
    assert (out.normal[:, 2] > 0).all()


@pytest.mark.parametrize("size", [32, 64])
def test_svbrdf_predictor_maps_images_and_spec_to_ten_channels(size):
    net = SVBRDFPredictor(width=4)
    y = net(torch.rand(1, 5, 3, size, size), torch.randn(1, 10, 3, size, size) * 1e-3)
    assert y.shape == (1, 10, size, size) and y.min() >= 0 and y.max() <= 1


def test_svbrdf_predictor_with_spec_refuses_to_run_without_it():
    with pytest.raises(ValueError, match="I\\^spec"):
        SVBRDFPredictor(width=4)(torch.rand(1, 5, 3, 32, 32))


def test_input_size_must_fit_the_downsampling():
    with pytest.raises(ValueError, match="multiples of 8"):
        Initializer(width=4)(torch.rand(1, 3, 36, 36))


def test_point_predictor_is_strictly_per_pixel():
    net = PointPredictor(hidden=16)
    imgs, irr, pats = torch.rand(2, 5, 3, 8, 8), torch.rand(2, 5, 3, 8, 8), torch.rand(2, 5, 3, 32, 32)
    y = net(imgs, irr, pats)
    perm = torch.randperm(64)

    def shuffle(t):
        return t.flatten(-2)[..., perm].reshape(t.shape)

    assert torch.allclose(net(shuffle(imgs), shuffle(irr), pats), shuffle(y), atol=1e-6)


def test_point_predictor_sees_each_materials_patterns():
    net = PointPredictor(hidden=16)
    imgs, irr = torch.rand(1, 5, 3, 8, 8).expand(2, -1, -1, -1, -1), torch.rand(1, 5, 3, 8, 8).expand(2, -1, -1, -1, -1)
    y = net(imgs, irr, torch.rand(2, 5, 3, 32, 32))
    assert not torch.allclose(y[0], y[1])


def test_learned_pattern_stays_in_range_and_learns():
    p = LearnedPattern((32, 32))
    v = p().detach()
    assert v.shape == (1, 3, 32, 32) and 0 < float(v.min()) <= float(v.max()) < 1
    p().mean().backward()
    assert p.logits.grad.abs().sum() > 0


def test_parameter_counts_are_reported(capsys):
    counts = {type(n).__name__: parameter_count(n) for n in (LightingPredictor(), PointPredictor(), SVBRDFPredictor(),
                                                               Initializer())}
    print(counts)
    assert all(c > 1000 for c in counts.values())
    assert counts["LightingPredictor"] < counts["SVBRDFPredictor"]  # G_l is the shallow one


def test_network_file_roundtrip(tmp_path):
    net = SVBRDFPredictor(width=4, use_spec=False)
    save_network(tmp_path / "g.pt", net)
    back = load_network(tmp_path / "g.pt", expect=SVBRDFPredictor)
    x = torch.rand(1, 5, 3, 32, 32)
    assert torch.equal(back(x), net(x))


def test_network_file_of_another_architecture_is_refused(tmp_path):
    save_network(tmp_path / "g.pt", LightingPredictor(width=4))
    with pytest.raises(NetworkFileError, match="holds a LightingPredictor, expected a SVBRDFPredictor"):
        load_network(tmp_path / "g.pt", expect=SVBRDFPredictor)


def test_corrupt_or_missing_network_file_is_refused(tmp_path):
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(NetworkFileError, match="cannot read"):
        load_network(tmp_path / "bad.pt")
    with pytest.raises(NetworkFileError, match="no such network file"):
        load_network(tmp_path / "none.pt")


def test_svbrdf_predictor_with_diffuse_ratio_refuses_to_run_without_irradiance():
    with pytest.raises(ValueError, match="irradiance"):
        SVBRDFPredictor(width=4, use_spec=False, diffuse_ratio=True)(torch.rand(1, 5, 3, 32, 32))


def test_widened_predictor_computes_what_the_plain_one_computes():
    plain = SVBRDFPredictor(width=4)
    for p in plain.parameters():  # a trained-looking net: fresh NAFBlocks would be the identity
        p.data.normal_(0, 0.1)
    wide = with_diffuse_ratio(plain)
    images, spec = torch.rand(2, 5, 3, 32, 32), torch.randn(2, 10, 3, 32, 32) * 1e-3
    irradiance = torch.rand(2, 5, 3, 32, 32)
    assert wide.diffuse_ratio and wide.config["diffuse_ratio"]
    assert torch.allclose(wide(images, spec, irradiance), plain(images, spec), atol=1e-6)
    assert with_diffuse_ratio(wide) is wide


def test_initializer_with_diffuse_ratio_refuses_to_run_without_irradiance():
    with pytest.raises(ValueError, match="irradiance"):
        Initializer(width=4, diffuse_ratio=True)(torch.rand(1, 3, 32, 32))


def test_initializer_with_diffuse_ratio_reads_the_ratio():
    net = Initializer(width=4, diffuse_ratio=True)
    for p in net.parameters():
        p.data.normal_(0, 0.1)
    i0 = torch.rand(1, 3, 32, 32)
    assert not torch.allclose(net(i0, torch.full_like(i0, 0.1)), net(i0, torch.full_like(i0, 0.2)))


def test_widened_initializer_computes_what_the_plain_one_computes():
    plain = Initializer(width=4)
    for p in plain.parameters():
        p.data.normal_(0, 0.1)
    wide = with_diffuse_ratio(plain)
    i0 = torch.rand(2, 3, 32, 32)
    assert wide.diffuse_ratio and wide.config["diffuse_ratio"]
    assert torch.allclose(wide(i0, torch.rand(1, 3, 32, 32)), plain(i0), atol=1e-6)


def test_plain_initializer_records_no_diffuse_ratio_so_older_files_load(tmp_path):
    assert "diffuse_ratio" not in Initializer(width=4).config
    save_network(tmp_path / "init.pt", Initializer(width=4, diffuse_ratio=True))
    assert load_network(tmp_path / "init.pt").diffuse_ratio


def test_diffuse_ratio_stays_finite_where_pattern_and_image_are_black():
    images = torch.zeros(1, 5, 3, 8, 8, requires_grad=True)
    irradiance = torch.zeros(1, 5, 3, 8, 8, requires_grad=True)
    r = diffuse_ratio(images, irradiance)
    r.sum().backward()
    assert torch.equal(r, torch.zeros_like(r))
    assert torch.isfinite(images.grad).all() and torch.isfinite(irradiance.grad).all()


# ---- weight averages of exports ---------------------------------------------------------------

def _export(path, seed, **svbrdf):
    """A stage export: an L_0 shared by every file (a frozen network) and a G_sc of its own."""
    from mitsvbrdf.nets import network_record

    torch.manual_seed(0)
    l0 = LearnedPattern(cells=(4, 4))
    torch.manual_seed(seed)
    gsc = SVBRDFPredictor(num_images=2, width=4, **svbrdf)
    torch.save({"l0": network_record(l0), "svbrdf": network_record(gsc), "acquisition": {"resolution": 16}}, path)
    return gsc


def test_the_average_of_exports_is_each_weights_mean_and_keeps_what_they_share(tmp_path):
    from mitsvbrdf.cli import main

    a, b = _export(tmp_path / "a.pt", 1), _export(tmp_path / "b.pt", 2)
    assert main(["average-networks", str(tmp_path / "a.pt"), str(tmp_path / "b.pt"), "--out", str(tmp_path / "m.pt")]) == 0
    got = torch.load(tmp_path / "m.pt", weights_only=True)
    for key, wa in a.state_dict().items():
        torch.testing.assert_close(got["svbrdf"]["state"][key], (wa + b.state_dict()[key]) / 2)
    shared = torch.load(tmp_path / "a.pt", weights_only=True)["l0"]["state"]
    assert all(torch.equal(got["l0"]["state"][k], v) for k, v in shared.items())
    assert got["acquisition"] == {"resolution": 16}


def test_exports_of_other_architectures_or_settings_are_not_averaged(tmp_path):
    from mitsvbrdf.nets.io import average_exports

    _export(tmp_path / "a.pt", 1)
    _export(tmp_path / "wide.pt", 2, use_spec=False)
    with pytest.raises(NetworkFileError, match="'svbrdf' is not a SVBRDFPredictor"):
        average_exports([tmp_path / "a.pt", tmp_path / "wide.pt"])
    other = torch.load(tmp_path / "a.pt", weights_only=True) | {"acquisition": {"resolution": 32}}
    torch.save(other, tmp_path / "r32.pt")
    with pytest.raises(NetworkFileError, match="its 'acquisition'"):
        average_exports([tmp_path / "a.pt", tmp_path / "r32.pt"])


def test_averaging_one_export_is_a_clear_error(tmp_path, capsys):
    from mitsvbrdf.cli import main

    _export(tmp_path / "a.pt", 1)
    assert main(["average-networks", str(tmp_path / "a.pt"), "--out", str(tmp_path / "m.pt")]) == 2
    assert "at least two exports" in capsys.readouterr().err


# ---- networks taken from another export --------------------------------------------------------

def test_replacing_a_network_takes_its_weights_from_the_donor_and_keeps_the_rest(tmp_path):
    from mitsvbrdf.cli import main

    _export(tmp_path / "base.pt", 1)
    donor = _export(tmp_path / "donor.pt", 2)
    assert main(["replace-networks", str(tmp_path / "base.pt"), "--from", str(tmp_path / "donor.pt"),
                 "--networks", "svbrdf", "--out", str(tmp_path / "m.pt")]) == 0
    got, base = (torch.load(tmp_path / p, weights_only=True) for p in ("m.pt", "base.pt"))
    assert all(torch.equal(got["svbrdf"]["state"][k], v) for k, v in donor.state_dict().items())
    assert all(torch.equal(got["l0"]["state"][k], v) for k, v in base["l0"]["state"].items())
    assert got["acquisition"] == base["acquisition"]


def test_a_network_the_donor_lacks_or_of_another_class_is_not_taken(tmp_path):
    from mitsvbrdf.nets import network_record
    from mitsvbrdf.nets.io import replace_networks

    _export(tmp_path / "base.pt", 1)
    torch.save({"l0": network_record(SVBRDFPredictor(num_images=2, width=4))}, tmp_path / "donor.pt")
    with pytest.raises(NetworkFileError, match="no network 'initializer'; its networks are \\['l0'\\]"):
        replace_networks(tmp_path / "base.pt", tmp_path / "donor.pt", ["initializer"])
    with pytest.raises(NetworkFileError, match="'l0' is a SVBRDFPredictor"):
        replace_networks(tmp_path / "base.pt", tmp_path / "donor.pt", ["l0"])
