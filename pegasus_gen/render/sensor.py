"""What a real camera adds to the light a render gives: exposure, white balance, defocus and motion blur, shot
and read noise, and the tone curve, in that order (the order of the physics: light is scaled and blurred
by the optics and the motion during the exposure, then counted with noise, then encoded)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SensorEffects:
    """One frame's camera effects; the defaults change nothing."""

    exposure: float = 1.0  # gain on the image
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)  # per-channel gains (R, G, B)
    gamma: float = 1.0  # tone curve: out = in ** (1 / gamma)
    defocus_px: float = 0.0  # radius of the blur disc, px
    motion_px: tuple[float, float] = (0.0, 0.0)  # the streak (dx, dy) a point draws during the exposure, px
    shot_noise: float = 0.0  # photon noise: std = shot_noise * sqrt(value) (values 0..1)
    read_noise: float = 0.0  # read noise std (values 0..1)


def disc_kernel(radius: float, supersample: int = 8) -> np.ndarray:
    """[2R+1, 2R+1] float32 kernel (sum 1) of a disc of ``radius`` px, edges anti-aliased; [[1]] below 0.5 px."""
    if radius < 0.5:
        return np.ones((1, 1), np.float32)
    half = int(np.ceil(radius))
    s = (np.arange(supersample) + 0.5) / supersample - 0.5
    offsets = np.arange(-half, half + 1)
    fine = (offsets[:, None] + s[None, :]).ravel()
    inside = (fine[:, None] ** 2 + fine[None, :] ** 2 <= radius**2).astype(np.float32)
    n = 2 * half + 1
    kernel = inside.reshape(n, supersample, n, supersample).mean(axis=(1, 3))
    return kernel / kernel.sum()


def streak_kernel(dx: float, dy: float) -> np.ndarray:
    """Kernel (sum 1, odd square, centred) of a straight streak from -(dx, dy)/2 to +(dx, dy)/2 px: the blur of
    a constant motion during the exposure. [[1]] for a streak under half a pixel."""
    length = float(np.hypot(dx, dy))
    if length < 0.5:
        return np.ones((1, 1), np.float32)
    half = int(np.ceil(length / 2)) + 1
    kernel = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
    for t in np.linspace(-0.5, 0.5, int(np.ceil(length * 4)) + 1):
        x, y = half + t * dx, half + t * dy
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        kernel[y0, x0] += (1 - fx) * (1 - fy)
        kernel[y0, x0 + 1] += fx * (1 - fy)
        kernel[y0 + 1, x0] += (1 - fx) * fy
        kernel[y0 + 1, x0 + 1] += fx * fy
    return kernel / kernel.sum()


def apply_sensor(rgb: np.ndarray, effects: SensorEffects, rng: np.random.Generator) -> np.ndarray:
    """[H, W, 3] float32 RGB in 0..1 as the camera of ``effects`` records the light ``rgb`` [H, W, 3] (0..1);
    ``rng`` draws the noise."""
    out = np.asarray(rgb, np.float32) * (effects.exposure * np.asarray(effects.white_balance, np.float32))
    for kernel in (disc_kernel(effects.defocus_px), streak_kernel(*effects.motion_px)):
        if kernel.size > 1:
            out = cv2.filter2D(out, -1, kernel, borderType=cv2.BORDER_REFLECT)
    if effects.shot_noise > 0 or effects.read_noise > 0:
        std = np.sqrt(np.float32(effects.shot_noise**2) * np.clip(out, 0, None) + np.float32(effects.read_noise**2))
        out = out + rng.standard_normal(out.shape, dtype=np.float32) * std
    out = np.clip(out, 0.0, 1.0)
    return out if effects.gamma == 1.0 else out ** np.float32(1.0 / effects.gamma)
