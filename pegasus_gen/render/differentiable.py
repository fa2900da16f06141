"""Differentiable Gaussian-splat rasterization for training: a plain-torch backend and a gsplat backend.

``rasterize(..., backend="torch" | "gsplat")`` renders one camera and keeps the autograd graph back to
the splat parameters (means, quaternions, log-scales, opacity logits, SH coefficients).

The torch backend is the correct-but-slow path (CPU or CUDA). It follows the forward math of
:mod:`pegasus_gen.render.cpu` (gsplat 1.5 conventions): world -> camera, near/far cull, covariance
R S S^T R^T from the normalised quaternion and exp(log-scales), EWA projection with the Jacobian taken at
the direction clamped to the frustum widened by 30%, ``eps2d`` added to the 2D covariance diagonal, SH
colour along the camera-centre -> splat direction (world frame) then ``max(. + 0.5, 0)``,
``alpha = min(0.999, o exp(power))`` with alpha < 1/255 skipped, and front-to-back compositing of all
splats sorted by camera depth (one global sort, as the tile sort yields).

Early termination: a pixel stops at the splat that would bring its transmittance to <= 1e-4 (that splat
and all behind it are not added), exactly as the numba renderer does; here it is evaluated densely by a
mask on the cumulative transmittance (no gradient flows through the mask itself).

Evaluation is dense over (pixels of a TILE x TILE tile) x (splats whose opacity-aware pixel box touches
the tile), SPLAT_CHUNK depth-sorted splats at a time with the transmittance carried from chunk to chunk;
a tile stops once all its pixels have terminated. With gradients enabled each chunk is wrapped in
activation checkpointing (recomputed in the backward pass), so memory stays bounded by one
[TILE^2, SPLAT_CHUNK] block of intermediates plus per-splat tensors (a 96x72 render of 20k splats with
backward adds < 100 MB of live tensors on CPU).

Pixel convention: OpenCV, pixel (u, v) has its centre at image coordinates (u, v).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint

# the forward math's constants are the numba renderer's (alpha threshold and clamp, early termination,
# pixel-box extent, frustum clamp, near plane, low-pass)
from pegasus_gen.render.cpu import (
    ALPHA_MAX,
    ALPHA_THRESHOLD,
    EPS2D,
    EXTEND_MAX,
    GRAD_EPS,
    NEAR_PLANE,
    T_MIN,
    frustum_limits,
)
from pegasus_gen.splats import sh as shlib

TILE = 8  # pixels per tile side (8 beat 16 on CPU: less dense work per tile)
SPLAT_CHUNK = 1024  # splats blended per dense [pixels x splats] block


@dataclass
class RasterOutput:
    """One rendered view.

    rgb [H, W, 3] colour with the background composited (rgb + T_final * background), not clamped;
    alpha [H, W] accumulated opacity (1 - T_final);
    visible [N] bool: splats that were projected into the image (a culled splat gets no gradient);
    radii [N, 2] float pixel half-extent of each splat's box (0 where culled);
    backend "torch" or "gsplat".
    The 2D means are held in ``means2d_source`` (the tensor the backend blends from, [N, 2] or gsplat's
    [1, N, 2], with its gradient retained when the inputs require grad, in the backend's pixel convention:
    ``means2d_offset`` is 0.5 for gsplat); use :attr:`means2d` / :meth:`means2d_grad` for [N, 2] views.
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    visible: torch.Tensor
    radii: torch.Tensor
    means2d_source: torch.Tensor
    backend: str
    means2d_offset: float = 0.0

    @property
    def means2d(self) -> torch.Tensor:
        """[N, 2] projected splat centres in OpenCV pixels (undefined where not visible), detached."""
        return self.means2d_source.detach().reshape(-1, 2) - self.means2d_offset

    def means2d_grad(self) -> torch.Tensor | None:
        """[N, 2] d(loss)/d(2D mean) in loss units per pixel after ``loss.backward()`` (None before)."""
        grad = self.means2d_source.grad
        return None if grad is None else grad.reshape(-1, 2)


# ------------------------------------------------------------------------------------- helpers
def _as_tensor(a, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.float64) if not isinstance(a, torch.Tensor) else a,
                           dtype=like.dtype, device=like.device)


def quat_to_rotmat(quats_wxyz: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N, 3, 3] of wxyz quaternions [N, 4] (normalised here)."""
    q = quats_wxyz / quats_wxyz.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """SH basis [N, (degree+1)^2] at unit directions ``dirs`` [N, 3] (3DGS sign convention)."""
    x, y, z = dirs.unbind(-1)
    cols = [torch.full_like(x, shlib.C0)]
    if degree >= 1:
        cols += [-shlib.C1 * y, shlib.C1 * z, -shlib.C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        c2 = shlib.C2
        cols += [c2[0] * x * y, c2[1] * y * z, c2[2] * (2 * zz - xx - yy), c2[3] * x * z, c2[4] * (xx - yy)]
    if degree >= 3:
        c3 = shlib.C3
        cols += [c3[0] * y * (3 * xx - yy), c3[1] * x * y * z, c3[2] * y * (4 * zz - xx - yy),
                 c3[3] * z * (2 * zz - 3 * xx - 3 * yy), c3[4] * x * (4 * zz - xx - yy),
                 c3[5] * z * (xx - yy), c3[6] * x * (xx - 3 * yy)]
    return torch.stack(cols, dim=-1)


def _sh_degree(sh: torch.Tensor, sh_degree: int | None) -> int:
    stored = shlib.degree_from_num_coeffs(sh.shape[1])
    if sh_degree is None:
        return stored
    if not 0 <= sh_degree <= stored:
        raise ValueError(f"sh_degree must be in 0..{stored} for {sh.shape[1]} coefficients, got {sh_degree}")
    return int(sh_degree)


def _check_inputs(means, quats_wxyz, log_scales, opacity_logits, sh):
    n = means.shape[0]
    shapes = {"means": (means, (n, 3)), "quats_wxyz": (quats_wxyz, (n, 4)), "log_scales": (log_scales, (n, 3)),
              "opacity_logits": (opacity_logits, (n,))}
    for name, (t, shape) in shapes.items():
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {tuple(t.shape)}")
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
        raise ValueError(f"sh must have shape ({n}, K, 3), got {tuple(sh.shape)}")


# ------------------------------------------------------------------------------ torch backend
def world_factor(quats_wxyz: torch.Tensor, log_scales: torch.Tensor) -> torch.Tensor:
    """Per splat the factor M [N, 3, 3] of its world-frame covariance M M^T (m): rotation times scales."""
    return quat_to_rotmat(quats_wxyz) * torch.exp(log_scales)[:, None, :]


def _ewa_jacobian(x, y, z, K, width, height):
    """The EWA projection at camera-frame centres x, y, z [N] (m) for intrinsics K [3, 3] (px), its Jacobian taken
    at the direction clamped to the frustum widened by 30 % (gsplat's limits); splats with z <= 0 are taken at
    z = 1. Returns (the Jacobian's non-zero entries j00, j02, j11, j12 [N] (u = row 0, v = row 1; px/m), u, v [N]
    the projected centres (OpenCV px))."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos = frustum_limits(width, height, float(fx), float(fy), float(cx),
                                                                float(cy))
    rz = 1.0 / torch.where(z > 0, z, torch.ones_like(z))
    j02 = -fx * rz * (x * rz).clamp(-lim_x_neg, lim_x_pos)
    j12 = -fy * rz * (y * rz).clamp(-lim_y_neg, lim_y_pos)
    return fx * rz, j02, fy * rz, j12, fx * x * rz + cx, fy * y * rz + cy


def _camera_factors(means, M, K, T_cam_world, width, height):
    """The EWA projection of splats [N] (centres [N, 3], covariance factors M [N, 3, 3] of
    :func:`world_factor`) for one camera (K [3, 3] px, T_cam_world [4, 4]).

    Returns (z [N] camera-frame depth of the centres (m), RM [N, 3, 3] camera-frame covariance factor (covariance
    RM RM^T, m), U [N, 2, 3] image-plane factor (2D covariance U U^T, px^2, without eps2d), means2d [N, 2]
    projected centres (OpenCV px)); rows of splats with z <= 0 are finite but meaningless (:func:`_ewa_jacobian`).
    """
    R = T_cam_world[:3, :3]
    t = T_cam_world[:3, 3]
    x, y, z = (means @ R.T + t).unbind(-1)
    j00, j02, j11, j12, u, v = _ewa_jacobian(x, y, z, K, width, height)
    # one GEMM for R M and the Jacobian's zeros skipped: batched 3x3 products are slow on a GPU (float64 most)
    RM = torch.einsum("ik,nkj->nij", R, M)
    U = torch.stack([j00[:, None] * RM[:, 0] + j02[:, None] * RM[:, 2],
                     j11[:, None] * RM[:, 1] + j12[:, None] * RM[:, 2]], dim=1)
    return z, RM, U, torch.stack([u, v], dim=-1)


def world_covariance(quats_wxyz: torch.Tensor, log_scales: torch.Tensor) -> torch.Tensor:
    """Per splat its world-frame covariance M M^T [N, 3, 3] (m^2), M of :func:`world_factor`."""
    M = world_factor(quats_wxyz, log_scales)
    return M @ M.transpose(1, 2)


def depth_planes(means, cov, K, T_cam_world, width: int, height: int) -> torch.Tensor:
    """Per splat (centres [N, 3], world covariances [N, 3, 3] of :func:`world_covariance`) the plane (A, B, C)
    [N, 3] of its depth over the image: on pixel (u, v) (OpenCV px) the
    splat's depth is A + B u + C v (m), the point of highest density on that pixel's ray in the affine camera
    model of the EWA projection, the depth rule of :func:`pegasus_gen.render.cpu.project` (its ``depth_grad``)
    without its clamp at EXTEND_MAX standard deviations. Blended with the splats' weights, the planes give a
    pixel's depth sum as sum(w A) + u sum(w B) + v sum(w C): how a rasteriser that blends feature channels
    linearly (gsplat) renders the CPU renderer's depth. Rows of splats behind the camera are finite but
    meaningless. Written for a GPU: two GEMMs and elementwise work on contiguous [N] rows (the camera-frame
    covariances as one product with kron(R, R)); run it in float64 (needle-like splats lose all
    their digits to float32's cancellation).
    """
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    x, y, z = R @ means.T + t[:, None]
    S = torch.kron(R, R) @ cov.reshape(-1, 9).T  # [9, N]: the camera-frame covariances R cov R^T, row-major
    s00, s01, s02, s11, s12, s22 = S[0], S[1], S[2], S[4], S[5], S[8]
    j00, j02, j11, j12, u, v = _ewa_jacobian(x, y, z, K, width, height)
    cov_uz = j00 * s02 + j02 * s22  # covariance of (u, v) with z
    cov_vz = j11 * s12 + j12 * s22
    a = j00 * (j00 * s00 + 2 * j02 * s02) + j02 * j02 * s22 + GRAD_EPS  # the 2D covariance, undilated
    b = j00 * (j11 * s01 + j12 * s02) + j02 * cov_vz
    c = j11 * (j11 * s11 + 2 * j12 * s12) + j12 * j12 * s22 + GRAD_EPS
    det = a * c - b * b
    dz_du = (c * cov_uz - b * cov_vz) / det
    dz_dv = (a * cov_vz - b * cov_uz) / det
    return torch.stack([z - dz_du * u - dz_dv * v, dz_du, dz_dv], dim=-1)


def project(means, quats_wxyz, log_scales, opacity_logits, sh, K, T_cam_world, width, height,
            sh_degree=None, near=NEAR_PLANE, far=1e10, eps2d=EPS2D) -> dict:
    """Per-splat projection (differentiable). Inputs as :func:`rasterize_torch`.

    Returns dict of tensors with N rows: ``valid`` [N] bool (not culled), ``means2d`` [N, 2] pixels,
    ``conic`` [N, 3] (A, B, C of the inverse 2D covariance, 1/pixels^2), ``depth`` [N] camera z (m),
    ``opacity`` [N], ``rgb`` [N, 3] SH colour; without gradient: ``radii`` [N, 2] pixel half-extent of the
    opacity-aware box (every pixel with alpha >= 1/255 lies in it), ``box_lo`` / ``box_hi`` [N, 2] its
    first / last pixel (x, y). Quantities of culled splats are finite but meaningless.
    """
    R = T_cam_world[:3, :3]
    t = T_cam_world[:3, 3]
    z, _, U, means2d = _camera_factors(means, world_factor(quats_wxyz, log_scales), K, T_cam_world, width, height)
    valid = (z > near) & (z < far)
    cov = U @ U.transpose(1, 2)
    a = cov[:, 0, 0] + eps2d
    b = cov[:, 0, 1]
    c = cov[:, 1, 1] + eps2d
    det = a * c - b * b
    valid = valid & (det > 0)
    det_s = torch.where(valid, det, torch.ones_like(det))
    conic = torch.stack([c / det_s, -b / det_s, a / det_s], dim=-1)
    opacity = torch.sigmoid(opacity_logits)
    valid = valid & (opacity >= ALPHA_THRESHOLD)
    # colour along camera centre -> splat (world frame)
    cam_center = -R.T @ t
    d = means - cam_center
    d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    deg = _sh_degree(sh, sh_degree)
    rgb = torch.clamp_min((sh_basis(d, deg)[:, :, None] * sh[:, :shlib.num_coeffs(deg)]).sum(1) + 0.5, 0.0)
    with torch.no_grad():  # opacity-aware pixel box, as the numba renderer (culling only)
        extend = torch.sqrt(2.0 * torch.log(opacity.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD))
        extend = extend.clamp_max(EXTEND_MAX)
        radii = torch.stack([torch.ceil(extend * a.clamp_min(0).sqrt()), torch.ceil(extend * c.clamp_min(0).sqrt())],
                            dim=-1)
        lo = torch.ceil(means2d - radii)
        hi = torch.floor(means2d + radii)
        valid &= (hi[:, 0] >= 0) & (lo[:, 0] <= width - 1) & (hi[:, 1] >= 0) & (lo[:, 1] <= height - 1)
        valid &= torch.isfinite(means2d).all(-1)
        radii = torch.where(valid[:, None], radii, torch.zeros_like(radii))
    return {"valid": valid, "means2d": means2d, "conic": conic, "depth": z, "opacity": opacity, "rgb": rgb,
            "radii": radii, "box_lo": lo, "box_hi": hi}


def _composite_chunk(px, py, log_t, done, means2d, conic, opacity, rgb):
    """Blend a chunk of M depth-sorted splats over P pixels, after the splats blended before it.

    px, py [P] pixel coordinates; log_t [P] log transmittance so far; done [P] bool pixels already
    terminated; means2d [M, 2]; conic [M, 3]; opacity [M]; rgb [M, 3].
    Returns (colour added [P, 3], log transmittance after the chunk [P], done after the chunk [P]).
    """
    dx = means2d[None, :, 0] - px[:, None]
    dy = means2d[None, :, 1] - py[:, None]
    power = -0.5 * (conic[None, :, 0] * dx * dx + conic[None, :, 2] * dy * dy) - conic[None, :, 1] * dx * dy
    alpha = torch.clamp_max(opacity[None, :] * torch.exp(power), ALPHA_MAX)
    alpha = torch.where((power <= 0) & (alpha >= ALPHA_THRESHOLD), alpha, torch.zeros_like(alpha))
    log_keep = torch.log1p(-alpha)
    log_t_after = log_t[:, None] + torch.cumsum(log_keep, dim=1)
    with torch.no_grad():  # early termination: a prefix of the chunk stays alive
        alive = (log_t_after > math.log(T_MIN)) & ~done[:, None]
    weight = alpha * torch.exp(log_t_after - log_keep) * alive
    return weight @ rgb, log_t + (log_keep * alive).sum(dim=1), done | ~alive[:, -1]


def rasterize_torch(means, quats_wxyz, log_scales, opacity_logits, sh, K, T_cam_world, width: int, height: int,
                    background=None, sh_degree: int | None = None, near: float = NEAR_PLANE, far: float = 1e10,
                    eps2d: float = EPS2D) -> RasterOutput:
    """Render one camera in plain torch (differentiable; CPU or CUDA; dtype and device of ``means``).

    means [N, 3] world (m); quats_wxyz [N, 4] (any norm); log_scales [N, 3] log std-dev (m);
    opacity_logits [N]; sh [N, K, 3] (gsplat layout); K [3, 3] OpenCV intrinsics (pixels);
    T_cam_world [4, 4] world -> camera; background [3] in [0, 1] (None: black);
    sh_degree: SH bands used (None: all stored). Returns :class:`RasterOutput`.
    """
    _check_inputs(means, quats_wxyz, log_scales, opacity_logits, sh)
    K = _as_tensor(K, means)
    T = _as_tensor(T_cam_world, means)
    bg = torch.zeros(3, dtype=means.dtype, device=means.device) if background is None else _as_tensor(background, means)
    proj = project(means, quats_wxyz, log_scales, opacity_logits, sh, K, T, width, height, sh_degree, near, far, eps2d)
    means2d = proj["means2d"]
    if means2d.requires_grad:
        means2d.retain_grad()
    valid = proj["valid"]
    idx = torch.nonzero(valid).squeeze(1)
    order = idx[torch.sort(proj["depth"].detach()[idx], stable=True).indices]  # front to back
    lo, hi = proj["box_lo"][order], proj["box_hi"][order]
    s_means2d, s_conic = means2d[order], proj["conic"][order]
    s_opacity, s_rgb = proj["opacity"][order], proj["rgb"][order]
    colour = torch.zeros(height, width, 3, dtype=means.dtype, device=means.device)
    alpha = torch.zeros(height, width, dtype=means.dtype, device=means.device)
    for y0 in range(0, height, TILE):
        for x0 in range(0, width, TILE):
            y1, x1 = min(y0 + TILE, height), min(x0 + TILE, width)
            hit = (hi[:, 0] >= x0) & (lo[:, 0] <= x1 - 1) & (hi[:, 1] >= y0) & (lo[:, 1] <= y1 - 1)
            sel = torch.nonzero(hit).squeeze(1)
            if sel.numel() == 0:
                continue
            gy, gx = torch.meshgrid(torch.arange(y0, y1, dtype=means.dtype, device=means.device),
                                    torch.arange(x0, x1, dtype=means.dtype, device=means.device), indexing="ij")
            px, py = gx.reshape(-1), gy.reshape(-1)
            tile_rgb, log_t = _blend_tile(px, py, sel, s_means2d, s_conic, s_opacity, s_rgb)
            colour[y0:y1, x0:x1] = tile_rgb.reshape(y1 - y0, x1 - x0, 3)
            alpha[y0:y1, x0:x1] = (1.0 - torch.exp(log_t)).reshape(y1 - y0, x1 - x0)
    rgb = colour + (1.0 - alpha)[..., None] * bg
    return RasterOutput(rgb=rgb, alpha=alpha, visible=valid, radii=proj["radii"], means2d_source=means2d,
                        backend="torch")


def _blend_tile(px, py, sel, means2d, conic, opacity, rgb):
    """Blend the depth-sorted splats ``sel`` [M] (indices into the sorted arrays) over pixels px, py [P],
    SPLAT_CHUNK at a time (each chunk checkpointed when gradients are needed); stops once every pixel has
    terminated. Returns (colour [P, 3], log transmittance [P])."""
    log_t = torch.zeros_like(px)
    done = torch.zeros(px.shape, dtype=torch.bool, device=px.device)
    colour = torch.zeros(px.shape[0], 3, dtype=px.dtype, device=px.device)
    for start in range(0, sel.numel(), SPLAT_CHUNK):
        part = sel[start:start + SPLAT_CHUNK]
        args = (px, py, log_t, done, means2d[part], conic[part], opacity[part], rgb[part])
        if torch.is_grad_enabled() and any(a.requires_grad for a in args):
            c, log_t, done = checkpoint(_composite_chunk, *args, use_reentrant=False, preserve_rng_state=False)
        else:
            c, log_t, done = _composite_chunk(*args)
        colour = colour + c
        if bool(done.all()):
            break
    return colour, log_t


# ----------------------------------------------------------------------------- gsplat backend
def rasterize_gsplat(means, quats_wxyz, log_scales, opacity_logits, sh, K, T_cam_world, width: int, height: int,
                     background=None, sh_degree: int | None = None, near: float = NEAR_PLANE, far: float = 1e10,
                     eps2d: float = EPS2D) -> RasterOutput:
    """Same inputs and outputs as :func:`rasterize_torch`, rendered by gsplat's CUDA ``rasterization``
    (tensors must be float32 on a CUDA device). gsplat samples pixel (u, v) at (u + 0.5, v + 0.5), so the
    principal point is shifted by +0.5 to keep the OpenCV convention."""
    from gsplat import rasterization  # lazy: CUDA-only dependency

    _check_inputs(means, quats_wxyz, log_scales, opacity_logits, sh)
    if means.device.type != "cuda":
        raise ValueError("the gsplat backend needs CUDA tensors")
    K_shift = _as_tensor(K, means).clone()
    K_shift[0, 2] += 0.5
    K_shift[1, 2] += 0.5
    T = _as_tensor(T_cam_world, means)
    bg = torch.zeros(3, dtype=means.dtype, device=means.device) if background is None else _as_tensor(background, means)
    colors, alphas, info = rasterization(
        means, quats_wxyz, torch.exp(log_scales), torch.sigmoid(opacity_logits), sh,
        viewmats=T[None], Ks=K_shift[None], width=width, height=height, near_plane=near, far_plane=far,
        eps2d=eps2d, sh_degree=_sh_degree(sh, sh_degree), packed=False, backgrounds=bg[None],
        render_mode="RGB", rasterize_mode="classic")
    means2d = info["means2d"]  # [1, N, 2] pixels, +0.5 from OpenCV's; the gradient is the same
    if means2d.requires_grad:
        means2d.retain_grad()
    radii = info["radii"][0]
    radii = radii.to(means.dtype) if radii.ndim == 2 else radii.to(means.dtype)[:, None].expand(-1, 2)
    return RasterOutput(rgb=colors[0], alpha=alphas[0, ..., 0], visible=(radii > 0).all(-1), radii=radii,
                        means2d_source=means2d, backend="gsplat", means2d_offset=0.5)


BACKENDS = {"torch": rasterize_torch, "gsplat": rasterize_gsplat}


def rasterize(means, quats_wxyz, log_scales, opacity_logits, sh, K, T_cam_world, width: int, height: int,
              background=None, sh_degree: int | None = None, backend: str = "torch", near: float = NEAR_PLANE,
              far: float = 1e10, eps2d: float = EPS2D) -> RasterOutput:
    """Differentiable render of one camera with ``backend`` "torch" (any device) or "gsplat" (CUDA).

    Arguments as :func:`rasterize_torch`.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {sorted(BACKENDS)}, got {backend!r}")
    return BACKENDS[backend](means, quats_wxyz, log_scales, opacity_logits, sh, K, T_cam_world, width, height,
                             background=background, sh_degree=sh_degree, near=near, far=far, eps2d=eps2d)


def gsplat_available() -> bool:
    """Whether gsplat imports and torch sees a CUDA device."""
    if not torch.cuda.is_available():
        return False
    try:
        import gsplat  # noqa: F401
    except Exception:  # noqa: BLE001  (a broken install raises anything: then it is not available)
        return False
    return True
