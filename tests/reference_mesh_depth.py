"""A brute-force, obviously-correct depth image of a triangle mesh, for checking labels against BOP's definitions.

Every triangle is projected; every pixel centre (integer image coordinates, OpenCV convention) inside its
bounding box is tested with the three edge functions, and a pixel inside gets the z of its ray's
intersection with the triangle's plane if nearer than what it holds. No ray-casting library, no code shared
with pegasus_gen.
"""

import numba
import numpy as np


@numba.njit(cache=True)
def _zbuffer(cam, faces, fx, fy, cx, cy, depth):
    height, width = depth.shape
    for f in range(faces.shape[0]):
        a, b, c = cam[faces[f, 0]], cam[faces[f, 1]], cam[faces[f, 2]]
        if a[2] <= 0 or b[2] <= 0 or c[2] <= 0:
            continue
        ua, va = fx * a[0] / a[2] + cx, fy * a[1] / a[2] + cy
        ub, vb = fx * b[0] / b[2] + cx, fy * b[1] / b[2] + cy
        uc, vc = fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy
        area = (ub - ua) * (vc - va) - (uc - ua) * (vb - va)
        if area == 0:
            continue
        n = np.cross(b - a, c - a)
        d = n[0] * a[0] + n[1] * a[1] + n[2] * a[2]
        x0, x1 = max(0, int(np.ceil(min(ua, ub, uc)))), min(width - 1, int(np.floor(max(ua, ub, uc))))
        y0, y1 = max(0, int(np.ceil(min(va, vb, vc)))), min(height - 1, int(np.floor(max(va, vb, vc))))
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                w0 = (ub - x) * (vc - y) - (uc - x) * (vb - y)
                w1 = (uc - x) * (va - y) - (ua - x) * (vc - y)
                w2 = (ua - x) * (vb - y) - (ub - x) * (va - y)
                if area < 0:
                    w0, w1, w2 = -w0, -w1, -w2
                if w0 < 0 or w1 < 0 or w2 < 0:
                    continue
                rx, ry = (x - cx) / fx, (y - cy) / fy
                z = d / (n[0] * rx + n[1] * ry + n[2])
                if z > 0 and (depth[y, x] == 0 or z < depth[y, x]):
                    depth[y, x] = z


def mesh_depth(vertices, faces, K, T_cam_obj, width, height):
    """[height, width] z-depth (units of ``vertices``) of the mesh at T_cam_obj [4, 4] seen by K [3, 3]; 0
    where no triangle covers a pixel centre."""
    cam = np.asarray(vertices, np.float64) @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    depth = np.zeros((height, width))
    _zbuffer(cam, np.asarray(faces, np.int64), K[0, 0], K[1, 1], K[0, 2], K[1, 2], depth)
    return depth
