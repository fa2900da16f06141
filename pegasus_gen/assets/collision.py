"""The geometric entity from splats: splat centres -> cleaned points -> alpha shape -> smoothed, decimated,
closed triangle mesh (open3d + trimesh), the paper's pipeline with the alpha chosen automatically.

The alpha radius starts at a few times the median neighbour spacing and grows until the alpha shape
is one closed manifold body (no inner cavity shell), so concave parts are kept as tight as the
sampling allows. Environments only
need a static triangle mesh and take the first alpha.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import open3d as o3d
import trimesh

from pegasus_gen.errors import PegasusError
from pegasus_gen.splats.cloud import SplatCloud

o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
VOLUME_PLATEAU = 0.02  # relative volume change between alphas that counts as "no longer growing"


@dataclass(frozen=True)
class MeshParams:
    """Every knob of :func:`splats_to_mesh` (recorded in the asset manifest)."""

    min_opacity: float = 0.2  # splats below this opacity are not surface evidence
    max_splat_size: float = 0.03  # m; splats with a larger standard deviation are floaters or blur
    outlier_neighbors: int = 20  # statistical outlier removal: neighbours considered
    outlier_std_ratio: float = 2.0  # ... and the distance threshold in standard deviations
    max_points: int = 40_000  # voxel-downsample the centres above this count
    alpha_start: float = 4.0  # first alpha radius, in median neighbour spacings
    alpha_growth: float = 1.25  # alpha factor between attempts
    alpha_max_fraction: float = 0.5  # give up when alpha exceeds this fraction of the bounding-box diagonal
    smooth_iterations: int = 10  # Taubin (volume-preserving Laplacian) smoothing passes
    max_triangles: int = 2000  # quadric decimation target


def _clean_points(cloud: SplatCloud, params: MeshParams) -> o3d.geometry.PointCloud:
    keep = (cloud.opacities >= params.min_opacity) & (cloud.scales.max(axis=1) <= params.max_splat_size)
    points = cloud.means[keep].astype(np.float64)
    if len(points) < 20:
        raise PegasusError(f"only {len(points)} splats have opacity >= {params.min_opacity} and size <= "
                           f"{params.max_splat_size} m: too few for a mesh")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if len(points) > params.max_points:
        diag = np.linalg.norm(np.ptp(points, axis=0))
        pcd = pcd.voxel_down_sample(diag * (1.0 / params.max_points) ** (1 / 2.2))
    pcd, _ = pcd.remove_statistical_outlier(params.outlier_neighbors, params.outlier_std_ratio)
    return pcd


def _as_trimesh(mesh: o3d.geometry.TriangleMesh) -> trimesh.Trimesh:
    out = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), process=False)
    out.merge_vertices()
    out.update_faces(out.nondegenerate_faces())
    out.update_faces(out.unique_faces())
    out.remove_unreferenced_vertices()
    return out


def _closing_alpha_shape(pcd, tetra, pt_map, alpha: float, params: MeshParams, diag: float):
    """(alpha shape, alpha): the smallest alpha whose shape is closed and whose volume no longer grows.

    A closed shape can still hide an empty inner cavity (tetrahedra deep inside a thick part are larger
    than alpha); the volume jumps once alpha fills it, then plateaus: the first plateau is the answer.
    """
    candidate = None  # (shape, alpha, volume) of the last closed shape
    while alpha <= params.alpha_max_fraction * diag:
        shape = _as_trimesh(o3d.geometry.TriangleMesh.create_from_point_cloud_alpha_shape(pcd, alpha, tetra, pt_map))
        if shape.is_watertight and shape.body_count == 1:
            trimesh.repair.fix_normals(shape)
            volume = abs(shape.volume)
            if candidate is not None and volume <= candidate[2] * (1 + VOLUME_PLATEAU):
                return candidate[0], candidate[1]
            candidate = (shape, alpha, volume)
        alpha *= params.alpha_growth
    if candidate is not None:
        return candidate[0], candidate[1]
    raise PegasusError(f"the splats do not close into a watertight mesh (alpha shapes up to "
                       f"{1000 * alpha / params.alpha_growth:.1f} mm tried); is this an open surface?")


def _decimate(smooth: o3d.geometry.TriangleMesh, params: MeshParams, closed: bool) -> trimesh.Trimesh:
    """The smoothed mesh decimated to at most ``params.max_triangles``. Decimation can open seams: small holes
    are filled, and for a closed mesh a decimation that stays open is retried with fewer triangles (another
    collapse order) before it is refused."""
    n = len(smooth.triangles)
    fractions = np.arange(1.0, 0.25, -0.1)  # 100 % of the budget down to 30 %
    targets = [round(params.max_triangles * f) for f in fractions] if n > params.max_triangles else [n]
    for target in targets:
        mesh = _as_trimesh(smooth if target == n else smooth.simplify_quadric_decimation(target))
        trimesh.repair.fix_normals(mesh)
        if closed and not mesh.is_watertight:
            trimesh.repair.fill_holes(mesh)
        if not closed or mesh.is_watertight:
            return mesh
    raise PegasusError("the decimated collision mesh is not closed; raise max_triangles")


def decimate_mesh(mesh: trimesh.Trimesh, params: MeshParams = MeshParams()) -> trimesh.Trimesh:
    """A closed ``mesh`` (e.g. an imported model) as a collision mesh: decimated to at most
    ``params.max_triangles``, still closed (PegasusError when no decimation stays closed)."""
    source = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                       o3d.utility.Vector3iVector(mesh.faces))
    return _decimate(source, params, closed=True)


def splats_to_mesh(cloud: SplatCloud, params: MeshParams = MeshParams(), closed: bool = True
                   ) -> tuple[trimesh.Trimesh, dict]:
    """Collision mesh (metres, the cloud's frame) and a report {params, alpha, volume, watertight}.

    closed=True (objects) requires a closed manifold and raises PegasusError when none is found;
    closed=False (environments) returns the alpha shape at the starting alpha.
    """
    pcd = _clean_points(cloud, params)
    spacing = float(np.median(np.asarray(pcd.compute_nearest_neighbor_distance())))
    diag = float(np.linalg.norm(np.ptp(np.asarray(pcd.points), axis=0)))
    if np.linalg.svd(np.asarray(pcd.points) - np.asarray(pcd.points).mean(0), compute_uv=False)[-1] < 1e-9:
        raise PegasusError("the splat centres are coplanar: a flat sheet has no volume to close into a mesh")
    tetra, pt_map = o3d.geometry.TetraMesh.create_from_point_cloud(pcd)
    alpha = params.alpha_start * spacing
    if closed:
        shape, alpha = _closing_alpha_shape(pcd, tetra, pt_map, alpha, params, diag)
    else:
        shape = _as_trimesh(o3d.geometry.TriangleMesh.create_from_point_cloud_alpha_shape(pcd, alpha, tetra, pt_map))
    trimesh.repair.fix_normals(shape)
    raw = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(shape.vertices),
                                    o3d.utility.Vector3iVector(shape.faces))
    smoothed = params.smooth_iterations > 0
    try:
        mesh = _decimate(raw.filter_smooth_taubin(params.smooth_iterations) if smoothed else raw, params, closed)
    except PegasusError:
        if not smoothed:
            raise
        # smoothing can pull two vertices of a thin part together; the merged vertex opens the surface
        smoothed = False
        mesh = _decimate(raw, params, closed)
    report = {"params": asdict(params), "alpha": alpha, "spacing": spacing, "points": len(pcd.points),
              "smoothed": smoothed, "triangles": len(mesh.faces), "watertight": bool(mesh.is_watertight),
              "volume": float(mesh.volume) if mesh.is_watertight else None}
    return mesh, report


def is_concave(mesh: trimesh.Trimesh, fill_ratio: float = 0.95) -> bool:
    """True when the closed ``mesh`` fills less than ``fill_ratio`` of its convex hull's volume."""
    return mesh.volume < fill_ratio * mesh.convex_hull.volume


def convex_decomposition(mesh: trimesh.Trimesh, out_path, resolution: int = 100_000) -> int:
    """Write the convex parts of ``mesh`` (PyBullet's V-HACD) as one OBJ with an object per part.

    PyBullet loads such an OBJ as a compound of convex hulls. Returns the number of parts.
    V-HACD's console output goes to ``<out_path>.log``.
    """
    import os
    import tempfile

    from pegasus_gen.io.bullet import quiet_pybullet

    pybullet = quiet_pybullet()

    out_path = str(out_path)
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "in.obj")
        mesh.export(src)
        saved = os.dup(1)  # V-HACD prints progress from C: silence the process's stdout meanwhile
        try:
            with open(out_path + ".log", "w") as log:
                os.dup2(log.fileno(), 1)
                pybullet.vhacd(src, out_path, os.path.join(tmp, "vhacd.log"), resolution=resolution)
        finally:
            os.dup2(saved, 1)
            os.close(saved)
    with open(out_path) as f:
        parts = sum(1 for line in f if line.startswith("o "))
    if parts == 0:
        raise PegasusError(f"{out_path}: V-HACD produced no convex parts")
    return parts
