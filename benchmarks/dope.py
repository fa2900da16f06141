"""DOPE speed: training images/s of each variant and of the zoom network (CPU, and CUDA when present) and
inference latency at 640x480: ONNX on the CPU (onnxruntime), torch on the CPU and, with CUDA, torch on the GPU as
``DopeModel`` runs it (channels-last; on the GPU half precision and cuDNN's autotuner).

Usage: python benchmarks/dope.py [--variants full light pretrained] [--devices cpu cuda] [--steps 5] [--runs 10]
Training is timed on random 3x{crop} images with random targets (the data pipeline is not included: it
runs in loader processes beside the GPU); the first step is not timed. Crops: full 400 px batch 8 (DOPE
uses 32 on a GPU), light 320 px batch 8, pretrained (the sim-to-real recipe's network) 128 px batch 8; the zoom
network (``pegasus train-zoom``'s defaults) 96 px crops with the silhouette view, batch 32.
Inference: the exported last stage on a 640x480 image (the input size the network sees when an image is not
rescaled), median of ``--runs`` after one warm-up (two on CUDA, where cuDNN's autotuner runs first).
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time

import numpy as np
import onnxruntime
import torch

from dope_training.export import export_onnx
from dope_training.infer import inference_network, network_outputs
from dope_training.model import DopeNetwork, ModelConfig, dope_loss
from dope_training.recipe import CROP_PX
from dope_training.zoom import ZoomNet, zoom_tensor
from dope_training.zoom_config import ZoomConfig

CROPS = {"full": 400, "light": 320, "pretrained": CROP_PX}


def train_rate(variant: str, device: str, steps: int, batch: int = 8) -> float:
    """Images/s of forward + backward + Adam step (AMP on CUDA) at the variant's crop size, tensors channels-last
    as ``pegasus train`` keeps them."""
    size = CROPS[variant]
    model = DopeNetwork(ModelConfig.of(variant)).to(device, memory_format=torch.channels_last).train()
    optimiser = torch.optim.Adam(model.parameters(), 1e-4)
    scaler = torch.amp.GradScaler("cuda", enabled=device == "cuda")
    image = torch.rand(batch, 3, size, size, device=device).contiguous(memory_format=torch.channels_last)
    beliefs = torch.rand(batch, 9, size // 8, size // 8, device=device)
    affinities = torch.rand(batch, 16, size // 8, size // 8, device=device) * 2 - 1
    times = []
    for _ in range(steps + 1):
        if device == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        with torch.autocast(device, dtype=torch.float16, enabled=device == "cuda"):
            outputs = model(image)
        loss = dope_loss([(b.float(), a.float()) for b, a in outputs], beliefs, affinities)
        optimiser.zero_grad()
        scaler.scale(loss).backward()
        scaler.step(optimiser)
        scaler.update()
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return batch / float(np.median(times[1:]))


def zoom_train_rate(device: str, steps: int) -> float:
    """Crops/s of the zoom network's forward + backward + AdamW step at train-zoom's default crop and batch, its
    input laid out as ``zoom_tensor`` lays it out."""
    cfg = ZoomConfig(data=["-"], object="-", out="-")
    net = ZoomNet(cfg.crop_px, pretrained=False).to(device, memory_format=torch.channels_last).train()
    optimiser = torch.optim.AdamW(net.parameters(), cfg.lr)
    rng = np.random.default_rng(0)
    size = (cfg.batch_size, cfg.crop_px, cfg.crop_px)
    x = zoom_tensor(rng.integers(0, 256, (*size, 3), np.uint8), rng.integers(0, 256, (*size, 1), np.uint8)).to(device)
    target = torch.zeros(cfg.batch_size, net.outputs, device=device)
    times = []
    for _ in range(steps + 1):
        t0 = time.perf_counter()
        loss = torch.nn.functional.smooth_l1_loss(net(x), target)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return cfg.batch_size / float(np.median(times[1:]))


def onnx_latency_ms(variant: str, runs: int) -> float:
    """Median ms of one 640x480 image through the exported network on onnxruntime's CPU provider."""
    model = DopeNetwork(ModelConfig.of(variant))
    with tempfile.TemporaryDirectory() as tmp:
        path = export_onnx(model, os.path.join(tmp, "dope.onnx"))
        session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    image = np.random.default_rng(0).random((1, 3, 480, 640), dtype=np.float32)
    session.run(None, {"image": image})
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        session.run(None, {"image": image})
        times.append(time.perf_counter() - t0)
    return 1000 * float(np.median(times))


def torch_latency_ms(variant: str, device: str, runs: int) -> float:
    """Median ms of one 640x480 image through the network on torch, as ``DopeModel`` runs it (channels-last; on
    CUDA half precision and cuDNN's autotuner), the input copied from and the result to the host."""
    model = inference_network(DopeNetwork(ModelConfig.of(variant)), torch.device(device))
    image = np.random.default_rng(0).random((1, 3, 480, 640), dtype=np.float32)
    times = []
    for _ in range(runs + 2):  # the first two (the autotuner) not timed
        t0 = time.perf_counter()
        network_outputs(model, image)
        times.append(time.perf_counter() - t0)
    return 1000 * float(np.median(times[2:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", nargs="+", default=list(CROPS), choices=list(CROPS))
    parser.add_argument("--devices", nargs="+", default=["cpu", "cuda"], choices=["cpu", "cuda"])
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--runs", type=int, default=10)
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads"
          + (f", {torch.cuda.get_device_name()}" if torch.cuda.is_available() else ""))
    for device in args.devices:
        if device == "cuda" and not torch.cuda.is_available():
            print("cuda: no CUDA device, skipped")
            continue
        for variant in args.variants:
            rate = train_rate(variant, device, args.steps)
            print(f"train {variant:5s} {CROPS[variant]} px, batch 8, {device}: {rate:7.2f} images/s")
        print(f"train zoom 96 px, batch 32, {device}: {zoom_train_rate(device, args.steps):7.2f} images/s")
    for variant in args.variants:
        print(f"onnxruntime CPU {variant:5s} 640x480: {onnx_latency_ms(variant, args.runs):7.1f} ms/image")
        print(f"torch CPU       {variant:5s} 640x480: {torch_latency_ms(variant, 'cpu', args.runs):7.1f} ms/image")
    if "cuda" in args.devices and torch.cuda.is_available():
        for variant in args.variants:
            print(f"torch CUDA      {variant:5s} 640x480: {torch_latency_ms(variant, 'cuda', args.runs):7.1f} ms/image")


if __name__ == "__main__":
    main()
