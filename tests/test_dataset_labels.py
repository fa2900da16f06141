"""The dataset around the images: validate, view, COCO read and scored by pycocotools, and DOPE json read as
DOPE's loader reads it. (Masks and gt_info against the BOP definitions: test_bop_labels.py.)"""

import contextlib
import io
import json
import shutil

import cv2
import numpy as np
import pytest
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from pegasus_gen.cli.main import main
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.dataset.validate import coco_instance_count, validate
from pegasus_gen.dataset.view import view

W, H = 320, 240


@pytest.fixture(scope="module")
def dataset(library, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "ds"
    cfg = load_config(None, [f"output={out}", f"library={library.root}", "scenes=1", "frames_per_scene=3",
                             f"camera.width={W}", f"camera.height={H}", "device=cpu", "dope_json=true",
                             "image_format=png",
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


def test_validate_counts_coco_annotations_as_bop_writes_them(dataset, tmp_path):
    infos = {"0": [{"px_count_visib": 40}, {"px_count_visib": 0}], "1": [{"px_count_visib": 1}]}
    assert coco_instance_count(infos) == 2  # a hidden instance has no annotation
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    path = copy / "train_pbr" / "000000" / "scene_gt_coco.json"
    coco = json.loads(path.read_text())
    coco["annotations"] = coco["annotations"][1:]  # one visible instance lost
    path.write_text(json.dumps(coco))
    problems = validate(copy).problems
    assert problems == [f"000000: scene_gt_coco.json has {len(coco['annotations'])} annotations for "
                        f"{len(coco['annotations']) + 1} instances with visible pixels"], problems


def coco_scores(coco_gt, iou_type):
    """pycocotools' AP and AR (IoU 0.5:0.95, all areas) of the ground truth itself scored as detections."""
    detections = [{**a, "score": 1.0} for a in coco_gt.dataset["annotations"]]
    evaluation = COCOeval(coco_gt, coco_gt.loadRes(detections), iou_type)
    with contextlib.redirect_stdout(io.StringIO()):
        evaluation.evaluate()
        evaluation.accumulate()
        evaluation.summarize()
    return evaluation.stats[0], evaluation.stats[8]


def test_scene_gt_coco_is_what_bop_toolkit_writes_and_pycocotools_scores_it_perfectly(dataset):
    scene = dataset / "train_pbr" / "000000"
    gt, infos = load(scene, "scene_gt.json"), load(scene, "scene_gt_info.json")
    for name, box_key in (("scene_gt_coco.json", "mask"), ("scene_gt_coco_modal.json", "mask_visib")):
        with contextlib.redirect_stdout(io.StringIO()):
            coco = COCO(str(scene / name))
        assert [(c["id"], c["name"]) for c in coco.dataset["categories"]] == [(1, "1"), (5, "5"), (7, "7")]
        assert [im["file_name"] for im in coco.dataset["images"]] == [f"rgb/{i:06d}.png" for i in range(3)]
        annotations = coco.dataset["annotations"]
        assert [a["id"] for a in annotations] == list(range(1, len(annotations) + 1))
        written = [(im_id, gt_idx) for im_id in sorted(gt, key=int) for gt_idx in range(len(gt[im_id]))
                   if infos[im_id][gt_idx]["px_count_visib"] > 0]
        assert len(annotations) == len(written)
        for ann, (im_id, gt_idx) in zip(annotations, written):
            mask_name = f"{int(im_id):06d}_{gt_idx:06d}.png"
            visib = cv2.imread(str(scene / "mask_visib" / mask_name), 0) > 0
            boxed = cv2.imread(str(scene / box_key / mask_name), 0) > 0
            ys, xs = np.nonzero(boxed)
            assert np.array_equal(coco.annToMask(ann) > 0, visib) and ann["area"] == visib.sum()
            assert ann["bbox"] == [xs.min(), ys.min(), np.ptp(xs) + 1, np.ptp(ys) + 1]
            assert ann["category_id"] == gt[im_id][gt_idx]["obj_id"] and ann["image_id"] == int(im_id)
            assert ann["ignore"] == (infos[im_id][gt_idx]["visib_fract"] < 0.1)
        for iou_type in ("bbox", "segm"):
            assert coco_scores(coco, iou_type) == (1.0, 1.0)


def read_dope_folder(folder):
    """What DOPE's training loader reads, written from its contract: every png with a json of the same name,
    each object's class and its 9 projected cuboid points (8 corners, then the centroid)."""
    samples = []
    for image in sorted(folder.glob("*.png")):
        doc = json.loads(image.with_suffix(".json").read_text())
        samples.append((image, [(o["class"], np.array(o["projected_cuboid"], float)) for o in doc["objects"]]))
    return samples


def test_dope_json_is_what_the_dope_loader_reads_and_matches_the_pose_and_the_model_box(dataset):
    scene = dataset / "train_pbr" / "000000"
    gt, cams, infos = load(scene, "scene_gt.json"), load(scene, "scene_camera.json"), load(scene, "scene_gt_info.json")
    info = load(dataset / "models", "models_info.json")
    samples = read_dope_folder(scene / "rgb")
    assert len(samples) == 3
    for image, objects in samples:
        im_id = image.stem.lstrip("0") or "0"
        doc = load(scene / "rgb", f"{image.stem}.json")
        K = np.array(cams[im_id]["cam_K"]).reshape(3, 3)
        assert doc["camera_data"]["intrinsics"] == {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
        visible = [n for n, i in enumerate(infos[im_id]) if i["px_count_visib"] > 0]
        assert [o["name"] for o in doc["objects"]] == [f"{info[str(gt[im_id][n]['obj_id'])]['name']}_{n:03d}"
                                                       for n in visible]
        assert [c for c, _ in objects] == [info[str(gt[im_id][n]["obj_id"])]["name"] for n in visible]
        for n, obj, (_, cuboid) in zip(visible, doc["objects"], objects):
            entry, gt_info = gt[im_id][n], infos[im_id][n]
            T = pose(entry["cam_R_m2c"], entry["cam_t_m2c"])
            m = info[str(entry["obj_id"])]
            lo = np.array([m["min_x"], m["min_y"], m["min_z"]]) / 1000
            size = np.array([m["size_x"], m["size_y"], m["size_z"]]) / 1000
            corner0 = lo + size * [1, 0, 1]  # (+x, -y, +z)
            assert cuboid.shape == (9, 2)
            for point, uv in ((lo + size / 2, cuboid[8]), (corner0, cuboid[0])):
                p = T[:3, :3] @ point + T[:3, 3]
                np.testing.assert_allclose(uv, (K @ p)[:2] / p[2], atol=1e-6)
            np.testing.assert_allclose(obj["location"], T[:3, 3] * 100, atol=1e-9)  # centimetres, as NDDS
            x, y, z, w = obj["quaternion_xyzw"]
            assert abs(np.dot([w, x, y, z], [w, x, y, z]) - 1) < 1e-9
            assert np.isclose(1 - 2 * (y * y + z * z), T[0, 0], atol=1e-9)
            bx, by, bw, bh = gt_info["bbox_visib"]
            assert obj["bounding_box_minx_maxx_miny_maxy"] == [bx, bx + bw, by, by + bh]
            assert (obj["px_count_all"], obj["px_count_visib"]) == (gt_info["px_count_all"], gt_info["px_count_visib"])
            T_world_cam = np.linalg.inv(np.array(doc["camera_data"]["camera_view_matrix"]))
            T_cam_obj = np.linalg.inv(T_world_cam) @ np.array(obj["local_to_world_matrix"])
            np.testing.assert_allclose(T_cam_obj[:3, 3], obj["location"], atol=1e-6)  # both in cm


def test_view_writes_overlays_and_a_gallery(dataset, tmp_path):
    page = view(dataset, tmp_path / "view", max_images=2)
    text = page.read_text()
    overlays = sorted((tmp_path / "view").glob("*.jpg"))
    assert [p.name for p in overlays] == ["000000_000000.jpg", "000000_000001.jpg"]
    assert all(p.name in text for p in overlays)
    drawn = cv2.imread(str(overlays[0])).astype(int)
    original = cv2.imread(str(dataset / "train_pbr" / "000000" / "rgb" / "000000.png")).astype(int)
    assert (np.abs(drawn - original).sum(axis=2) > 60).mean() > 0.01  # contours and boxes were drawn
