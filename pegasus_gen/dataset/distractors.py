"""Distractors: procedural clutter (boxes, cylinders, spheres with random textures, or painted in the objects'
colours) dropped with the objects.

They are physical (they collide, fall, occlude and cast shadows) and rendered, but never labelled: they
have no model in ``models/``, so the dataset's scene_gt, gt_info, COCO and DOPE files leave them out
(BOP's obj_ids must refer to models, and a network trained on the dataset is to learn that they are not
targets). What they hide of a target is still accounted for: the target's ``mask_visib`` and
``visib_fract`` come from the rendered depth, which they are in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from pegasus_gen.dataset.config import DistractorConfig
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.procedural import random_texture
from pegasus_gen.splats.sh import sh_dc_to_rgb
from pegasus_gen.splats.surface_splats import surface_splats

SPACING = 0.004  # m between neighbouring splats
TEXTURE_PERIOD = (0.008, 0.04)  # m
DENSITY = (200.0, 900.0)  # kg/m^3


@dataclass
class Distractor:
    """A clutter object: ``splats`` and ``surface`` (its exact convex shape) in its frame (origin at the centre
    of mass, which for these symmetric solids is the bounding-box centre); ``mass`` in kg."""

    name: str
    splats: SplatCloud
    surface: trimesh.Trimesh
    mass: float

    @property
    def mesh(self) -> trimesh.Trimesh:
        """The collision shape (the surface itself: every distractor is convex)."""
        return self.surface


PALETTE_SPLATS = 256  # splat colours drawn from each object for the distractors' palette


def object_palette(clouds: list[SplatCloud], rng: np.random.Generator) -> np.ndarray:
    """rgb [P, 3] (0..1): the base (view-independent) colours of ``PALETTE_SPLATS`` random splats of each cloud."""
    dc = np.concatenate([c.sh[rng.integers(len(c), size=PALETTE_SPLATS), 0] for c in clouds])
    return np.clip(sh_dc_to_rgb(dc), 0.0, 1.0)


def palette_colours(palette: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """rgb [1 or 2, 3]: one or two colours drawn from ``palette`` [P, 3]."""
    return palette[rng.integers(len(palette), size=int(rng.integers(1, 3)))]


def make_distractor(cfg: DistractorConfig, rng: np.random.Generator, index: int,
                    palette: np.ndarray | None = None) -> Distractor:
    """A random box, cylinder or sphere whose largest extent is drawn from ``cfg.size`` (m), textured: with
    probability ``cfg.object_colours`` (and a ``palette`` [P, 3] of the scene's objects' colours) in one or two
    of the palette's colours, a look-alike of the objects' colour without their shape; else in random colours."""
    colours = None
    if cfg.object_colours > 0 and palette is not None and rng.random() < cfg.object_colours:
        colours = palette_colours(palette, rng)
    size = rng.uniform(*cfg.size)
    kind = ("box", "cylinder", "sphere")[int(rng.integers(3))]
    if kind == "box":
        extents = rng.uniform(0.3, 1.0, 3)
        surface = trimesh.creation.box(extents=size * extents / extents.max())
    elif kind == "cylinder":
        radius, height = size / 2 * rng.uniform(0.3, 1.0), size * rng.uniform(0.3, 1.0)
        surface = trimesh.creation.cylinder(radius=radius, height=height, sections=32)
    else:
        surface = trimesh.creation.icosphere(subdivisions=3, radius=size / 2 * rng.uniform(0.4, 1.0))
    count = max(200, int(surface.area / SPACING**2))
    points, faces = trimesh.sample.sample_surface(surface, count, seed=int(rng.integers(2**31)))
    normals = surface.face_normals[faces]
    splats = surface_splats(points, normals, random_texture(rng, TEXTURE_PERIOD, colours)(points), SPACING, rng)
    return Distractor(f"distractor_{index}_{kind}", splats, surface, float(surface.volume * rng.uniform(*DENSITY)))
