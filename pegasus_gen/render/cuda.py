"""gsplat CUDA backend of :func:`pegasus_gen.render.renderer.render` (needs torch with CUDA and
``pip install '.[cuda]'``).

Each part of a scene (a SplatCloud) is uploaded once and kept on the GPU while it lives, and a scene's parts
are concatenated there once while the same parts are rendered again (the frames of a static scene), with the
instance labels as one-hot feature channels. Per frame: colour from gsplat's SH evaluation, blended with the labels;
depth by the CPU renderer's rule, each splat's depth on a pixel's ray being a plane A + B u + C v over the image
(:func:`pegasus_gen.render.differentiable.depth_planes`), rendered as three feature channels and evaluated per
pixel (the CPU's clamp at 3.33 standard deviations of z aside: tests/test_depth_planes.py measures what it
changes). gsplat samples pixel (u, v) at (u + 0.5, v + 0.5), so the principal point is shifted by +0.5 to keep
the OpenCV convention of the CPU backend. The images are finished on the GPU (background, depth, label ids) and
come back to the host in one copy into pinned memory. The work before gsplat's rasteriser and after it is tens of
small kernels; from a scene's second frame with the same intrinsics and outputs it is replayed from CUDA graphs.
"""

from __future__ import annotations

import weakref

import numpy as np
import torch

from pegasus_gen.render.differentiable import depth_planes, world_covariance

_PARTS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()  # SplatCloud -> its device tensors
_SCENE: dict = {}  # the last scene rendered: "parts" (weak references) and its concatenated device tensors
# replay a scene's per-frame work before and after gsplat's rasteriser from CUDA graphs (captured on the second
# frame with the same camera intrinsics and outputs); False runs it directly every frame (benchmarks compare)
GRAPHS = True


def _part_on_gpu(cloud, device) -> dict:
    """Device tensors of one cloud (uploaded on first use, kept while the cloud lives)."""
    cached = _PARTS.get(cloud)
    if cached is None:
        cached = _PARTS[cloud] = {
            "means": torch.from_numpy(cloud.means).to(device, torch.float32),
            "quats": torch.from_numpy(cloud.quats_wxyz).to(device, torch.float32),
            "log_scales": torch.from_numpy(cloud.log_scales).to(device, torch.float32),
            "opacity_logits": torch.from_numpy(cloud.opacity_logits).to(device, torch.float32),
            "sh": torch.from_numpy(cloud.sh).to(device, torch.float32)}
    return cached


def _scene_on_gpu(parts, label_index, present, device) -> dict:
    """Device tensors of the splats of ``parts`` concatenated (each part uploaded once while it lives; the
    concatenation made again only when the parts differ from the last call's): means [N, 3], quats [N, 4],
    scales [N, 3], opacities [N], sh [N, K, 3] (parts of lower SH degree padded with zeros), sh_degree,
    means64 [N, 3] and cov64 [N, 3, 3] (float64, :func:`world_covariance`: the depth planes' inputs), and
    features [N, 3 + n_labels + 3] float32, gsplat's feature channels (colour and depth plane, written per
    frame; the one-hot labels of ``label_index`` written here), present [L] int32 (the labels of the dense
    indices), camera [28] float64 (the frame's T_cam_world, gsplat's K and background, which the graphs read) and
    graphs (the scene's CUDA graphs by key, :func:`_graphed`)."""
    refs = _SCENE.get("parts", ())
    if len(refs) == len(parts) and all(r() is p for r, p in zip(refs, parts)) and \
            np.array_equal(_SCENE["present_host"], present):
        return _SCENE
    n_labels = max(len(present), 1)
    on_gpu = [_part_on_gpu(p, device) for p in parts]
    k = max(p.sh.shape[1] for p in parts)

    def cat(key):
        return torch.cat([g[key] for g in on_gpu])

    means, quats, log_scales = cat("means"), cat("quats"), cat("log_scales")
    labels = torch.from_numpy(np.concatenate(label_index)).to(device)
    features = torch.zeros((len(means), 3 + n_labels + 3), dtype=torch.float32, device=device)
    features[torch.arange(len(means), device=device), 3 + labels.long()] = 1.0
    _SCENE.clear()
    _SCENE.update({
        "parts": tuple(weakref.ref(p) for p in parts), "present_host": np.array(present),
        "present": torch.from_numpy(np.asarray(present, np.int32)).to(device),
        "means": means, "quats": quats, "scales": log_scales.exp(),
        "opacities": torch.sigmoid(cat("opacity_logits")),
        "sh": torch.cat([torch.nn.functional.pad(g["sh"], (0, 0, 0, k - g["sh"].shape[1])) for g in on_gpu]),
        "sh_degree": int(round(k ** 0.5)) - 1,
        # in float64: the planes of needle-like splats lose all their digits to float32's cancellation
        "means64": means.double(), "cov64": world_covariance(quats.double(), log_scales.double()),
        "features": features,
        "camera": torch.zeros(28, dtype=torch.float64, device=device),  # T_cam_world, gsplat's K, background
        "graphs": {},
    })
    return _SCENE


def render_gsplat(parts, label_index, present, requested_index, K, T_cam_world, width, height, background,
                  near, far, eps2d, alpha_min, antialiased=False):
    """Render on CUDA with gsplat; the same outputs as the CPU backend, finished on the GPU and copied to the
    host once (one pinned buffer, of which the returned arrays are views).

    parts: SplatClouds; label_index: per part [N_i] int32 dense label index into ``present`` [L] (the labels
    present, sorted); requested_index [R] dense indices (-1: label absent); K [3, 3] px; T_cam_world [4, 4];
    background [3] in [0, 1]; alpha_min: the coverage below which a pixel has no depth; antialiased: gsplat's
    antialiased mode (the CPU backend's ``antialiased``). Returns rgb [H, W, 3]
    float32 in [0, 1], depth [H, W] float32 (m, 0 where none), alpha [H, W] float32, label [H, W] int32 (-1 where
    none), weights [R, H, W] float32.
    """
    from gsplat import rasterization

    parts_kept = [(p, idx) for p, idx in zip(parts, label_index) if len(p)]
    if not parts_kept:
        blank = np.zeros((height, width), np.float32)
        return (np.broadcast_to(np.asarray(background, np.float32), (height, width, 3)).copy(), blank, blank.copy(),
                np.full((height, width), -1, np.int32), np.zeros((len(requested_index), height, width), np.float32))
    device = torch.device("cuda")
    g = _scene_on_gpu([p for p, _ in parts_kept], [idx for _, idx in parts_kept], present, device)
    # the camera and background in one transfer from pinned memory (a pageable copy waits for the GPU) into the
    # scene's camera buffer, which the captured graphs read
    K64 = np.asarray(K, np.float64)
    K_gsplat = K64 + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]
    packed = torch.empty(28, dtype=torch.float64, pin_memory=True)
    packed.numpy()[:] = np.concatenate([np.ravel(T_cam_world), K_gsplat.ravel(), background])
    g["camera"].copy_(packed, non_blocking=True)
    requested = tuple(int(i) for i in requested_index)
    with torch.no_grad():
        viewmats, Ks = _graphed(g["graphs"], ("features", K64.tobytes(), width, height),
                                lambda: _features(g, K64, width, height))
        colors, alphas, _ = rasterization(
            g["means"], g["quats"], g["scales"], g["opacities"], g["features"], viewmats=viewmats, Ks=Ks,
            width=width, height=height, near_plane=near, far_plane=far, eps2d=eps2d, sh_degree=None, packed=False,
            render_mode="RGB", rasterize_mode="antialiased" if antialiased else "classic")
        flat = _graphed(g["graphs"], ("finish", requested, alpha_min, width, height),
                        lambda c, a: _finish(g, c, a, requested, alpha_min), colors, alphas)
        host = torch.empty(flat.shape, dtype=torch.float32, pin_memory=True)
        host.copy_(flat)
    images, n = host.numpy(), height * width
    return (images[:3 * n].reshape(height, width, 3), images[3 * n:4 * n].reshape(height, width),
            images[4 * n:5 * n].reshape(height, width), images[5 * n:6 * n].view(np.int32).reshape(height, width),
            images[6 * n:].reshape(len(requested_index), height, width))


def _features(g: dict, K: np.ndarray, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Write the camera's colour (gsplat's SH evaluation) and depth planes into the scene's feature channels
    (``g["features"]``, for the camera in ``g["camera"]``); returns gsplat's viewmats [1, 4, 4] and Ks [1, 3, 3]
    (float32, on the GPU). Device work only (no host synchronisation): a CUDA graph can hold it."""
    from gsplat import spherical_harmonics

    camera, features = g["camera"], g["features"]
    T64 = camera[:16].reshape(4, 4)
    campos = (-T64[:3, :3].T @ T64[:3, 3]).float()
    features[:, :3] = torch.clamp_min(spherical_harmonics(g["sh_degree"], g["means"] - campos, g["sh"]) + 0.5, 0.0)
    features[:, -3:] = depth_planes(g["means64"], g["cov64"], torch.from_numpy(K), T64, width, height)
    return T64.float()[None], camera[16:25].reshape(1, 3, 3).float()


def _finish(g: dict, colors: torch.Tensor, alphas: torch.Tensor, requested: tuple, alpha_min: float) -> torch.Tensor:
    """The images from gsplat's output (colors [1, H, W, 3 + L + 3], alphas [1, H, W, 1]): rgb with the
    background, depth by the planes' rule, label ids and the requested label weights, flattened into one float32
    tensor (rgb [H, W, 3], depth, alpha, label (int32 bits), weights [R, H, W]). Device work only."""
    out, alpha = colors[0], alphas[0, ..., 0]
    height, width = alpha.shape
    n_labels = out.shape[-1] - 6
    rgb = (out[..., :3] + (1.0 - alpha)[..., None] * g["camera"][25:].float()).clamp(0.0, 1.0)
    weights = out[..., 3:3 + n_labels]
    best_w, best = weights.max(dim=-1)
    label = torch.where(best_w > 0, g["present"][best], -1).int()
    A, B, C = out[..., 3 + n_labels:].unbind(-1)
    u = torch.arange(width, device=alpha.device, dtype=torch.float32)
    v = torch.arange(height, device=alpha.device, dtype=torch.float32)[:, None]
    depth = torch.where(alpha >= alpha_min, (A + B * u + C * v) / alpha.clamp_min(1e-12), 0.0)
    req = [weights[..., i] if i >= 0 else torch.zeros_like(alpha) for i in requested]
    return torch.cat([rgb.reshape(-1), depth.reshape(-1), alpha.reshape(-1), label.view(torch.float32).reshape(-1),
                      *(w.reshape(-1) for w in req)])


def _graphed(graphs: dict, key, fn, *inputs):
    """``fn(*inputs)``: device work without host synchronisation, on device tensors ``inputs``. Run directly the
    first time ``key`` is seen; on its second use captured into a CUDA graph (``inputs`` copied into tensors of its
    own), replayed from then on: one launch instead of ``fn``'s tens of kernels, which otherwise keep the GPU waiting
    on Python. The returned tensors of a replayed graph are its own, overwritten by its next replay. With GRAPHS
    False, always run directly."""
    entry = graphs.get(key)
    if not GRAPHS or entry is None:
        graphs[key] = "seen"
        return fn(*inputs)
    if entry == "seen":
        static = [t.clone() for t in inputs]
        side = torch.cuda.Stream()  # warm-up on a side stream, as capture asks
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            fn(*static)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, capture_error_mode="thread_local"):
            out = fn(*static)
        entry = graphs[key] = (graph, static, out)
    graph, static, out = entry
    for s, t in zip(static, inputs):
        s.copy_(t)
    graph.replay()
    return out


def smoke_test() -> None:
    """Render one Gaussian on the GPU (compiles gsplat's kernels on first use); raises if that fails."""
    from pegasus_gen.splats.cloud import SplatCloud

    cloud = SplatCloud(np.array([[0.0, 0.0, 2.0]]), np.array([[1.0, 0, 0, 0]]), np.log(np.full((1, 3), 0.1)),
                       np.array([2.0]), np.zeros((1, 1, 3)), np.zeros(1, np.int32))
    K = np.array([[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]])
    _, _, alpha, _, _ = render_gsplat([cloud], [np.zeros(1, np.int32)], np.zeros(1, np.int32), [], K, np.eye(4),
                                      16, 16, np.zeros(3), 0.01, 1e10, 0.3, 0.5)
    if not (np.isfinite(alpha).all() and alpha.max() > 0.5):
        raise RuntimeError("gsplat rendered a wrong test image")
