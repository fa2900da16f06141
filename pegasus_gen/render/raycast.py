"""Exact z-depth images of triangle meshes by ray casting (Open3D's Embree scene), independent of the splats.

Used where a mesh is the truth: checking a dataset's masks and depth against its models (validate),
measuring how much of a camera's view an environment fills and how much of each object the others hide
(trajectories) and which splats placed objects shade (shadows).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import trimesh


class MeshRaycaster:
    """A triangle mesh prepared once for casting many camera views at it."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                                 o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))

    def depth(self, K: np.ndarray, T_cam_mesh: np.ndarray, width: int, height: int) -> np.ndarray:
        """[H, W] float32 z-depth (mesh units) seen by the pinhole camera ``K`` [3, 3] at ``T_cam_mesh`` [4, 4]
        (mesh frame -> camera, same units); 0 where a pixel's ray misses the mesh. One ray per pixel centre."""
        hits = self.cast(*_pixel_rays(K, T_cam_mesh, width, height))
        return np.where(np.isfinite(hits), hits, np.float32(0.0))

    def surface(self, K: np.ndarray, T_cam_mesh: np.ndarray, width: int, height: int) -> tuple[np.ndarray,
                                                                                                np.ndarray]:
        """What each pixel centre's ray (``depth``'s camera) hits first: the face [H, W] int64 (-1 on a miss) and
        the hit's barycentric weights [H, W, 3] float32 of the face's three vertices (0 on a miss)."""
        origin, directions = _pixel_rays(K, T_cam_mesh, width, height)
        rays = np.empty((height, width, 6), np.float32)
        rays[..., :3], rays[..., 3:] = origin, directions
        out = self.scene.cast_rays(o3d.core.Tensor.from_numpy(rays.reshape(-1, 6)))
        ids = out["primitive_ids"].numpy().astype(np.int64).reshape(height, width)
        uv = out["primitive_uvs"].numpy().reshape(height, width, 2)
        miss = ids == o3d.t.geometry.RaycastingScene.INVALID_ID
        ids[miss] = -1
        weights = np.stack([1.0 - uv[..., 0] - uv[..., 1], uv[..., 0], uv[..., 1]], axis=-1).astype(np.float32)
        weights[miss] = 0.0
        return ids, weights

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """float32 [...] ray parameter t of the first hit of each ray origins + t directions (arrays [..., 3]
        broadcast against each other, e.g. one origin [3] and directions [N, 3]); inf on a miss (with unit
        directions, t is the distance)."""
        rays = _rays(origins, directions)
        return self.scene.cast_rays(o3d.core.Tensor.from_numpy(rays.reshape(-1, 6)))["t_hit"].numpy() \
            .reshape(rays.shape[:-1])

    def occluded(self, origins: np.ndarray, directions: np.ndarray, max_t: float = np.inf) -> np.ndarray:
        """bool [...]: whether the ray origins + t directions (``cast``'s arrays) hits the mesh at some t <= max_t
        (inf: anywhere). ``cast``'s t (finite) <= max_t, but Embree stops at the first hit it finds instead of
        searching for the nearest: 3-4x faster where most rays hit, 1.2x on generated scenes' contact shadows."""
        rays = _rays(origins, directions)
        return self.scene.test_occlusions(o3d.core.Tensor.from_numpy(rays.reshape(-1, 6)), tfar=float(max_t)) \
            .numpy().reshape(rays.shape[:-1])

    def view_coverage(self, K: np.ndarray, T_cam_world: np.ndarray, width: int, height: int,
                      samples: tuple[int, int] = (16, 12)) -> float:
        """Fraction of the image (sampled on a ``samples`` = (columns, rows) grid) in which the mesh (world
        frame) is seen: 1.0 when an environment fills the whole view."""
        cols, rows = samples
        K_coarse = np.array(K, dtype=np.float64)
        K_coarse[0] *= cols / width
        K_coarse[1] *= rows / height
        K_coarse[0, 2] += 0.5 * cols / width - 0.5  # keep pixel centres at integer coordinates
        K_coarse[1, 2] += 0.5 * rows / height - 0.5
        return float((self.depth(K_coarse, T_cam_world, cols, rows) > 0).mean())


class SceneRaycaster:
    """Several triangle meshes in one frame (e.g. placed objects in the world) prepared once for casting rays at;
    each ray's first hit says which of them it hit."""

    def __init__(self, meshes: list[trimesh.Trimesh]):
        self.scene = o3d.t.geometry.RaycastingScene()
        ids = [self.scene.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                                        o3d.core.Tensor(np.asarray(m.faces, np.uint32))) for m in meshes]
        self._index = np.full(max(ids, default=0) + 1, -1, np.int64)
        self._index[ids] = np.arange(len(ids))

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the rays origins + t directions (``MeshRaycaster.cast``'s arrays): t [...] float32 of the first hit
        (inf on a miss) and the index [...] int64 into the meshes of what it hit (-1 on a miss)."""
        rays = _rays(origins, directions)
        out = self.scene.cast_rays(o3d.core.Tensor.from_numpy(rays.reshape(-1, 6)))
        ids = out["geometry_ids"].numpy().astype(np.int64)
        hit = ids != o3d.t.geometry.RaycastingScene.INVALID_ID
        index = np.full(ids.shape, -1, np.int64)
        index[hit] = self._index[ids[hit]]
        return out["t_hit"].numpy().reshape(rays.shape[:-1]), index.reshape(rays.shape[:-1])


def _rays(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """[..., 6] float32 rays (origin, direction) of ``origins`` and ``directions`` [..., 3] broadcast together."""
    shape = np.broadcast_shapes(np.shape(origins), np.shape(directions))
    rays = np.empty((*shape[:-1], 6), np.float32)  # filled in place: no float64 copies of every ray
    rays[..., :3] = origins
    rays[..., 3:] = directions
    return rays


def _pixel_rays(K: np.ndarray, T_cam_mesh: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The camera's origin [3] in the mesh frame and the ray through each pixel centre [H, W, 3] float32 (mesh
    frame, unit z in the camera: a hit's ray parameter is its z-depth)."""
    R_mesh_cam = np.asarray(T_cam_mesh, np.float64)[:3, :3].T
    origin = -R_mesh_cam @ np.asarray(T_cam_mesh, np.float64)[:3, 3]
    # the ray through pixel (u, v), R_mesh_cam [(u - cx) / fx, (v - cy) / fy, 1], is linear in u and v
    du, dv = R_mesh_cam[:, 0] / K[0, 0], R_mesh_cam[:, 1] / K[1, 1]
    d0 = R_mesh_cam[:, 2] - K[0, 2] * du - K[1, 2] * dv
    rows = (np.arange(height)[:, None] * dv + d0).astype(np.float32)  # [H, 3]
    return origin, np.arange(width, dtype=np.float32)[None, :, None] * du.astype(np.float32) + rows[:, None, :]
