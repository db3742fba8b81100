"""torch Datasets of SVBRDFs: the procedural stream, Deschaintre-format strips, folders of maps.

Every dataset returns **items as dicts of tensors** (one material, no batch dimension)::

    {"normal": (3, H, W) unit vectors, "diffuse": (3, H, W), "roughness": (1, H, W),
     "specular": (3, H, W), "index": int, "name": str}
    (+ "render": (3, H, W) for 5-tile dataset strips, values as stored)

with the conventions of :class:`mitsvbrdf.SVBRDF` (x right, y up, row 0 at the top; albedos as
stored). Torch's default collate stacks them into ``(B, C, H, W)`` tensors (and lists of names);
:func:`collate` does the same and :func:`to_svbrdf` turns a batch into an :class:`SVBRDF`.
:func:`collate_svbrdf` goes straight to an SVBRDF (``DataLoader(..., collate_fn=collate_svbrdf)``).

Randomness (crops, augmentations) is drawn from a generator seeded by ``(seed, epoch, index)``,
so an item is reproducible, differs between epochs after :meth:`set_epoch`, and does not depend on
the DataLoader's worker layout.

Datasets:

* :class:`ProceduralDataset` -- index i -> material i of a procedural stream (deterministic);
  ``__getitems__`` builds a whole batch in one vectorised call when used with a DataLoader.
* :class:`StripDataset` -- a folder (or list) of strip images: 5-tile dataset strips
  ``[render | normal | diffuse | roughness | specular]`` (e.g. Deschaintre 2018, 288 px tiles with
  random 256 crops) and 4-tile map strips ``[normal | diffuse | roughness | specular]``.
* :class:`MapFolderDataset` -- a folder of material folders, each with ``normal``, ``diffuse``,
  ``roughness``, ``specular`` as ``.png`` or ``.exr``.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Sequence

import torch
from torch import Tensor
from torch.utils.data import Dataset

from ..errors import ImageFileError, MaterialError, MitsvbrdfError
from ..svbrdf import SVBRDF
from .augment import MAP_KEYS, Augment, crop_maps
from .procedural import check_bump, check_dark_metals, generate_indices, material_seed

STRIP_SUFFIXES = (".png", ".jpg", ".jpeg")


def _generator(seed: int, epoch: int, index: int) -> torch.Generator:
    return torch.Generator().manual_seed(material_seed(seed, index, f"augment:{epoch}"))


def _item(svbrdf: SVBRDF, index: int, name: str | None) -> dict[str, Any]:
    out: dict[str, Any] = {k: getattr(svbrdf, k)[0] for k in MAP_KEYS}
    if svbrdf.render is not None:
        out["render"] = svbrdf.render[0]
    out["index"] = index
    out["name"] = name if name is not None else (svbrdf.name or str(index))
    return out


def to_svbrdf(batch: dict[str, Any]) -> SVBRDF:
    """A collated batch (dict of ``(B, C, H, W)`` tensors) -> :class:`SVBRDF` (validated)."""
    names = batch.get("name")
    name = names[0] if isinstance(names, (list, tuple)) and len(set(names)) == 1 else None
    return SVBRDF(**{k: batch[k] for k in MAP_KEYS}, render=batch.get("render"), name=name)


def collate(items: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Stack items into a batch: tensors -> (B, ...), ``index`` -> long tensor (B,), ``name`` -> list.

    ``render`` is kept only if every item has one. All items must share one resolution.
    """
    if not items:
        raise MaterialError("collate needs at least one item")
    sizes = {tuple(it["normal"].shape[-2:]) for it in items}
    if len(sizes) != 1:
        raise MaterialError(f"cannot batch materials of different sizes {sorted(sizes)}; crop them to one size")
    out: dict[str, Any] = {k: torch.stack([it[k] for it in items]) for k in MAP_KEYS}
    if all("render" in it for it in items):
        out["render"] = torch.stack([it["render"] for it in items])
    out["index"] = torch.tensor([int(it["index"]) for it in items], dtype=torch.long)
    out["name"] = [str(it["name"]) for it in items]
    return out


def collate_svbrdf(items: Sequence[dict[str, Any]]) -> SVBRDF:
    """``collate`` then :func:`to_svbrdf`: a DataLoader ``collate_fn`` that yields SVBRDFs."""
    return to_svbrdf(collate(items))


class _Epoch:
    epoch = 0

    def set_epoch(self, epoch: int) -> None:
        """Change the random crops/augmentations for a new epoch (items stay reproducible per epoch)."""
        self.epoch = int(epoch)


class ProceduralDataset(Dataset, _Epoch):
    """Material i of a procedural stream (:func:`mitsvbrdf.data.procedural.generate`).

    Args:
        length: number of items (the stream itself is unbounded).
        size: resolution of the generated maps.
        seed, families, bump, dark_metals: the stream's identity (see ``generate``).
        augment: optional :class:`Augment` applied per item (generated materials need none; flips
            and rotations are cheap extra variety).
        start: index of item 0 in the stream (e.g. disjoint training and validation ranges).
        device: where materials are generated (items are returned there).
    """

    def __init__(self, length: int, size: int = 256, seed: int = 0, families: Sequence[str] | None = None, *,
                 augment: Augment | None = None, bump: float | tuple[float, float] = 1.0,
                 dark_metals: float = 0.0, start: int = 0, device: str | None = None):
        if length < 1:
            raise MaterialError(f"length must be >= 1, got {length}")
        self.length, self.size, self.seed, self.families = int(length), int(size), int(seed), families
        self.augment, self.bump, self.start, self.device = augment, check_bump(bump), int(start), device
        self.dark_metals = check_dark_metals(dark_metals)

    def __len__(self) -> int:
        return self.length

    def _check(self, i: int) -> int:
        if not -self.length <= i < self.length:
            raise IndexError(f"index {i} out of range for a dataset of {self.length}")
        return i % self.length

    def __getitem__(self, i: int) -> dict[str, Any]:
        return self.__getitems__([i])[0]

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """Items at ``indices``, generated in one vectorised batch (used by DataLoader)."""
        idx = [self._check(int(i)) for i in indices]
        batch = generate_indices([self.start + i for i in idx], self.size, self.seed, self.families,
                                 self.device, bump=self.bump, dark_metals=self.dark_metals)
        items = []
        for b, i in enumerate(idx):
            item = _item(batch[b], i, f"procedural:{self.seed}:{self.start + i}")
            if self.augment is not None:
                item.update(self.augment({k: item[k] for k in MAP_KEYS}, _generator(self.seed, self.epoch, i)))
            items.append(item)
        return items


class _FileDataset(Dataset, _Epoch):
    """Shared loading, cropping and augmentation of file-backed materials."""

    def __init__(self, paths: list[Path], *, crop: int | None, random_crop: bool, augment: Augment | None,
                 seed: int, srgb_albedo: bool, strict: bool):
        if crop is not None and crop < 1:
            raise MaterialError(f"crop must be a positive size or None, got {crop}")
        self.paths, self.crop, self.random_crop, self.augment = paths, crop, random_crop, augment
        self.seed, self.srgb_albedo, self.strict = int(seed), srgb_albedo, strict

    def __len__(self) -> int:
        return len(self.paths)

    def load(self, i: int) -> SVBRDF:
        """The material of item ``i`` as stored (B = 1), before cropping and augmentation."""
        return SVBRDF.load(self.paths[i], strict=self.strict, srgb_albedo=self.srgb_albedo)

    def __getitem__(self, i: int) -> dict[str, Any]:
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for a dataset of {len(self)}")
        i %= len(self)
        svbrdf = self.load(i)
        item = _item(svbrdf, i, self.paths[i].stem if self.paths[i].is_file() else self.paths[i].name)
        g = _generator(self.seed, self.epoch, i)
        if self.crop is not None:
            H, W = item["normal"].shape[-2:]
            if self.crop > min(H, W):
                raise MaterialError(f"{self.paths[i]}: tiles are {H}x{W} px, smaller than the crop {self.crop}")
            if self.random_crop:
                top = int(torch.randint(0, H - self.crop + 1, (), generator=g))
                left = int(torch.randint(0, W - self.crop + 1, (), generator=g))
            else:
                top, left = (H - self.crop) // 2, (W - self.crop) // 2
            item.update(crop_maps({k: item[k] for k in (*MAP_KEYS, "render") if k in item}, top, left, self.crop))
        if self.augment is not None:
            item.update(self.augment({k: item[k] for k in (*MAP_KEYS, "render") if k in item}, g))
        return item


def _scan(root: str | Path | Sequence[str | Path], want_dirs: bool) -> list[Path]:
    if isinstance(root, (str, Path)):
        root = Path(root)
        if not root.is_dir():
            raise ImageFileError(f"{root}: no such folder")
        if want_dirs:
            return sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
        return sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in STRIP_SUFFIXES)
    paths = [Path(p) for p in root]
    for p in paths:
        if not (p.is_dir() if want_dirs else p.is_file()):
            raise ImageFileError(f"{p}: no such {'folder' if want_dirs else 'file'}")
    return paths


def strip_layout(path: str | Path) -> tuple[int, int]:
    """``(tiles, tile_size)`` of a strip image from its header alone: tiles is 4 or 5.

    Raises:
        ImageFileError: not a readable image.
        MaterialError: a width that is not 4 or 5 times the height.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        with Image.open(path) as im:
            w, h = im.size
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
        raise ImageFileError(f"{path}: not a readable image ({e})") from e
    if h > 0 and w == 4 * h:
        return 4, h
    if h > 0 and w == 5 * h:
        return 5, h
    raise MaterialError(f"{path}: a strip must be 4 or 5 square tiles wide (width {4 * h} or {5 * h} for "
                        f"height {h}), got {w}x{h}")


class StripDataset(_FileDataset):
    """Strip images from a folder (sorted by name; other files are ignored) or an explicit list.

    Args:
        root: a folder of ``.png``/``.jpg`` strips, or a sequence of strip paths.
        crop: output size (default 256); tiles larger than it are cropped (random position when
            ``random_crop``, else centred), tiles smaller raise MaterialError. None keeps the tiles.
        random_crop: random (training) or centred (evaluation) crops.
        augment: optional :class:`Augment` (flips/rotations/jitter) after cropping.
        seed: seed of the per-item random draws.
        srgb_albedo, strict: passed to :meth:`SVBRDF.load`.
        check: read every file's header now and raise (or, with ``skip_bad``, warn and drop the
            file) when it is not a readable image or not a 4- or 5-tile strip.
        skip_bad: drop bad files found by ``check`` instead of raising.

    Item ``i``'s ``name`` is the file stem; a 5-tile strip's item has ``render``.
    """

    def __init__(self, root: str | Path | Sequence[str | Path], crop: int | None = 256, *, random_crop: bool = True,
                 augment: Augment | None = None, seed: int = 0, srgb_albedo: bool = False, strict: bool = False,
                 check: bool = True, skip_bad: bool = False):
        paths = _scan(root, want_dirs=False)
        if check:
            good = []
            for p in paths:
                try:
                    strip_layout(p)
                    good.append(p)
                except MitsvbrdfError as e:
                    if not skip_bad:
                        raise
                    warnings.warn(f"skipping {e}", stacklevel=2)
            paths = good
        if not paths:
            raise ImageFileError(f"{root}: no strip images ({', '.join(STRIP_SUFFIXES)}) found")
        super().__init__(paths, crop=crop, random_crop=random_crop, augment=augment, seed=seed,
                         srgb_albedo=srgb_albedo, strict=strict)


class MapFolderDataset(_FileDataset):
    """Materials stored as folders of per-map files (``normal``, ``diffuse``, ``roughness``,
    ``specular`` as ``.png`` or ``.exr``; see :meth:`SVBRDF.load`).

    Args:
        root: a folder whose sub-folders are materials (sorted by name), or a sequence of folders.
        crop, random_crop, augment, seed, srgb_albedo, strict: as for :class:`StripDataset`.

    Item ``i``'s ``name`` is the folder name.
    """

    def __init__(self, root: str | Path | Sequence[str | Path], crop: int | None = None, *, random_crop: bool = True,
                 augment: Augment | None = None, seed: int = 0, srgb_albedo: bool = False, strict: bool = False):
        paths = _scan(root, want_dirs=True)
        if not paths:
            raise ImageFileError(f"{root}: no material folders found")
        super().__init__(paths, crop=crop, random_crop=random_crop, augment=augment, seed=seed,
                         srgb_albedo=srgb_albedo, strict=strict)
