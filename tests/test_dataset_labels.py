"""The dataset around the images: validate, view, scene_gt_coco, DOPE json, and gt_info recomputed here
from the written files by the BOP definitions."""

import json
import shutil

import cv2
import numpy as np
import pytest

from pegasus_gen.cli.main import main
from pegasus_gen.dataset.bop import ray_lengths
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.dataset.validate import validate
from pegasus_gen.dataset.view import view
from pegasus_gen.render.renderer import render

W, H = 320, 240


@pytest.fixture(scope="module")
def dataset(library, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "ds"
    cfg = load_config(None, [f"output={out}", f"library={library.root}", "scenes=1", "frames_per_scene=3",
                             f"camera.width={W}", f"camera.height={H}", "device=cpu", "dope_json=true",
                             "environments=[wooden_table]",
                             "objects=[{asset: 1, count: [1, 1]}, {asset: 5, count: [1, 1]},"
                             " {asset: 7, count: [1, 1]}]"])
    return generate(cfg)


def load(scene, name):
    return json.loads((scene / name).read_text())


def pose(R, t_mm):
    T = np.eye(4)
    T[:3, :3] = np.array(R).reshape(3, 3)
    T[:3, 3] = np.array(t_mm) / 1000
    return T


def test_generated_dataset_passes_validate(dataset, capsys):
    report = validate(dataset)
    assert report.ok, report.problems
    assert report.images == 3 and report.instances == 9
    assert report.ious and min(report.ious) >= 0.9
    assert report.depth_errors_mm and max(report.depth_errors_mm) <= 5.0
    assert main(["validate", str(dataset)]) == 0
    assert "OK" in capsys.readouterr().out


def corrupted(dataset, tmp_path, edit):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    path = copy / "train_pbr" / "000000" / "scene_gt.json"
    gt = json.loads(path.read_text())
    edit(gt["0"][0])
    path.write_text(json.dumps(gt))
    return copy


def test_validate_catches_a_wrong_pose_and_metres_for_millimetres(dataset, tmp_path, capsys):
    def shift(entry):
        entry["cam_t_m2c"][0] += 25.0  # 2.5 cm sideways

    report = validate(corrupted(dataset, tmp_path / "a", shift))
    assert any("000000/000000_000000: the posed model covers its mask with IoU" in p for p in report.problems)

    def metres(entry):
        entry["cam_t_m2c"] = [v / 1000 for v in entry["cam_t_m2c"]]

    bad = corrupted(dataset, tmp_path / "b", metres)
    assert any("not a depth in mm" in p for p in validate(bad).problems)
    assert main(["validate", str(bad)]) == 1
    assert main(["validate", str(tmp_path / "nothing")]) == 2
    assert "no train_pbr/ folder" in capsys.readouterr().err


def test_gt_info_equals_a_recomputation_from_the_written_files(dataset, library):
    """calc_gt_info's definitions applied here: the object alone rendered on the full 3x canvas (no window),
    visibility from the written 16-bit depth and distances along the rays."""
    scene = dataset / "train_pbr" / "000000"
    gt, cams, infos = (load(scene, n) for n in ("scene_gt.json", "scene_camera.json", "scene_gt_info.json"))
    for im_id, entries in gt.items():
        cam = cams[im_id]
        K = np.array(cam["cam_K"]).reshape(3, 3)
        T_cam_world = pose(cam["cam_R_w2c"], cam["cam_t_w2c"])
        depth_png = cv2.imread(str(scene / "depth" / f"{int(im_id):06d}.png"), cv2.IMREAD_UNCHANGED)
        depth_m = depth_png * cam["depth_scale"] / 1000
        K3 = K.copy()
        K3[:2, 2] += [W, H]
        for gt_idx, (entry, info) in enumerate(zip(entries, infos[im_id])):
            T_world_obj = np.linalg.inv(T_cam_world) @ pose(entry["cam_R_m2c"], entry["cam_t_m2c"])
            splats = library.get(entry["obj_id"]).splats.transformed(T_world_obj)
            canvas = render(splats, K3, T_cam_world, 3 * W, 3 * H, device="cpu").depth
            obj = canvas[H:2 * H, W:2 * W]
            rays = ray_lengths(K, W, H)
            visible = (obj > 0) & ((obj * rays - depth_m * rays <= 0.015) | (depth_m == 0))
            ys, xs = np.nonzero(canvas > 0)
            assert abs(info["px_count_all"] - len(xs)) <= 2
            box = [xs.min() - W, ys.min() - H, np.ptp(xs) + 1, np.ptp(ys) + 1]
            assert np.abs(np.array(info["bbox_obj"]) - box).max() <= 1
            written = cv2.imread(str(scene / "mask_visib" / f"{int(im_id):06d}_{gt_idx:06d}.png"), 0) > 0
            assert (written != visible).sum() <= max(2, 0.005 * visible.sum())  # depth PNG rounding at delta
            assert abs(info["px_count_visib"] - visible.sum()) <= max(2, 0.005 * visible.sum())
            assert info["visib_fract"] == pytest.approx(info["px_count_visib"] / info["px_count_all"])


def rle_decode(rle):
    h, w = rle["size"]
    flat = np.zeros(h * w, bool)
    pos, value = 0, False
    for count in rle["counts"]:
        flat[pos:pos + count] = value
        pos, value = pos + count, not value
    assert pos == h * w
    return flat.reshape((h, w), order="F")


def test_scene_gt_coco_holds_the_visible_masks(dataset):
    scene = dataset / "train_pbr" / "000000"
    coco, gt, infos = (load(scene, n) for n in ("scene_gt_coco.json", "scene_gt.json", "scene_gt_info.json"))
    assert {c["id"] for c in coco["categories"]} == {1, 5, 7}
    assert [im["file_name"] for im in coco["images"]] == [f"rgb/{i:06d}.jpg" for i in range(3)]
    per_image = {}
    for ann in coco["annotations"]:
        per_image.setdefault(ann["image_id"], []).append(ann)
    for im_id, anns in per_image.items():
        for gt_idx, ann in enumerate(anns):
            visib = cv2.imread(str(scene / "mask_visib" / f"{im_id:06d}_{gt_idx:06d}.png"), 0) > 0
            assert np.array_equal(rle_decode(ann["segmentation"]), visib)
            assert ann["category_id"] == gt[str(im_id)][gt_idx]["obj_id"]
            assert ann["bbox"] == infos[str(im_id)][gt_idx]["bbox_visib"] and ann["area"] == visib.sum()
    assert len({a["id"] for a in coco["annotations"]}) == 9


def test_dope_json_cuboid_matches_the_pose_and_the_model_box(dataset):
    scene = dataset / "train_pbr" / "000000"
    gt, cams = load(scene, "scene_gt.json"), load(scene, "scene_camera.json")
    info = load(dataset / "models", "models_info.json")
    doc = load(scene / "rgb", "000001.json")
    K = np.array(cams["1"]["cam_K"]).reshape(3, 3)
    assert doc["camera_data"]["intrinsics"] == {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    for entry, obj in zip(gt["1"], doc["objects"]):
        T = pose(entry["cam_R_m2c"], entry["cam_t_m2c"])
        m = info[str(entry["obj_id"])]
        lo = np.array([m["min_x"], m["min_y"], m["min_z"]]) / 1000
        size = np.array([m["size_x"], m["size_y"], m["size_z"]]) / 1000
        corner0 = lo + size * [1, 0, 1]  # (+x, -y, +z)
        for point, uv in ((lo + size / 2, obj["projected_cuboid"][8]), (corner0, obj["projected_cuboid"][0])):
            p = T[:3, :3] @ point + T[:3, 3]
            np.testing.assert_allclose(uv, (K @ p)[:2] / p[2], atol=1e-6)
        np.testing.assert_allclose(obj["location"], T[:3, 3] * 100, atol=1e-9)  # centimetres, as NDDS
        x, y, z, w = obj["quaternion_xyzw"]
        assert abs(np.dot([w, x, y, z], [w, x, y, z]) - 1) < 1e-9
        assert np.isclose(1 - 2 * (y * y + z * z), T[0, 0], atol=1e-9)


def test_view_writes_overlays_and_a_gallery(dataset, tmp_path):
    page = view(dataset, tmp_path / "view", max_images=2)
    text = page.read_text()
    overlays = sorted((tmp_path / "view").glob("*.jpg"))
    assert [p.name for p in overlays] == ["000000_000000.jpg", "000000_000001.jpg"]
    assert all(p.name in text for p in overlays)
    drawn = cv2.imread(str(overlays[0])).astype(int)
    original = cv2.imread(str(dataset / "train_pbr" / "000000" / "rgb" / "000000.jpg")).astype(int)
    assert (np.abs(drawn - original).sum(axis=2) > 60).mean() > 0.01  # contours and boxes were drawn
