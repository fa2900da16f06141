"""Importing splat files and meshes as assets: scale, frame conventions, support-plane alignment.

Objects end up in their object frame (origin at the collision mesh's bounding-box centre, z up as
given). Environments are aligned so their dominant support plane (RANSAC) is z = 0 with z up, the
plane's inliers centred on the origin, and the drop region taken from those inliers.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import open3d as o3d
import trimesh
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from pegasus_gen.assets.collision import MeshParams, decimate_mesh, splats_to_mesh
from pegasus_gen.assets.library import Asset, AssetLibrary, AssetManifest, DropRegion, check_new_asset, save_asset
from pegasus_gen.assets.surface import mesh_surface, splat_surface
from pegasus_gen.errors import PegasusError
from pegasus_gen.splats.cloud import SplatCloud, is_rigid
from pegasus_gen.splats.from_mesh import DEFAULT_SPACING, SILHOUETTE_INSET, load_mesh, mesh_to_splats
from pegasus_gen.splats.ply import read_ply


def support_plane_alignment(points: np.ndarray, rng: np.random.Generator, distance: float = 0.005
                            ) -> tuple[np.ndarray, np.ndarray]:
    """(T [4, 4] putting the dominant plane of ``points`` [N, 3] at z = 0, z up; inlier mask [N]).

    The plane normal is oriented towards the side holding most of the off-plane points (the clutter on
    a table lies above it); the inliers' centroid goes to the origin and their principal axis to x.
    """
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    o3d.utility.random.seed(int(rng.integers(2**31)))
    (a, b, c, d), inliers = pcd.segment_plane(distance_threshold=distance, ransac_n=3, num_iterations=2000)
    if len(inliers) < 0.05 * len(points):
        raise PegasusError(f"no dominant support plane found ({len(inliers)} of {len(points)} points on it)")
    normal = np.array([a, b, c]) / np.linalg.norm([a, b, c])
    offset = d / np.linalg.norm([a, b, c])
    side = points @ normal + offset
    mask = np.zeros(len(points), bool)
    mask[inliers] = True
    off_plane = side[~mask]
    if (off_plane > 0).sum() < (off_plane < 0).sum() or (len(off_plane) == 0 and normal[2] < 0):
        normal, offset = -normal, -offset
    axis = np.cross(normal, [0.0, 0.0, 1.0])
    angle = np.arctan2(np.linalg.norm(axis), normal[2])
    R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix() if np.linalg.norm(axis) > 1e-12 \
        else (np.eye(3) if normal[2] > 0 else np.diag([1.0, -1.0, -1.0]))
    level = np.asarray(points)[mask] @ R.T
    # yaw: the plane's principal axes along x and y, so the axis-aligned drop region fits it tightly
    xy = level[:, :2] - level[:, :2].mean(axis=0)
    major = np.linalg.eigh(xy.T @ xy)[1][:, -1]
    yaw = -np.arctan2(major[1], major[0])
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]) @ R
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -(np.asarray(points)[mask] @ R.T).mean(axis=0)
    return T, mask


def _drop_region(points_on_plane: np.ndarray, margin: float = 0.1) -> DropRegion:
    lo, hi = np.percentile(points_on_plane[:, :2], [2, 98], axis=0)
    inset = margin * (hi - lo)
    return DropRegion(x_min=lo[0] + inset[0], x_max=hi[0] - inset[0], y_min=lo[1] + inset[1], y_max=hi[1] - inset[1])


def _flat_polygon(points: np.ndarray) -> trimesh.Trimesh:
    """A fan-triangulated convex outline (at the median height) of points [N, 3] lying on a level plane."""
    xy = points[:, :2].astype(np.float64)
    ring = xy[ConvexHull(xy).vertices]
    z = float(np.median(points[:, 2]))
    vertices = np.concatenate([[np.r_[ring.mean(0), z]], np.c_[ring, np.full(len(ring), z)]])
    faces = [[0, i + 1, (i + 1) % len(ring) + 1] for i in range(len(ring))]
    return trimesh.Trimesh(vertices, faces, process=False)


def environment_mesh(cloud: SplatCloud, on_plane: np.ndarray, params: MeshParams) -> trimesh.Trimesh:
    """Static collision mesh of a levelled environment: its support plane as one flat polygon (exactly
    level, so dropped objects rest still) plus the alpha shape of everything off the plane."""
    parts = [_flat_polygon(cloud.means[on_plane])]
    rest = cloud.select(~on_plane)
    if len(rest) >= 20:
        try:
            parts.append(splats_to_mesh(rest, params, closed=False)[0])
        except PegasusError:  # too few or coplanar off-plane splats: the support plane alone
            pass
    return trimesh.util.concatenate(parts)


def _finish(cloud: SplatCloud, mesh: trimesh.Trimesh | None, name: str, kind: str, obj_id: int | None,
            library: AssetLibrary, rng: np.random.Generator, params: MeshParams, overwrite: bool,
            surface: trimesh.Trimesh | None = None, **fields) -> Asset:
    """Conventions applied and the asset saved: an environment levelled on its support plane, an object centred
    on its collision mesh's bounding box, with its ``surface`` (reconstructed from the splats when None)."""
    if kind == "environment":
        T, on_plane = support_plane_alignment(cloud.means, rng)
        cloud = cloud.transformed(T)
        mesh = environment_mesh(cloud, on_plane, params) if mesh is None else mesh.copy().apply_transform(T)
        manifest = AssetManifest(name=name, kind=kind, drop_region=_drop_region(cloud.means[on_plane]),
                                 support_height=0.0, **fields)
    else:  # an object (check_new_asset has checked kind and obj_id)
        if mesh is not None and mesh.is_watertight and len(mesh.faces) > params.max_triangles:
            try:  # a fine model (a scan's, a BOP model) collides as a decimated copy; it stays the surface
                mesh = decimate_mesh(mesh, params)
            except PegasusError:
                mesh = None  # no decimation stayed closed: one from the splats, as for an open mesh
        if mesh is None or not mesh.is_watertight:
            mesh, report = splats_to_mesh(cloud, params)
            fields["geometry"] = {k: v for k, v in report.items() if k != "volume"}
        centre = mesh.bounds.mean(axis=0)
        T = np.eye(4)
        T[:3, 3] = -centre
        cloud = cloud.transformed(T)
        mesh = mesh.copy().apply_translation(-centre)
        surface = splat_surface(cloud) if surface is None else surface.copy().apply_translation(-centre)
        manifest = AssetManifest(name=name, kind=kind, obj_id=obj_id, **fields)
    return save_asset(library.asset_path(name), manifest, cloud, mesh, surface, overwrite=overwrite)


def _check_placement(scale: float, transform) -> np.ndarray:
    if not (np.isfinite(scale) and scale > 0):
        raise PegasusError(f"--scale must be a positive finite number, got {scale}")
    T = np.eye(4) if transform is None else np.asarray(transform, dtype=np.float64).reshape(4, 4)
    if not is_rigid(T):
        raise PegasusError("--transform must be a rigid 4x4 transform (16 numbers, row-major)")
    return T


def import_splat(ply: str | os.PathLike, name: str, kind: str, library: AssetLibrary, obj_id: int | None = None,
                 scale: float = 1.0, transform=None, rng: np.random.Generator | None = None,
                 params: MeshParams = MeshParams(), overwrite: bool = False, **fields) -> Asset:
    """A trained 3DGS PLY as an asset in ``library``: scaled by ``scale`` to metres, then moved by the
    optional rigid ``transform`` [4, 4] (e.g. to make z up) before the conventions above apply."""
    check_new_asset(library, name, kind, obj_id, overwrite, **fields)
    T = _check_placement(scale, transform)
    return import_cloud(read_ply(ply).transformed(T, scale=scale), name, kind, library, obj_id, rng, params,
                        overwrite, **fields)


def import_cloud(cloud: SplatCloud, name: str, kind: str, library: AssetLibrary, obj_id: int | None = None,
                 rng: np.random.Generator | None = None, params: MeshParams = MeshParams(), overwrite: bool = False,
                 **fields) -> Asset:
    """A splat cloud already in metres and z up (e.g. from ``pegasus scan``) as an asset in ``library``."""
    check_new_asset(library, name, kind, obj_id, overwrite, **fields)
    return _finish(cloud, None, name, kind, obj_id, library, rng or np.random.default_rng(0), params, overwrite,
                   **fields)


def import_mesh(path: str | os.PathLike, name: str, kind: str, library: AssetLibrary, obj_id: int | None = None,
                scale: float = 1.0, transform=None, spacing: float = DEFAULT_SPACING,
                rng: np.random.Generator | None = None, params: MeshParams = MeshParams(), overwrite: bool = False,
                **fields) -> Asset:
    """A mesh file (OBJ + texture, PLY, ...) as an asset, scaled to metres and moved by the optional rigid
    ``transform``; its splats are sampled from its surface (an object's inside it: ``SILHOUETTE_INSET``)."""
    check_new_asset(library, name, kind, obj_id, overwrite, **fields)
    T = _check_placement(scale, transform)
    rng = rng or np.random.default_rng(0)
    mesh = load_mesh(Path(path))
    mesh.apply_scale(scale)
    mesh.apply_transform(T)
    cloud = mesh_to_splats(mesh, rng, spacing=spacing, inset=SILHOUETTE_INSET if kind == "object" else 0.0)
    collision = mesh.copy()
    collision.merge_vertices(merge_tex=True, merge_norm=True)  # OBJ/STL seams split vertices
    surface = mesh_surface(mesh) if kind == "object" else None
    return _finish(cloud, collision, name, kind, obj_id, library, rng, params, overwrite, surface, **fields)
