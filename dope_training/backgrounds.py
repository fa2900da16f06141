"""Photographs behind the objects: a training crop's background (everything but the labelled objects' visible
pixels: the environment, the procedural distractors) replaced by a random view of a real photograph, so that the
network meets real-world textures (screens, plants, papers, cables) where it must find nothing.

The photos are a folder of the user's own (any PNG/JPEG; a few dozen indoor photos are enough to start) or, by
default, the photographs that ship inside scikit-image's wheel (``skimage.data``: a cat, a coffee cup, a rocket,
a motorcycle in a workshop, microscopy, gravel, brick...; nothing is downloaded). Each use takes a random photo,
scale (0.5-2x), rotation and place, mirrored half of the time, warped to the crop; the objects' masks, warped as
the crop was and so soft at their edges, keep the rendered pixels in front.

Every fourth photo is kept out of training (``split_photos``): ``photo_backed`` shows those behind the objects of
held-out frames, where the network meets real textures it never learnt to ignore, as it will on a user's photos
(``benchmarks/real.py`` sets the detection score there).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import IMAGE_EXTENSIONS, bop_frames
from pegasus_gen.io.images import read_rgb, write_image

# the photographs (not drawings or test charts) bundled in scikit-image's wheel (stereo_motorcycle: its left view)
SKIMAGE_PHOTOS = ("astronaut", "brick", "camera", "cell", "chelsea", "coffee", "coins", "grass", "gravel",
                  "hubble_deep_field", "immunohistochemistry", "moon", "stereo_motorcycle", "page", "retina",
                  "rocket", "text")
SCALE = (0.5, 2.0)  # photo pixels per crop pixel, drawn log-uniformly
# every HELD_OUT_EVERY-th photo (from the first) is kept out of training, for the held-out frames that set the
# detection score: behind them the network meets real textures it never learnt to ignore, as on a user's photos
HELD_OUT_EVERY = 4


def _rgb(image: np.ndarray) -> np.ndarray:
    """[H, W] or [H, W, 3|4] uint8 -> [H, W, 3] uint8 RGB."""
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2)
    return np.ascontiguousarray(image[:, :, :3])


def load_photos(folder: str | Path | None = None) -> list[np.ndarray]:
    """Background photos [H, W, 3] uint8 RGB: every image in ``folder`` (searched recursively), or without one
    the photographs bundled with scikit-image. A folder without images is a PegasusError."""
    if folder:
        folder = Path(folder)
        if not folder.is_dir():
            raise PegasusError(f"{folder}: no such folder of background photos")
        paths = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_EXTENSIONS)
        if not paths:
            raise PegasusError(f"{folder}: no images ({', '.join(IMAGE_EXTENSIONS)}) to use as backgrounds")
        return [read_rgb(p) for p in paths]
    import skimage.data

    photos = [getattr(skimage.data, name)() for name in SKIMAGE_PHOTOS]
    return [_rgb(p[0] if isinstance(p, tuple) else p) for p in photos]  # stereo_motorcycle: (left, right, disparity)


def split_photos(photos: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``photos`` split into (training, held out): every ``HELD_OUT_EVERY``-th one from the first is held out, none
    of fewer than two."""
    if len(photos) < 2:
        return list(photos), []
    return ([p for i, p in enumerate(photos) if i % HELD_OUT_EVERY],
            [p for i, p in enumerate(photos) if not i % HELD_OUT_EVERY])


def photo_view(photos: list[np.ndarray], size: int | tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A random view [height, width, 3] uint8 (``size``: both, or (height, width)) of one of ``photos``: random
    photo, scale, rotation, centre and mirroring (reflected at the photo's borders)."""
    height, width = (size, size) if np.isscalar(size) else size
    photo = photos[rng.integers(len(photos))]
    h, w = photo.shape[:2]
    scale = np.exp(rng.uniform(*np.log(SCALE)))  # photo px per crop px
    angle = rng.uniform(0, 2 * np.pi)
    flip = -1.0 if rng.uniform() < 0.5 else 1.0
    R = scale * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]) @ np.diag([flip, 1.0])
    centre = rng.uniform((0, 0), (w, h))
    middle = np.array([(width - 1) / 2, (height - 1) / 2])
    A = np.concatenate([R, (centre - R @ middle)[:, None]], axis=1)  # view px -> photo px
    return cv2.warpAffine(photo, A, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT_101)


def masks_union(masks: list[Path]) -> np.ndarray | None:
    """[H, W] uint8, 1 on the union of the visible masks (image-sized PNGs, nonzero on the object) closed by a pixel
    (neighbouring objects' masks can leave a seam of antialiased pixels that neither holds); None without masks."""
    union = None
    for path in masks:
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise PegasusError(f"{path}: cannot read this mask")
        union = mask > 0 if union is None else union | (mask > 0)
    if union is None:
        return None
    return cv2.morphologyEx(union.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))


def warp_alpha(union: np.ndarray | None, M: np.ndarray, size: int) -> np.ndarray:
    """[size, size] float32 0..1: ``union`` ([H, W] 0/1, ``masks_union``; None: nothing) warped into the crop by M
    [2, 3] (image -> crop px), bilinear so that its edges are soft as the crop's are."""
    if union is None:
        return np.zeros((size, size), np.float32)
    return cv2.warpAffine(union.astype(np.float32), M, (size, size), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)


def behind_objects(crop: np.ndarray, alpha: np.ndarray, photo: np.ndarray) -> np.ndarray:
    """``crop`` [S, S, 3] uint8 with ``photo`` [S, S, 3] uint8 where ``alpha`` [S, S] (0..1, the objects) is 0,
    blended where it is fractional."""
    a = alpha[:, :, None]
    return np.clip(a * crop + (1.0 - a) * photo + 0.5, 0, 255).astype(np.uint8)


def photo_backed(root: str | Path, split: str, out: str | Path, photos: list[np.ndarray], seed: int = 0) -> Path:
    """A copy in ``out`` of BOP dataset ``root``'s ``split`` (its scenes' JSON files, ``camera.json`` and the models)
    whose every image shows a random view of one of ``photos`` (``photo_view``, a frame's size) behind its labelled
    objects (the union of their BOP visible masks) instead of the rendered environment and distractors; the same
    image names and formats, drawn with ``seed``. It appears whole or not at all (written beside ``out``, then
    renamed); an existing ``out`` is a PegasusError, as a frame without visible masks is. Returns ``out``."""
    root, out = Path(root), Path(out)
    if out.exists():
        raise PegasusError(f"{out} exists: choose a new folder for the photo-backed copy")
    if not photos:
        raise PegasusError("photo_backed needs at least one photo")
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)  # a copy cut short earlier: never a dataset on its own
    try:
        rng = np.random.default_rng(seed)
        for frame in bop_frames(root / split):
            union = masks_union(frame.visible_masks())
            if union is None:
                raise PegasusError(f"{frame.scene}: image {frame.im_id} has no visible masks (mask_visib) to keep")
            image = read_rgb(frame.image)
            view = photo_view(photos, image.shape[:2], rng)
            scene = partial / split / frame.scene.name
            (scene / "rgb").mkdir(parents=True, exist_ok=True)
            write_image(scene / "rgb" / frame.image.name, behind_objects(image, union.astype(np.float32), view))
            for name in ("scene_gt.json", "scene_camera.json", "scene_gt_info.json"):
                if (frame.scene / name).is_file() and not (scene / name).is_file():
                    shutil.copy2(frame.scene / name, scene / name)
        for name in ("models", "models_eval"):
            if (root / name).is_dir():
                shutil.copytree(root / name, partial / name)
        if (root / "camera.json").is_file():
            shutil.copy2(root / "camera.json", partial / "camera.json")
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    partial.rename(out)
    return out
