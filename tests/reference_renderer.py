"""A slow, obviously-correct splat renderer for tests: every pixel loops over all depth-sorted Gaussians.

Written from the 3DGS / gsplat forward equations (REFERENCE.md section 1) without sharing code with
pegasus_gen: its own quaternion algebra, SH formula and full 2x2 covariance inverse per Gaussian.
OpenCV pixel grid: pixel (u, v) is evaluated at image coordinates (u, v).
"""

import math

import numpy as np

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396]
C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
      1.445305721320277, -0.5900435899266435]


def sh_color(c, d):
    """c [K, 3], d unit direction [3] -> rgb [3] = max(sum + 0.5, 0)."""
    x, y, z = d
    terms = [C0, -C1 * y, C1 * z, -C1 * x,
             C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * z * z - x * x - y * y), C2[3] * x * z, C2[4] * (x * x - y * y),
             C3[0] * y * (3 * x * x - y * y), C3[1] * x * y * z, C3[2] * y * (4 * z * z - x * x - y * y),
             C3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y), C3[4] * x * (4 * z * z - x * x - y * y),
             C3[5] * z * (x * x - y * y), C3[6] * x * (x * x - 3 * y * y)]
    out = sum(terms[k] * c[k].astype(np.float64) for k in range(c.shape[0]))
    return np.maximum(out + 0.5, 0.0)


def quat_to_matrix(q):
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def reference_render(cloud, K, T_cam_world, width, height, background=(0, 0, 0), near=0.01, eps2d=0.3):
    """Returns dict rgb [H,W,3], alpha [H,W], depth_sum [H,W] (sum w z, each Gaussian's z where the pixel's ray
    meets its highest density: t = p^T S^-1 d / d^T S^-1 d for the ray t d, d = ((u - cx)/fx, (v - cy)/fy, 1),
    mean p and covariance S in the camera frame, held within 3.33 standard deviations of the mean's z),
    weights {label: [H,W]}."""
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    cam_center = -R.T @ t
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    # frustum clamp of gsplat (its pixel centres are at +0.5, so its principal point is cx + 0.5)
    lim_x = ((width - (cx + 0.5)) / fx + 0.3 * 0.5 * width / fx, (cx + 0.5) / fx + 0.3 * 0.5 * width / fx)
    lim_y = ((height - (cy + 0.5)) / fy + 0.3 * 0.5 * height / fy, (cy + 0.5) / fy + 0.3 * 0.5 * height / fy)
    gauss = []
    for i in range(len(cloud)):
        mean = cloud.means[i].astype(np.float64)
        p = R @ mean + t
        if p[2] <= near:
            continue
        o = 1 / (1 + math.exp(-float(cloud.opacity_logits[i])))
        if o < 1 / 255:
            continue
        M = quat_to_matrix(cloud.quats_wxyz[i]) @ np.diag(np.exp(cloud.log_scales[i].astype(np.float64)))
        cov_cam = R @ M @ M.T @ R.T
        z = p[2]
        tx = z * min(lim_x[0], max(-lim_x[1], p[0] / z))
        ty = z * min(lim_y[0], max(-lim_y[1], p[1] / z))
        J = np.array([[fx / z, 0, -fx * tx / z**2], [0, fy / z, -fy * ty / z**2]])
        cov2 = J @ cov_cam @ J.T + eps2d * np.eye(2)
        d = mean - cam_center
        color = sh_color(cloud.sh[i], d / np.linalg.norm(d))
        mu = np.array([fx * p[0] / z + cx, fy * p[1] / z + cy])
        info = np.linalg.inv(cov_cam)
        z_range = (z - 3.33 * math.sqrt(cov_cam[2, 2]), z + 3.33 * math.sqrt(cov_cam[2, 2]))
        gauss.append((z, mu, np.linalg.inv(cov2), o, color, int(cloud.labels[i]), info @ p, info, z_range))
    gauss.sort(key=lambda g: g[0])
    rgb = np.zeros((height, width, 3))
    alpha = np.zeros((height, width))
    depth_sum = np.zeros((height, width))
    weights = {}
    for v in range(height):
        for u in range(width):
            T = 1.0
            acc = np.zeros(3)
            ray = np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
            for z, mu, inv, o, color, label, info_p, info, z_range in gauss:
                dlt = mu - np.array([u, v], np.float64)
                power = -0.5 * dlt @ inv @ dlt
                if power > 0:
                    continue
                a = min(0.999, o * math.exp(power))
                if a < 1 / 255:
                    continue
                if T * (1 - a) <= 1e-4:
                    break
                w = a * T
                acc += w * color
                depth_sum[v, u] += w * np.clip((info_p @ ray) / (ray @ info @ ray), *z_range)
                weights.setdefault(label, np.zeros((height, width)))[v, u] += w
                T *= 1 - a
            rgb[v, u] = acc + T * np.asarray(background, np.float64)
            alpha[v, u] = 1 - T
    return {"rgb": rgb, "alpha": alpha, "depth_sum": depth_sum, "weights": weights}
