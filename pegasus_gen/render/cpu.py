"""Tile-based CPU Gaussian-splat rasterizer (numba), following the gsplat 1.5 forward math.

Pipeline: :func:`project` (per splat: camera transform, EWA covariance, conic, opacity-aware pixel
box, SH colour) -> depth sort -> :func:`bin_to_tiles` (per 16x16 tile, splats front to back) ->
:func:`rasterize` (per tile, front-to-back alpha blending with early termination; each splat visits
only its pixel box clipped to the tile, each row only the span where alpha >= 1/255).

Pixel convention: OpenCV, pixel (u, v) has its centre at image coordinates (u, v).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pegasus_gen.splats.sh import basis_into

# OpenMP first: some wheels (open3d's dependencies) bring a TBB too old for numba, which then warns.
numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

ALPHA_THRESHOLD = 1.0 / 255.0  # contributions below this are skipped
ALPHA_MAX = 0.999  # per-splat alpha clamp (gsplat; INRIA uses 0.99)
T_MIN = 1e-4  # a pixel stops when its transmittance would fall to this
EXTEND_MAX = 3.33  # pixel-box half size in standard deviations, at most
TILE = 16
NEAR_PLANE = 0.01  # metres, as gsplat
EPS2D = 0.3  # pixels^2 added to the 2D covariance diagonal (anti-aliasing low-pass), as 3DGS
# the antialiased mode's low-pass: Mip-Splatting's 2D filter (a Gaussian of 0.1 px^2 standing for a one-pixel box)
EPS2D_ANTIALIASED = 0.1
PROJECT_CHUNK = 4096  # splats per parallel work item in project()
GRAD_EPS = 1e-3  # px^2 added to the undilated 2D covariance before the depth gradient inverts it


def low_pass(antialiased: bool) -> float:
    """The 2D covariance's low-pass (px^2) of a render mode: EPS2D classic, EPS2D_ANTIALIASED antialiased."""
    return EPS2D_ANTIALIASED if antialiased else EPS2D


@numba.njit(cache=True)
def frustum_limits(width, height, fx, fy, cx, cy):
    """(x_neg, x_pos, y_neg, y_pos): bounds of x/z and y/z used in the EWA Jacobian. gsplat clamps the
    projected direction to the image frustum widened by 30% (its pixel centres sit at +0.5)."""
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    return ((cx + 0.5) / fx + 0.3 * tan_fovx, (width - cx - 0.5) / fx + 0.3 * tan_fovx,
            (cy + 0.5) / fy + 0.3 * tan_fovy, (height - cy - 0.5) / fy + 0.3 * tan_fovy)


@numba.njit(parallel=True, cache=True)
def project(means, quats, log_scales, opacity_logits, sh, R, t, cam_center, fx, fy, cx, cy,
            width, height, near, far, eps2d, antialiased, valid, mean2d, conic, depth, depth_grad, box, rgb,
            log_opacity):
    """Project splats into the image, writing into the given output arrays (all with N rows).

    Inputs: means [N,3], quats [N,4] wxyz, log_scales [N,3], opacity_logits [N], sh [N,K,3] (float32,
    world frame); R [3,3], t [3] world->camera; cam_center [3] world; fx, fy, cx, cy OpenCV intrinsics;
    antialiased: the opacity scaled by sqrt(det(cov2d) / det(cov2d + eps2d I)) (gsplat's antialiased mode: the
    low-pass keeps a splat's total weight, so a splat seen edge-on or smaller than a pixel does not widen what it
    covers).
    Outputs: valid [N] bool (False: culled, other outputs undefined), mean2d [N,2] pixels,
    conic [N,3] (A, B, C of the inverse 2D covariance), depth [N] camera z (m) of the centre,
    depth_grad [N,3] (dz/du, dz/dv in m/px, and a bound in m): the splat's depth at pixel offset (du, dv)
    from its centre is depth + clip(dz/du du + dz/dv dv, -bound, bound), the point of highest density on
    that pixel's ray (the conditional mean of z given the image position, in the same affine camera model as
    the covariance; on a flat splat, the ray's intersection with its plane), held within EXTEND_MAX standard
    deviations of z (a sub-pixel splat reaches neighbouring pixels through eps2d alone),
    box [N,4] int32 inclusive pixel box (x0, x1, y0, y1), rgb [N,3], log_opacity [N] (natural log).
    """
    n = means.shape[0]
    k = sh.shape[1]
    lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos = frustum_limits(width, height, fx, fy, cx, cy)
    log_alpha_thr = math.log(ALPHA_THRESHOLD)
    n_chunks = (n + PROJECT_CHUNK - 1) // PROJECT_CHUNK
    for chunk in numba.prange(n_chunks):
        bvals = np.empty(16, dtype=np.float64)  # SH basis scratch, one per chunk
        for i in range(chunk * PROJECT_CHUNK, min(n, (chunk + 1) * PROJECT_CHUNK)):
            valid[i] = False
            mx, my, mz = float(means[i, 0]), float(means[i, 1]), float(means[i, 2])
            x = R[0, 0] * mx + R[0, 1] * my + R[0, 2] * mz + t[0]
            y = R[1, 0] * mx + R[1, 1] * my + R[1, 2] * mz + t[1]
            z = R[2, 0] * mx + R[2, 1] * my + R[2, 2] * mz + t[2]
            if z <= near or z >= far:
                continue
            o = 1.0 / (1.0 + math.exp(-float(opacity_logits[i])))
            if o < ALPHA_THRESHOLD:
                continue
            # world covariance  M M^T with M = Rq diag(s)
            qw, qx, qy, qz = float(quats[i, 0]), float(quats[i, 1]), float(quats[i, 2]), float(quats[i, 3])
            qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            if qn == 0.0:
                continue
            qw /= qn
            qx /= qn
            qy /= qn
            qz /= qn
            s0 = math.exp(float(log_scales[i, 0]))
            s1 = math.exp(float(log_scales[i, 1]))
            s2 = math.exp(float(log_scales[i, 2]))
            m00 = (1 - 2 * (qy * qy + qz * qz)) * s0
            m01 = 2 * (qx * qy - qw * qz) * s1
            m02 = 2 * (qx * qz + qw * qy) * s2
            m10 = 2 * (qx * qy + qw * qz) * s0
            m11 = (1 - 2 * (qx * qx + qz * qz)) * s1
            m12 = 2 * (qy * qz - qw * qx) * s2
            m20 = 2 * (qx * qz - qw * qy) * s0
            m21 = 2 * (qy * qz + qw * qx) * s1
            m22 = (1 - 2 * (qx * qx + qy * qy)) * s2
            # camera-frame factor  C = R M  (covariance R M M^T R^T)
            c00 = R[0, 0] * m00 + R[0, 1] * m10 + R[0, 2] * m20
            c01 = R[0, 0] * m01 + R[0, 1] * m11 + R[0, 2] * m21
            c02 = R[0, 0] * m02 + R[0, 1] * m12 + R[0, 2] * m22
            c10 = R[1, 0] * m00 + R[1, 1] * m10 + R[1, 2] * m20
            c11 = R[1, 0] * m01 + R[1, 1] * m11 + R[1, 2] * m21
            c12 = R[1, 0] * m02 + R[1, 1] * m12 + R[1, 2] * m22
            c20 = R[2, 0] * m00 + R[2, 1] * m10 + R[2, 2] * m20
            c21 = R[2, 0] * m01 + R[2, 1] * m11 + R[2, 2] * m21
            c22 = R[2, 0] * m02 + R[2, 1] * m12 + R[2, 2] * m22
            # EWA: J (2x3) at the clamped direction; the 2D covariance is (J C)(J C)^T + eps2d I
            rz = 1.0 / z
            tx = z * min(lim_x_pos, max(-lim_x_neg, x * rz))
            ty = z * min(lim_y_pos, max(-lim_y_neg, y * rz))
            j00 = fx * rz
            j02 = -fx * tx * rz * rz
            j11 = fy * rz
            j12 = -fy * ty * rz * rz
            u0 = j00 * c00 + j02 * c20
            u1 = j00 * c01 + j02 * c21
            u2 = j00 * c02 + j02 * c22
            v0 = j11 * c10 + j12 * c20
            v1 = j11 * c11 + j12 * c21
            v2 = j11 * c12 + j12 * c22
            a = u0 * u0 + u1 * u1 + u2 * u2 + eps2d
            b = u0 * v0 + u1 * v1 + u2 * v2
            c = v0 * v0 + v1 * v1 + v2 * v2 + eps2d
            det = a * c - b * b
            if det <= 0.0:
                continue
            if antialiased:
                o *= math.sqrt(max((a - eps2d) * (c - eps2d) - b * b, 0.0) / det)
                if o < ALPHA_THRESHOLD:
                    continue
            px = fx * x * rz + cx
            py = fy * y * rz + cy
            extend = min(EXTEND_MAX, math.sqrt(2.0 * (math.log(o) - log_alpha_thr)))
            rx = math.ceil(extend * math.sqrt(a))
            ry = math.ceil(extend * math.sqrt(c))
            if rx <= 0.0 and ry <= 0.0:
                continue
            x0 = max(0, int(math.ceil(px - rx)))
            x1 = min(width - 1, int(math.floor(px + rx)))
            y0 = max(0, int(math.ceil(py - ry)))
            y1 = min(height - 1, int(math.floor(py + ry)))
            if x0 > x1 or y0 > y1:
                continue
            # view-dependent colour along the camera->splat direction (world frame)
            dx = mx - cam_center[0]
            dy = my - cam_center[1]
            dz = mz - cam_center[2]
            dn = math.sqrt(dx * dx + dy * dy + dz * dz)
            if dn > 0.0:
                dx /= dn
                dy /= dn
                dz /= dn
            basis_into(dx, dy, dz, k, bvals)
            for ch in range(3):
                acc = 0.0
                for j in range(k):
                    acc += bvals[j] * sh[i, j, ch]
                rgb[i, ch] = max(acc + 0.5, 0.0)
            valid[i] = True
            mean2d[i, 0] = px
            mean2d[i, 1] = py
            conic[i, 0] = c / det
            conic[i, 1] = -b / det
            conic[i, 2] = a / det
            depth[i] = z
            # depth gradient: Cov(uv)^-1 Cov(uv, z), undilated (eps2d widens the footprint, not the surface)
            cuz = u0 * c20 + u1 * c21 + u2 * c22
            cvz = v0 * c20 + v1 * c21 + v2 * c22
            a0 = a - eps2d + GRAD_EPS
            c0 = c - eps2d + GRAD_EPS
            det0 = a0 * c0 - b * b
            depth_grad[i, 0] = (c0 * cuz - b * cvz) / det0
            depth_grad[i, 1] = (a0 * cvz - b * cuz) / det0
            depth_grad[i, 2] = EXTEND_MAX * math.sqrt(c20 * c20 + c21 * c21 + c22 * c22)
            box[i, 0] = x0
            box[i, 1] = x1
            box[i, 2] = y0
            box[i, 3] = y1
            log_opacity[i] = math.log(o)


@numba.njit(cache=True)
def sort_by_depth(depth, keep):
    """``keep`` [M] splat indices reordered front to back (stable LSD radix sort on float32 depth bits).

    depth [N] must be positive where kept (positive floats order like their bit patterns).
    """
    m = keep.shape[0]
    key_f = np.empty(m, dtype=np.float32)
    for j in range(m):
        key_f[j] = depth[keep[j]]
    keys = key_f.view(np.uint32)
    idx = keep.copy()
    tmp_keys = np.empty_like(keys)
    tmp_idx = np.empty_like(idx)
    for shift in (0, 11, 22):
        counts = np.zeros(2049, dtype=np.int64)
        for j in range(m):
            counts[((keys[j] >> shift) & 2047) + 1] += 1
        for b in range(2048):
            counts[b + 1] += counts[b]
        for j in range(m):
            b = (keys[j] >> shift) & 2047
            tmp_keys[counts[b]] = keys[j]
            tmp_idx[counts[b]] = idx[j]
            counts[b] += 1
        keys, tmp_keys = tmp_keys, keys
        idx, tmp_idx = tmp_idx, idx
    return idx


@numba.njit(cache=True)
def bin_to_tiles(order, box, tiles_x, n_tiles):
    """Tile lists. order [M] splat indices front to back; box [N,4] pixel boxes.

    Returns (offsets [n_tiles+1], ids [pairs]): tile t holds ids[offsets[t]:offsets[t+1]], front to back.
    """
    m = order.shape[0]
    tiles = np.empty((m, 4), dtype=np.int32)  # tile box per sorted splat: one gather, then sequential passes
    counts = np.zeros(n_tiles + 1, dtype=np.int64)
    for j in range(m):
        g = order[j]
        tx0, tx1, ty0, ty1 = box[g, 0] // TILE, box[g, 1] // TILE, box[g, 2] // TILE, box[g, 3] // TILE
        tiles[j, 0], tiles[j, 1], tiles[j, 2], tiles[j, 3] = tx0, tx1, ty0, ty1
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                counts[ty * tiles_x + tx + 1] += 1
    offsets = np.cumsum(counts)
    cursor = offsets[:-1].copy()
    ids = np.empty(offsets[-1], dtype=np.int32)
    for j in range(m):
        for ty in range(tiles[j, 2], tiles[j, 3] + 1):
            for tx in range(tiles[j, 0], tiles[j, 1] + 1):
                tile = ty * tiles_x + tx
                ids[cursor[tile]] = order[j]
                cursor[tile] += 1
    return offsets, ids


@numba.njit(parallel=True, cache=True)
def rasterize(offsets, ids, mean2d, conic, depth, depth_grad, box, rgb, log_opacity, label_idx, n_labels,
              requested, width, height, background):
    """Blend splats front to back per pixel (in centre-depth order); each splat contributes its depth on
    the pixel's ray (``project``'s depth_grad).

    label_idx [M] dense label index per splat (0..n_labels-1); requested [R] dense indices (-1: absent).
    Returns (rgb [H,W,3] f32 incl. background, depth_sum [H,W] f64 (sum of w z_ray), transmittance [H,W] f64,
    label [H,W] int32 dense index with the largest weight (-1 if none), weights [R,H,W] f32).
    """
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = offsets.shape[0] - 1
    out_rgb = np.empty((height, width, 3), dtype=np.float32)
    out_depth = np.empty((height, width), dtype=np.float64)
    out_t = np.empty((height, width), dtype=np.float64)
    out_label = np.empty((height, width), dtype=np.int32)
    out_w = np.zeros((requested.shape[0], height, width), dtype=np.float32)
    log_thr_base = -math.log(ALPHA_THRESHOLD)
    for tile in numba.prange(n_tiles):
        px0 = (tile % tiles_x) * TILE
        py0 = (tile // tiles_x) * TILE
        px1 = min(px0 + TILE, width) - 1
        py1 = min(py0 + TILE, height) - 1
        n_pix = (px1 - px0 + 1) * (py1 - py0 + 1)
        trans = np.ones((TILE, TILE), dtype=np.float64)
        done = np.zeros((TILE, TILE), dtype=np.bool_)
        col = np.zeros((TILE, TILE, 3), dtype=np.float64)
        dsum = np.zeros((TILE, TILE), dtype=np.float64)
        lw = np.zeros((TILE, TILE, n_labels), dtype=np.float64)
        n_done = 0
        for k in range(offsets[tile], offsets[tile + 1]):
            g = ids[k]
            gx0 = max(box[g, 0], px0)
            gx1 = min(box[g, 1], px1)
            gy0 = max(box[g, 2], py0)
            gy1 = min(box[g, 3], py1)
            ca = conic[g, 0]
            cb = conic[g, 1]
            cc = conic[g, 2]
            mx = mean2d[g, 0]
            my = mean2d[g, 1]
            log_o = log_opacity[g]
            lab = label_idx[g]
            r = rgb[g, 0]
            gr = rgb[g, 1]
            bl = rgb[g, 2]
            z = depth[g]
            zu = depth_grad[g, 0]
            zv = depth_grad[g, 1]
            z_bound = depth_grad[g, 2]
            # alpha >= 1/255  <=>  q(dx, dy) = 0.5 A dx^2 + B dx dy + 0.5 C dy^2 <= ln(255 o)
            lim = log_o + log_thr_base
            for y in range(gy0, gy1 + 1):
                dy = my - y
                disc = (cb * dy) ** 2 - ca * (cc * dy * dy - 2.0 * lim)
                if disc < 0.0:
                    continue
                sq = math.sqrt(disc)
                # dx = mx - x within [(-B dy - sq)/A, (-B dy + sq)/A] (+ a rounding margin; exact test below)
                xa = max(gx0, int(math.ceil(mx - (-cb * dy + sq) / ca - 1e-6)))
                xb = min(gx1, int(math.floor(mx - (-cb * dy - sq) / ca + 1e-6)))
                ly = y - py0
                for x in range(xa, xb + 1):
                    lx = x - px0
                    if done[ly, lx]:
                        continue
                    dx = mx - x
                    power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                    if power > 0.0:
                        continue
                    alpha = min(ALPHA_MAX, math.exp(power + log_o))
                    if alpha < ALPHA_THRESHOLD:
                        continue
                    t_cur = trans[ly, lx]
                    t_next = t_cur * (1.0 - alpha)
                    if t_next <= T_MIN:
                        done[ly, lx] = True
                        n_done += 1
                        continue
                    w = alpha * t_cur
                    col[ly, lx, 0] += r * w
                    col[ly, lx, 1] += gr * w
                    col[ly, lx, 2] += bl * w
                    dsum[ly, lx] += (z + min(z_bound, max(-z_bound, -zu * dx - zv * dy))) * w
                    lw[ly, lx, lab] += w
                    trans[ly, lx] = t_next
            if n_done == n_pix:
                break
        for y in range(py0, py1 + 1):
            for x in range(px0, px1 + 1):
                ly = y - py0
                lx = x - px0
                t_fin = trans[ly, lx]
                for ch in range(3):
                    out_rgb[y, x, ch] = col[ly, lx, ch] + t_fin * background[ch]
                out_depth[y, x] = dsum[ly, lx]
                out_t[y, x] = t_fin
                best = -1
                best_w = 0.0
                for j in range(n_labels):
                    if lw[ly, lx, j] > best_w:
                        best_w = lw[ly, lx, j]
                        best = j
                out_label[y, x] = best
                for r_i in range(requested.shape[0]):
                    if requested[r_i] >= 0:
                        out_w[r_i, y, x] = lw[ly, lx, requested[r_i]]
    return out_rgb, out_depth, out_t, out_label, out_w
