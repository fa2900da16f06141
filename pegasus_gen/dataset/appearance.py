"""Appearance and sensor randomisation of a scene, drawn from the config's ranges and the scene's seed.

Per scene: a colour transform for each object instance (per-channel gain, then a hue turn), a tint of the
environment (per-channel gain) and, for a share of scenes, a random procedural texture painted over the
environment and a distant light shading the objects (its highlights follow the camera), applied to the splats. Per
frame: the camera (exposure, white balance, gamma, shot and read noise, defocus, motion blur along the image motion
of the objects' centre, JPEG quality), applied to the rendered image. None of it moves anything: the labels are
those of the scene without it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pegasus_gen.dataset.config import AppearanceConfig
from pegasus_gen.dataset.distractors import object_palette, palette_colours
from pegasus_gen.render.sensor import SensorEffects
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.colour import hue_rotation
from pegasus_gen.splats.procedural import random_texture


def object_colour_transforms(cfg: AppearanceConfig, count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """[3, 3] colour transform of each of ``count`` object instances: diag(gains) after a hue turn."""
    return [np.diag(rng.uniform(*cfg.object_gain, 3)) @ hue_rotation(rng.uniform(-1, 1) * cfg.object_hue_deg)
            for _ in range(count)]


def environment_tint(cfg: AppearanceConfig, rng: np.random.Generator) -> np.ndarray:
    """[3, 3] colour transform of the environment: per-channel gains."""
    return np.diag(rng.uniform(*cfg.environment_tint, 3))


def environment_texture(cfg: AppearanceConfig, rng: np.random.Generator, objects: list[SplatCloud] = ()):
    """(texture function points [N, 3] -> rgb [N, 3], blend weight) repainting the environment, for a share
    ``cfg.retexture`` of scenes; None for the others. A share ``cfg.texture_object_colours`` of the repainted ones
    take one or two colours of the scene's ``objects`` (``distractors.object_palette``); the draws of the others are
    the same as without it."""
    repaint = rng.uniform() < cfg.retexture
    texture, weight = random_texture(rng, cfg.texture_period), float(rng.uniform(*cfg.texture_weight))
    if repaint and objects and cfg.texture_object_colours > 0 and rng.uniform() < cfg.texture_object_colours:
        texture = random_texture(rng, cfg.texture_period, palette_colours(object_palette(objects, rng), rng))
    return (texture, weight) if repaint else None


class ObjectLight(NamedTuple):
    """A distant light on a scene's objects: the unit direction [3] towards it (world), the ambient share of the
    diffuse shading, and its highlights' strength (0: none) and shininess (``splats.colour.shade_specular``)."""

    direction: np.ndarray
    ambient: float
    specular: float
    shininess: float


def object_light(cfg: AppearanceConfig, rng: np.random.Generator) -> ObjectLight | None:
    """The light on the objects (world z up, 20-90 degrees above the horizon, from a random azimuth) for a share
    ``cfg.object_light`` of scenes; None for the others."""
    lit = rng.uniform() < cfg.object_light
    azimuth, elevation = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(20, 90))
    direction = np.array([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
    ambient = float(rng.uniform(*cfg.object_ambient))
    specular, shininess = float(rng.uniform(*cfg.object_specular)), float(rng.uniform(*cfg.object_shininess))
    return ObjectLight(direction, ambient, specular, shininess) if lit else None


def image_motion(K: np.ndarray, T_before: np.ndarray, T_after: np.ndarray, point: np.ndarray,
                 frames_apart: int) -> np.ndarray:
    """[2] px per frame that ``point`` [3] (world, m) moves in the image between cameras T_before and
    T_after (T_cam_world [4, 4]) ``frames_apart`` frames apart."""
    def project(T):
        p = T[:3, :3] @ point + T[:3, 3]
        return (K @ (p / max(p[2], 1e-6)))[:2]
    return (project(T_after) - project(T_before)) / max(frames_apart, 1)


def frame_effects(cfg: AppearanceConfig, rng: np.random.Generator, motion_px: np.ndarray) -> tuple[SensorEffects, int]:
    """(the camera effects of one frame, its JPEG quality); ``motion_px`` [2]: the image motion per frame."""
    red, blue = rng.uniform(*cfg.white_balance, 2)
    effects = SensorEffects(exposure=float(2.0 ** rng.uniform(*cfg.exposure_ev)),
                            white_balance=(float(red), 1.0, float(blue)),
                            gamma=float(rng.uniform(*cfg.gamma)),
                            defocus_px=float(rng.uniform(*cfg.defocus_px)),
                            motion_px=tuple(float(v) for v in np.asarray(motion_px) * rng.uniform(*cfg.shutter)),
                            shot_noise=float(rng.uniform(*cfg.shot_noise)),
                            read_noise=float(rng.uniform(*cfg.read_noise)))
    return effects, int(rng.integers(cfg.jpg_quality[0], cfg.jpg_quality[1] + 1))
