"""Meshes to splats: surface samples coloured from the mesh's texture or vertex colours, flat Gaussians.

This is how CAD models and meshes from other tools become splat assets. Units: the mesh's (metres
expected); the splats lie in the mesh frame.
"""

from __future__ import annotations

import os

import numpy as np
import trimesh

from pegasus_gen.errors import PegasusError
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.surface_splats import surface_splats

DEFAULT_SPACING = 0.002  # metres between neighbouring splats
# how far (in spacings) an object's splats sit inside its surface (``import-mesh`` of an object): a flat Gaussian on
# a curved or creased surface overhangs its outline, so splats on the surface render 1.2-1.7 % larger than the mesh
# (LM-O's ape, cat, duck and holepuncher, 2 mm apart, at 150-200 px across); 0.275 spacings in brings all four to
# within 0.4 % there (benchmarks/silhouette.py), leaving the renderer's half-pixel low-pass (0.5-0.7 % at 50-70 px)
SILHOUETTE_INSET = 0.275


MAX_SPLATS = 2_000_000  # a mesh import's splat budget (~1 GB while building); a finer spacing is refused


def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """One triangle mesh from an OBJ/PLY/STL/GLB file (scenes are merged), with its texture if any; a mesh
    with a non-finite vertex is refused."""
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise PegasusError(f"{path}: cannot read mesh ({exc.__class__.__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise PegasusError(f"{path}: the file holds no triangle mesh")
        loaded = geoms[0] if len(geoms) == 1 else trimesh.util.concatenate(geoms)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise PegasusError(f"{path}: the file holds no triangle mesh")
    bad = int((~np.isfinite(np.asarray(loaded.vertices))).any(axis=1).sum())
    if bad:
        raise PegasusError(f"{path}: {bad} vertex(es) with a NaN or infinite coordinate")
    return loaded


def _sample_texture(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup. image [H, W, 3] float in [0, 1]; uv [N, 2], origin bottom-left. Returns [N, 3].

    Coordinates outside [0, 1] repeat the texture (beyond a rounding tolerance: an interpolated 1 + 1e-16 is
    the edge, not the start again); samples at the border clamp to the edge texels.
    """
    h, w = image.shape[:2]
    uv = np.where((uv < -1e-9) | (uv > 1 + 1e-9), uv % 1.0, np.clip(uv, 0.0, 1.0))
    u = uv[:, 0] * w - 0.5
    v = (1.0 - uv[:, 1]) * h - 0.5
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    u0, u1 = np.clip(u0, 0, w - 1), np.clip(u0 + 1, 0, w - 1)
    v0, v1 = np.clip(v0, 0, h - 1), np.clip(v0 + 1, 0, h - 1)
    return ((image[v0, u0] * (1 - fu) + image[v0, u1] * fu) * (1 - fv)
            + (image[v1, u0] * (1 - fu) + image[v1, u1] * fu) * fv)


def surface_colors(mesh: trimesh.Trimesh, faces: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Colour [N, 3] in [0, 1] at barycentric points ``bary`` [N, 3] of ``faces`` [N]."""
    visual = mesh.visual
    if visual.kind == "texture" and getattr(visual, "uv", None) is not None:
        image = getattr(visual.material, "image", None) or getattr(visual.material, "baseColorTexture", None)
        if image is not None:
            rgb = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
            uv = np.einsum("nk,nkj->nj", bary, np.asarray(visual.uv)[mesh.faces[faces]])
            return _sample_texture(rgb, uv)
        color = getattr(visual.material, "main_color", None)
        return np.tile(np.asarray(color[:3], float) / 255.0 if color is not None else [0.6] * 3, (len(faces), 1))
    if visual.kind == "vertex":
        colors = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
        return np.einsum("nk,nkj->nj", bary, colors[mesh.faces[faces]])
    if visual.kind == "face":
        return np.asarray(visual.face_colors, dtype=np.float64)[faces, :3] / 255.0
    return np.full((len(faces), 3), 0.6)


def mesh_to_splats(mesh: trimesh.Trimesh, rng: np.random.Generator, spacing: float = DEFAULT_SPACING,
                   sh_degree: int = 0, opacity: float = 0.95, label: int = 0, inset: float = 0.0) -> SplatCloud:
    """Cover ``mesh`` with flat Gaussians about ``spacing`` metres apart, coloured from its surface.

    Samples are area-uniform; each Gaussian lies in its face's plane (thin along the face normal), its centre
    ``inset * spacing`` behind the surface (along the face normal, which must point outwards; ``SILHOUETTE_INSET``
    makes the splats render the mesh's outline rather than overhang it).
    """
    if not (np.isfinite(spacing) and spacing > 0):
        raise PegasusError(f"--spacing must be a positive number of metres, got {spacing}")
    count = max(1, int(round(mesh.area / spacing**2)))
    if count > MAX_SPLATS:
        raise PegasusError(f"--spacing {spacing} m would cover the mesh's {mesh.area:.4g} m2 with {count:,} splats "
                           f"(at most {MAX_SPLATS:,}): use --spacing {np.sqrt(mesh.area / MAX_SPLATS):.2g} or more")
    points, faces, bary = _sample_surface(mesh, count, rng)
    normals = np.asarray(mesh.face_normals)[faces]
    if mesh.is_watertight and mesh.volume < 0:  # wound inside out: the normals point in
        normals = -normals
    colors = np.clip(surface_colors(mesh, faces, bary), 0.0, 1.0)
    return surface_splats(points - inset * spacing * normals, normals, colors, spacing, rng, sh_degree=sh_degree,
                          view_dependence=0.0, opacity=opacity, label=label)


def _sample_surface(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator):
    """(points [count, 3], face index [count], barycentric weights [count, 3]), area-uniform."""
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    cumulative = np.cumsum(areas)
    faces = np.minimum(np.searchsorted(cumulative, rng.uniform(0, cumulative[-1], count)), len(areas) - 1)
    r1, r2 = rng.uniform(size=(2, count))
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    tri = np.asarray(mesh.vertices, dtype=np.float64)[mesh.faces[faces]]
    return np.einsum("nk,nkj->nj", bary, tri), faces, bary
