"""Scan pipeline timings and accuracy on the synthetic capture (cup on an ArUco board, known truth).

Usage: python benchmarks/scan.py [--views 36] [--size 640 480] [--preset cpu-small] [--train-size 160]
       [--device auto]

Prints the time of each stage (marker detection, SfM, training, total), SfM quality, the metric scale's
error against the truth and the held-out PSNR of the trained splats.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.scan.capture import write_capture
from pegasus_gen.scan.frame import fit_similarity
from pegasus_gen.scan.pipeline import ScanOptions, run_scan


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--views", type=int, default=36)
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480))
    parser.add_argument("--preset", default="cpu-small")
    parser.add_argument("--train-size", type=int, default=160)
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_capture(tmp / "cap", views=args.views, width=args.size[0], height=args.size[1], distance=0.45)
        truth = json.loads((tmp / "cap" / "truth.json").read_text())
        K = np.array(truth["K"])
        options = ScanOptions(kind="object", name="bench_cup", obj_id=30, aruco_size=truth["marker_size"],
                              intrinsics=(K[0, 0], K[1, 1], K[0, 2], K[1, 2]), masks=str(tmp / "cap" / "masks"),
                              preset=args.preset, train_size=args.train_size, device=args.device)
        report = run_scan(tmp / "cap" / "images", tmp / "work", options, AssetLibrary(tmp / "lib"))
    cams = report.cameras_T_cam_frame
    names = [n for n in truth["images"] if n in cams]

    def centre(T):
        T = np.asarray(T)
        return -T[:3, :3].T @ T[:3, 3]

    S = fit_similarity(np.array([centre(cams[n]) for n in names]),
                       np.array([centre(truth["images"][n]["T_cam_world"]) for n in names]))
    scale_error = np.cbrt(np.linalg.det(S[:3, :3])) - 1
    t, sfm, tr = report.timings_s, report.sfm, report.training
    print(f"capture: {args.views} views at {args.size[0]}x{args.size[1]}")
    print(f"markers {t.markers:.1f} s | SfM {t.sfm:.1f} s ({1000 * t.sfm / args.views:.0f} ms/photo) | "
          f"training {t.training:.1f} s | total {t.total:.1f} s")
    print(f"registered {sfm['registered']}/{sfm['images']}, {sfm['points']} points, reprojection error "
          f"{sfm['mean_reprojection_error_px']:.2f} px; metric scale error {100 * scale_error:+.2f}% "
          f"(marker edge spread {100 * report.scale['relative_std']:.2f}%)")
    print(f"splat training ({tr['device']}, {tr['backend']}, {tr['iterations']} iterations at {args.train_size} px): "
          f"{tr['iterations'] / tr['seconds']:.1f} it/s, held-out PSNR {tr['psnr_test']:.2f} dB, "
          f"{tr['n_splats_final']:,} splats")


if __name__ == "__main__":
    main()
