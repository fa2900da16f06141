"""The GPU check: on a machine with a CUDA GPU and the cuda extra, every ``gpu``-marked test and the GPU figures
in one table (``make gpu-check``).

Usage: python benchmarks/gpu_check.py [--frames 10] [--runs 10] [--no-tests]

Prints the card and the torch / CUDA / gsplat versions, runs ``pytest -m gpu`` (its summary line), then one
table: CUDA depth against the CPU renderer's (median, 320x240 and 640x480), ``render()`` frames/s at 0.3 M and
1 M splats (640x480, with labels; also without CUDA graphs) beside gsplat's ``rasterization()`` alone on the
same splats, DOPE training images/s (``benchmarks/dope.py``'s synthetic batches, AMP) and inference ms per
640x480 image (torch, as ``DopeModel`` runs it: half precision, channels-last), each with the issue's target
where there is one. Exit code 0 when the tests passed, 1 when one failed, 2 without a usable CUDA GPU.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dope as dope_bench  # noqa: E402  (benchmarks/dope.py)
import render as render_bench  # noqa: E402  (benchmarks/render.py)

from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at  # noqa: E402
from pegasus_gen.render import cuda as rasterizer_cuda  # noqa: E402
from pegasus_gen.render.renderer import cuda_status, render  # noqa: E402
from pegasus_gen.splats import procedural as synthetic  # noqa: E402


def depth_difference_mm(width: int, height: int) -> float:
    """Median |CPU - CUDA| depth (mm) on the tabletop scene (150k splats) where both have depth."""
    env, objects, poses = synthetic.tabletop_scene(150_000, np.random.default_rng(0), sh_degree=3)
    scene = [env] + [o.transformed(T) for o, T in zip(objects, poses)]
    K, T = intrinsics_from_fov(width, height, 55), look_at([0.7, -0.5, 0.55], [0, 0, 0.05])
    cpu, gpu = (render(scene, K, T, width, height, device=d) for d in ("cpu", "cuda"))
    both = (cpu.depth > 0) & (gpu.depth > 0)
    return 1000 * float(np.median(np.abs(cpu.depth[both] - gpu.depth[both])))


def gsplat_alone_ms(n_splats: int, frames: int, width: int = 640, height: int = 480) -> float:
    """Median ms of gsplat's ``rasterization()`` alone (SH degree 3, RGB+D) on ``benchmarks/render.py``'s scene."""
    from gsplat import rasterization

    env, objects, poses = synthetic.tabletop_scene(n_splats, np.random.default_rng(0), sh_degree=3)
    parts = [env] + [o.transformed(T) for o, T in zip(objects, poses)]

    def cat(name):
        return torch.from_numpy(np.concatenate([getattr(p, name) for p in parts])).float().cuda()

    means, quats, sh = cat("means"), cat("quats_wxyz"), cat("sh")
    scales, opacities = cat("log_scales").exp(), torch.sigmoid(cat("opacity_logits"))
    K = torch.tensor(intrinsics_from_fov(width, height, 60.0), dtype=torch.float32, device="cuda")[None]
    times = []
    for T in render_bench.orbit_cameras(frames + 1):
        viewmat = torch.tensor(T, dtype=torch.float32, device="cuda")[None]
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        rasterization(means, quats, scales, opacities, sh, viewmat, K, width, height, sh_degree=3,
                      render_mode="RGB+D")
        torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return 1000 * float(np.median(times[1:]))


def run_tests() -> tuple[bool, str]:
    """(passed, pytest's summary line) of every ``gpu``-marked test."""
    root = Path(__file__).resolve().parent.parent
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "gpu", "-p", "no:cacheprovider", "tests"],
                            cwd=root, capture_output=True, text=True)
    lines = [line for line in result.stdout.splitlines() if line.strip()]
    return result.returncode == 0, (lines[-1] if lines else result.stderr.strip()[-300:])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10, help="frames per render figure")
    parser.add_argument("--runs", type=int, default=10, help="images per inference figure")
    parser.add_argument("--no-tests", action="store_true", help="the figures only")
    args = parser.parse_args()
    usable, reason = cuda_status()
    if not usable:
        print(f"gpu-check: no usable CUDA GPU here: {reason}")
        return 2
    import gsplat

    print(f"card: {torch.cuda.get_device_name()}; torch {torch.__version__}, CUDA {torch.version.cuda}, "
          f"gsplat {gsplat.__version__}")
    passed = True
    if not args.no_tests:
        passed, summary = run_tests()
        print(f"gpu tests: {summary}")
    rows = []
    for w, h in ((320, 240), (640, 480)):
        rows.append((f"CUDA depth vs CPU, median, {w}x{h}", f"{depth_difference_mm(w, h):.3f} mm", "<= 0.5 mm"))
    for n, target in ((300_000, 300), (1_000_000, 150)):
        r = render_bench.bench(n, "cuda", args.frames)
        rasterizer_cuda.GRAPHS = False
        direct = render_bench.bench(n, "cuda", args.frames)
        rasterizer_cuda.GRAPHS = True
        alone = gsplat_alone_ms(n, args.frames)
        rows.append((f"render() 640x480 + labels, {n / 1e6:g} M splats", f"{r['fps']:.0f} frames/s",
                     f">= {target} frames/s"))
        rows.append(("  without CUDA graphs", f"{direct['fps']:.0f} frames/s", ""))
        rows.append((f"  gsplat rasterization() alone, {n / 1e6:g} M", f"{alone:.2f} ms ({r['ms'] / alone:.2f}x)",
                     "render() <= 1.5x"))
    for variant in ("full", "light"):
        rows.append((f"DOPE {variant} training, {dope_bench.CROPS[variant]} px, batch 8, AMP",
                     f"{dope_bench.train_rate(variant, 'cuda', 5):.0f} images/s", ""))
    for variant, target in (("full", "<= 15 ms"), ("light", "")):
        rows.append((f"DOPE {variant} inference 640x480 (torch, fp16)",
                     f"{dope_bench.torch_latency_ms(variant, 'cuda', args.runs):.1f} ms", target))
    width = max(len(r[0]) for r in rows)
    print(f"{'figure':<{width}}  {'value':<22} target")
    for name, value, target in rows:
        print(f"{name:<{width}}  {value:<22} {target}")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
