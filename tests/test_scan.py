"""The scan pipeline on a synthetic capture with known truth (a cup on an ArUco board rendered from a
hemisphere of views): registration, metric scale, plane, object centring, trained splats, asset; and
the clear failures (no markers, too few or unrelated photos) that leave no asset behind."""

import json
import logging

import cv2
import numpy as np
import pytest

from pegasus_gen.assets.library import AssetLibrary, load_asset
from pegasus_gen.cli.main import main
from pegasus_gen.errors import PegasusError
from pegasus_gen.scan.capture import write_capture
from pegasus_gen.scan.frame import camera_in_frame, fit_similarity, similarity_matrix
from pegasus_gen.scan.pipeline import ScanOptions, run_scan, training_image

VIEWS = 60
PSNR_HELD_OUT_DB = 26.0  # stated bar for the CPU "cpu-small" training at 96 px (measured 29.7-30.0 dB)
# (at 64 px: 28.3 dB, but only ~265 splats opaque and small enough for the collision mesh, against ~850 at 96 px, and
# the mesh came out 8-17 % narrow: the size check below failed CI once)


def centre(T) -> np.ndarray:
    T = np.asarray(T)
    return -T[:3, :3].T @ T[:3, 3]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """Two halves of an object scan: the cup upright, then turned over (other camera poses)."""
    root = tmp_path_factory.mktemp("capture")
    for half, flipped in (("upright", False), ("flipped", True)):
        write_capture(root / half, views=VIEWS, width=640, height=480, distance=0.42, seed=int(flipped),
                      flipped=flipped, progress=False)
    return root


@pytest.fixture(scope="module")
def scanned(capture, tmp_path_factory):
    """run_scan on both halves (masks, calibrated camera): (report, library, truth of each half)."""
    truth = {half: json.loads((capture / half / "truth.json").read_text()) for half in ("upright", "flipped")}
    K = np.array(truth["upright"]["K"])
    library = AssetLibrary(tmp_path_factory.mktemp("lib"))
    options = ScanOptions(kind="object", name="scanned_cup", obj_id=20, aruco_size=truth["upright"]["marker_size"],
                          intrinsics=(K[0, 0], K[1, 1], K[0, 2], K[1, 2]), masks=str(capture / "upright" / "masks"),
                          second_images=str(capture / "flipped" / "images"),
                          second_masks=str(capture / "flipped" / "masks"), train_size=96, device="cpu")
    report = run_scan(capture / "upright" / "images", tmp_path_factory.mktemp("work"), options, library)
    return report, library, truth


def test_scan_registers_scales_and_levels_the_capture(scanned):
    report, _, truth = scanned
    assert report.sfm["registered_fraction"] >= 0.9
    # every registered camera in the scan frame vs the truth: one similarity relates them; it must be
    # (nearly) a pure rigid motion keeping z up, the cup at the origin and the board at z = 0
    cameras = report.cameras_T_cam_frame
    names = [n for n in truth["upright"]["images"] if n in cameras]
    est = np.array([centre(cameras[n]) for n in names])
    tru = np.array([centre(truth["upright"]["images"][n]["T_cam_world"]) for n in names])
    S = fit_similarity(est, tru)
    c = np.cbrt(np.linalg.det(S[:3, :3]))
    assert abs(c - 1.0) < 0.02, f"metric scale off by {100 * (c - 1):.2f}%"
    assert np.degrees(np.arccos(np.clip(S[2, 2] / c, -1, 1))) < 2.0, "support plane normal off by > 2 deg"
    assert np.linalg.norm(S[:2, 3]) < 0.005, "the object is not centred over the origin"
    assert abs(S[2, 3]) < 0.005, "the support plane is not at z = 0"
    assert report.scale["relative_std"] < 0.02
    # the turned-over half lands where its cameras were relative to the cup
    second = report.second_half
    assert second["second_half_registered"] >= 0.8 * VIEWS
    T_cup_up = np.array(truth["upright"]["T_world_object"])
    T_cup_flip = np.array(truth["flipped"]["T_world_object"])
    placed = [n for n in truth["flipped"]["images"] if f"second/{n}" in cameras]
    assert len(placed) == second["second_half_registered"]
    est2 = np.array([centre(cameras[f"second/{n}"]) for n in placed])
    tru2 = np.array([centre(np.array(truth["flipped"]["images"][n]["T_cam_world"]) @ T_cup_flip
                            @ np.linalg.inv(T_cup_up)) for n in placed])
    error = np.linalg.norm(est2 @ S[:3, :3].T + S[:3, 3] - tru2, axis=1)
    # (cameras ~0.42 m away; the first half's own cameras sit within ~2 mm of the truth)
    assert np.median(error) < 0.01 and error.max() < 0.02, \
        f"second-half cameras off by {1000 * np.median(error):.1f} mm (median), {1000 * error.max():.1f} mm (max)"
    first = np.linalg.norm(est @ S[:3, :3].T + S[:3, 3] - tru, axis=1)
    assert first.max() < 0.005, f"first-half cameras off by up to {1000 * first.max():.1f} mm"


def test_scanned_splats_reach_the_stated_psnr_and_become_an_asset(scanned):
    report, library, truth = scanned
    assert report.training["psnr_test"] > PSNR_HELD_OUT_DB
    asset = load_asset(report.asset)
    assert asset.manifest.obj_id == 20 and asset.manifest.kind == "object"
    assert library.get("scanned_cup").path == asset.path
    size = np.ptp(asset.mesh.bounds, axis=0)  # the red demo cup: 94 mm across the rim, 105 mm tall
    assert np.allclose(size, [0.094, 0.094, 0.105], rtol=0.15), size


def test_fit_similarity_recovers_a_known_similarity(rng):
    S = similarity_matrix(2.5, np.eye(4))
    S[:3, :3] = S[:3, :3] @ cv2.Rodrigues(np.array([0.3, -1.2, 0.7]))[0]
    S[:3, 3] = [1.0, -2.0, 0.5]
    src = rng.normal(size=(10, 3))
    assert np.allclose(fit_similarity(src, src @ S[:3, :3].T + S[:3, 3]), S, atol=1e-10)


def test_camera_in_frame_keeps_every_pixel(rng):
    T_cam_rec = np.eye(4)
    T_cam_rec[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
    T_cam_rec[:3, 3] = [0.1, -0.2, 3.0]
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
    T[:3, 3] = rng.normal(size=3)
    S = similarity_matrix(0.37, T)
    x = rng.normal(size=(20, 3)) * 0.3
    cam_a = x @ T_cam_rec[:3, :3].T + T_cam_rec[:3, 3]
    Tf = camera_in_frame(T_cam_rec, S)
    xf = x @ S[:3, :3].T + S[:3, 3]
    cam_b = xf @ Tf[:3, :3].T + Tf[:3, 3]
    assert np.allclose(cam_a[:, :2] / cam_a[:, 2:], cam_b[:, :2] / cam_b[:, 2:], atol=1e-12)
    assert np.allclose(Tf[:3, :3] @ Tf[:3, :3].T, np.eye(3), atol=1e-12)


def test_training_image_intrinsics_follow_the_resize(tmp_path):
    image = np.zeros((300, 400, 3), np.uint8)
    cv2.circle(image, (283, 117), 6, (255, 255, 255), -1)  # a dot at a known pixel
    cv2.imwrite(str(tmp_path / "a.png"), image)
    K = np.array([[500.0, 0, 199.5], [0, 500.0, 149.5], [0, 0, 1]])
    small, K_small = training_image(tmp_path / "a.png", K, np.zeros(4), 100)
    assert small.shape == (75, 100, 3)
    ys, xs = np.nonzero(small[..., 0] > 0.5)
    ray = np.linalg.inv(K) @ [283, 117, 1]  # the dot's ray, reprojected with the new intrinsics
    u, v = (K_small @ ray)[:2]
    assert abs(xs.mean() - u) < 0.3 and abs(ys.mean() - v) < 0.3


def test_no_markers_means_no_metric_scale(tmp_path, capsys):
    write_capture(tmp_path / "cap", views=3, width=240, height=180, markers=False, progress=False)
    library = AssetLibrary(tmp_path / "lib")
    with pytest.raises(PegasusError, match="metric scale is impossible"):
        run_scan(tmp_path / "cap" / "images", tmp_path / "work",
                 ScanOptions(name="x", obj_id=3, aruco_size=0.05), library)
    assert library.names() == []
    # with a given scale the markers are not needed: the run gets past that check (here it then stops
    # in SfM: 3 small photos are too few to reconstruct)
    code = main(["scan", str(tmp_path / "cap" / "images"), "--kind", "object", "--obj-id", "3", "--name", "x",
                 "--scale", "1.0", "--library", str(library.root), "--work", str(tmp_path / "w2")])
    err = capsys.readouterr().err
    assert "metric scale is impossible" not in err
    assert code == 0 or library.names() == []


def test_too_few_or_unrelated_photos_fail_clearly_without_an_asset(tmp_path, capsys):
    rng = np.random.default_rng(0)
    folder = tmp_path / "unrelated"
    folder.mkdir()
    for i in range(6):  # independent noise: plenty of features, no shared scene
        noise = cv2.resize(rng.integers(0, 256, (60, 80, 3), dtype=np.uint8), (320, 240),
                           interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(folder / f"{i}.png"), noise)
    library = tmp_path / "lib"
    args = ["--kind", "environment", "--name", "room", "--scale", "1.0", "--library", str(library)]
    assert main(["scan", str(folder), "--work", str(tmp_path / "w1"), *args]) == 2
    err = capsys.readouterr().err
    assert "could be placed" in err or "registered no images" in err
    few = tmp_path / "few"
    few.mkdir()
    for name in ("0.png", "1.png"):
        (few / name).write_bytes((folder / name).read_bytes())
    assert main(["scan", str(few), "--work", str(tmp_path / "w2"), *args]) == 2
    assert "at least 3" in capsys.readouterr().err
    assert not library.exists() or not any(library.iterdir())


@pytest.mark.slow  # 45-60 s: make test-all (make test stays under 15 min)
def test_environment_scan_is_level_and_metric(tmp_path, caplog):
    """The board scanned as an environment through the command line (no masks, estimated camera, photos
    matched in sequence): level at z = 0, board-sized. 30 photos, 24 degrees apart on each of two rings: with
    20 (36 degrees apart) two neighbouring low views failed to register in sequential matching (18 of 20,
    exactly on the bar); with 30, 29-30 of 30 registered over seeds 3-5."""
    write_capture(tmp_path / "cap", views=30, width=400, height=300, seed=3, progress=False)
    library = AssetLibrary(tmp_path / "lib")
    caplog.set_level(logging.INFO, logger="pegasus_gen.scan")  # the pipeline's progress is logged
    assert main(["scan", str(tmp_path / "cap" / "images"), "--kind", "environment", "--name", "board",
                 "--aruco-size", "0.05", "--matcher", "sequential", "--train-size", "64", "--iterations", "150",
                 "--device", "cpu", "--library", str(library.root), "--work", str(tmp_path / "work")]) == 0
    assert "structure from motion (sequential matching)" in caplog.text
    report = json.loads((tmp_path / "work" / "scan_report.json").read_text())
    assert report["sfm"]["registered_fraction"] >= 0.9
    env = library.get("board")
    xy, z = env.splats.means[:, :2], env.splats.means[:, 2]
    board = (np.abs(xy) < 0.2).all(axis=1) & (np.linalg.norm(xy - np.median(xy, axis=0), axis=1) > 0.08)
    # most splats lie on the board, at z = 0 (within 1 cm: 0.75-0.79 over seeds 3-5)
    assert np.mean(np.abs(z) < 0.01) > 0.6
    flat = env.splats.means[board & (np.abs(z) < 0.01)]
    normal = np.linalg.svd(flat - flat.mean(axis=0), full_matrices=False)[2][2]
    assert np.degrees(np.arccos(abs(normal[2]))) < 1.0 and abs(flat[:, 2].mean()) < 0.002, "board not level at z = 0"
    region = env.manifest.drop_region  # inset from the 0.5 m board's inliers (2-98th percentile, 10% margin)
    for extent in (region.x_max - region.x_min, region.y_max - region.y_min):
        assert 0.3 < extent < 0.45, extent
    assert (tmp_path / "work" / "preview.png").is_file() and (tmp_path / "work" / "training_loss.png").is_file()


def test_scan_capture_command_writes_photos_masks_and_truth(tmp_path, capsys):
    assert main(["scan-capture", str(tmp_path / "c"), "--views", "2", "--size", "80", "60"]) == 0
    assert sorted(p.name for p in (tmp_path / "c" / "images").iterdir()) == ["0000.png", "0001.png"]
    mask = cv2.imread(str(tmp_path / "c" / "masks" / "0000.png"), cv2.IMREAD_GRAYSCALE)
    assert mask.shape == (60, 80) and 0 < (mask > 0).mean() < 0.5  # the cup, not the board
    truth = json.loads((tmp_path / "c" / "truth.json").read_text())
    assert set(truth["images"]) == {"0000.png", "0001.png"}
    assert "pegasus scan" in capsys.readouterr().out


def test_unknown_marker_dictionary_is_named(tmp_path):
    write_capture(tmp_path / "cap", views=3, width=120, height=90, progress=False)
    with pytest.raises(PegasusError, match="unknown ArUco dictionary 'DICT_NOPE'"):
        run_scan(tmp_path / "cap" / "images", tmp_path / "work",
                 ScanOptions(name="x", obj_id=3, aruco_size=0.05, aruco_dict="DICT_NOPE"), AssetLibrary(tmp_path / "l"))
