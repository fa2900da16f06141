"""Image reading, conversion and writing: RGB from files, float images to uint8/uint16, colourised depth and labels,
atomic PNG writes."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from pegasus_gen.errors import PegasusError
from pegasus_gen.io.files import write_atomic


def rgb_to_uint8(rgb: np.ndarray) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> uint8, clamped before rounding (no wrap-around)."""
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def colorize_depth(depth: np.ndarray) -> np.ndarray:
    """[H, W] metres (0 = none) -> [H, W, 3] uint8 RGB (turbo colour map, near = red; none = black)."""
    valid = depth > 0
    out = np.zeros(depth.shape + (3,), np.uint8)
    if valid.any():
        lo, hi = np.percentile(depth[valid], [1, 99])
        t = np.clip((depth - lo) / max(hi - lo, 1e-9), 0, 1)
        bgr = cv2.applyColorMap(np.round((1 - t) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
        out[valid] = bgr[valid][:, ::-1]
    return out


def colorize_labels(label: np.ndarray) -> np.ndarray:
    """[H, W] int labels (-1 = none) -> [H, W, 3] uint8 RGB, a fixed distinct colour per label."""
    golden = 0.618033988749895
    ids = np.unique(label[label >= 0])
    out = np.zeros(label.shape + (3,), np.uint8)
    for i in ids:
        hue = int(((i * golden) % 1.0) * 179)
        value = 110 if i == 0 else 255
        hsv = np.uint8([[[hue, 200 if i else 40, value]]])
        out[label == i] = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]
    return out


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """[H, W, 3] uint8 RGB of an image file; a PegasusError if it cannot be read."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise PegasusError(f"{path}: cannot read the image")
    return np.ascontiguousarray(image[..., ::-1])


def write_image(path: str | os.PathLike, image: np.ndarray, jpg_quality: int = 95) -> Path:
    """Write an RGB (H, W, 3) or single-channel uint8/uint16 image; the file appears atomically."""
    path = Path(path)
    data = image[..., ::-1] if image.ndim == 3 else image
    try:
        params = [cv2.IMWRITE_JPEG_QUALITY, int(jpg_quality)] if path.suffix.lower() in (".jpg", ".jpeg") else []
        ok, buf = cv2.imencode(path.suffix or ".png", np.ascontiguousarray(data), params)
    except cv2.error:
        ok = False
    if not ok:
        raise PegasusError(f"{path}: cannot encode an image with this extension")
    return write_atomic(path, lambda f: f.write(buf.tobytes()))
