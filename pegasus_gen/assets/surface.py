"""Surface models: an object's real surface as a fine triangle mesh with per-vertex colours (metres, asset
frame), separate from the low-poly collision mesh the physics uses.

The surface is what a dataset writes as the BOP model and what its masks are computed from, so it is made
from the same source as the splats: an imported mesh subdivided and coloured from its own texture, or, for
splat objects (scans, 3DGS files), a fine reconstruction on the splat centres coloured by the splats.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from pegasus_gen.assets.collision import MeshParams, splats_to_mesh
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.from_mesh import surface_colors
from pegasus_gen.splats.sh import sh_dc_to_rgb

MAX_EDGE = 0.0015  # m: longest edge of a surface model (texture detail kept per vertex)
SPLAT_SURFACE = MeshParams(smooth_iterations=3, max_triangles=60_000)  # finer than the collision mesh
COLOUR_NEIGHBOURS = 4  # splats averaged for a reconstructed surface's vertex colour


def with_colors(mesh: trimesh.Trimesh, rgb: np.ndarray) -> trimesh.Trimesh:
    """``mesh`` with per-vertex colours rgb [V, 3] in [0, 1]."""
    rgba = np.concatenate([np.round(np.clip(rgb, 0, 1) * 255), np.full((len(rgb), 1), 255)], 1).astype(np.uint8)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=rgba, process=False)


def mesh_surface(mesh: trimesh.Trimesh, max_edge: float = MAX_EDGE) -> trimesh.Trimesh:
    """A mesh (metres; textured, vertex- or face-coloured, or plain) subdivided until no edge is longer than
    ``max_edge`` and coloured per vertex from its own appearance (the colour at each new vertex's point of
    the original face). Vertices split at texture seams stay split."""
    vertices, faces, index = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge,
                                                              max_iter=20, return_index=True)
    fine = trimesh.Trimesh(vertices, faces, process=False)
    # each vertex's colour from one face containing it: its original face and barycentric weights there
    face_of_vertex = np.zeros(len(vertices), np.int64)
    face_of_vertex[faces.ravel()] = np.repeat(np.arange(len(faces)), 3)
    source = index[face_of_vertex]
    with np.errstate(divide="ignore", invalid="ignore"):
        bary = trimesh.triangles.points_to_barycentric(np.asarray(mesh.triangles)[source], vertices)
    bary = np.where(np.isfinite(bary).all(axis=1, keepdims=True), bary, 1.0 / 3.0)  # a zero-area face: its mean
    return with_colors(fine, surface_colors(mesh, source, np.clip(bary, 0.0, 1.0)))


def splat_surface(cloud: SplatCloud, params: MeshParams = SPLAT_SURFACE) -> trimesh.Trimesh:
    """A closed surface reconstructed on the opaque splat centres of ``cloud`` (metres, its frame), each
    vertex coloured with the mean view-independent (SH DC) colour of its nearest opaque splats."""
    surface, _ = splats_to_mesh(cloud, params)
    opaque = cloud.opacities >= params.min_opacity
    _, nearest = cKDTree(cloud.means[opaque]).query(surface.vertices, k=COLOUR_NEIGHBOURS)
    rgb = sh_dc_to_rgb(cloud.sh[opaque][:, 0, :])  # [N, 3] colour of each opaque splat
    return with_colors(surface, rgb[nearest].mean(axis=1))
