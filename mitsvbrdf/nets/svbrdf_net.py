"""G_sc, the SVBRDF predictor (paper Sec. 3.5): NAFNet with two encoders, one for the images and
one for the specular appearance maps I^spec, and one decoder on the fused features."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .nafnet import NAFDecoder, NAFEncoder, _stack, diffuse_ratio, normalize_images


class SVBRDFPredictor(nn.Module):
    """(images (B, P, 3, H, W), spec (B, P(P-1)/2, 3, H, W)[, irradiance (B, P, 3, H, W)]) ->
    (B, 10, H, W) encoded maps in [0, 1].

    Args:
        num_images: P (5 in the paper).
        width: channels of the first encoder level (32 in the paper).
        enc_blocks, middle_blocks: NAFBlocks per level and at the bottom.
        use_spec: False gives the single-encoder NAFNet of the fixed-pattern baselines (``spec``
            is then ignored and may be None).
        diffuse_ratio: besides the images, feed the image encoder each image over its pattern's
            flat-Lambertian irradiance L^d (:func:`~mitsvbrdf.nets.nafnet.diffuse_ratio`); the
            forward pass then needs ``irradiance``. Not in the paper: a documented option of
            the compute-limited recipe (docs/training.md). Default False (the paper's inputs).
    """

    #: the convolution that takes the inputs (:func:`~mitsvbrdf.nets.nafnet.with_diffuse_ratio`)
    RATIO_INTRO = "images.intro.weight"

    def __init__(self, num_images: int = 5, width: int = 32, enc_blocks: tuple[int, ...] = (1, 1, 1),
                 middle_blocks: int = 1, use_spec: bool = True, diffuse_ratio: bool = False):
        super().__init__()
        self.config = dict(num_images=num_images, width=width, enc_blocks=tuple(enc_blocks),
                           middle_blocks=middle_blocks, use_spec=use_spec, diffuse_ratio=diffuse_ratio)
        self.use_spec = use_spec
        self.diffuse_ratio = diffuse_ratio
        self.images = NAFEncoder(3 * num_images * (2 if diffuse_ratio else 1), width, enc_blocks)
        c = self.images.out_channels
        if use_spec:
            pairs = num_images * (num_images - 1) // 2
            self.spec = NAFEncoder(3 * pairs, width, enc_blocks)
            self.fuse = nn.Conv2d(2 * c, c, 1)
        self.middle = _stack(c, middle_blocks)
        self.decoder = NAFDecoder(10, width, enc_blocks)

    def forward(self, images: Tensor, spec: Tensor | None = None, irradiance: Tensor | None = None) -> Tensor:
        x = normalize_images(images).flatten(1, 2)
        if self.diffuse_ratio:
            if irradiance is None:
                raise ValueError("this SVBRDFPredictor was built with diffuse_ratio=True and needs the patterns' "
                                 "irradiance L^d")
            # appended after all images' channels, so that with_diffuse_ratio can widen a trained net
            x = torch.cat([x, diffuse_ratio(images, irradiance.expand_as(images)).flatten(1, 2)], 1)
        bottom, skips = self.images(x)
        if self.use_spec:
            if spec is None:
                raise ValueError("this SVBRDFPredictor was built with use_spec=True and needs I^spec maps")
            # I^spec is a signed difference of products: a signed log keeps its sign and range.
            s = spec.flatten(1, 2)
            sb, sskips = self.spec(torch.sign(s) * torch.log1p(s.abs() / 0.0025))
            bottom = self.fuse(torch.cat([bottom, sb], 1))
            skips = [a + b for a, b in zip(skips, sskips)]
        return torch.sigmoid(self.decoder(self.middle(bottom), skips))
