"""COCO as bop_toolkit's calc_gt_coco writes it, read and scored by pycocotools, on masks made here."""

import contextlib
import io
import json

import numpy as np
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from pegasus_gen.dataset.coco import CocoInstance, scene_coco

H, W = 60, 80


def rect(x0, y0, x1, y1):
    mask = np.zeros((H, W), bool)
    mask[max(y0, 0):y1, max(x0, 0):x1] = True
    return mask


def instances():
    """Image 0: a box half hidden behind another, a blob, a box cut by the image border and one fully hidden
    (no visible pixel); image 3: one box seen at 5 %."""
    yy, xx = np.mgrid[:H, :W]
    blob = (yy - 40) ** 2 / 60 + (xx - 60) ** 2 / 30 < 1
    front, behind = rect(10, 10, 30, 40), rect(20, 15, 45, 35)
    hidden = rect(12, 12, 20, 20)
    return [CocoInstance(0, 1, behind, behind & ~front, 0.6), CocoInstance(0, 2, front, front, 1.0),
            CocoInstance(0, 3, blob, blob, 1.0), CocoInstance(0, 1, rect(70, 0, 80, 20), rect(70, 0, 80, 20), 1.0),
            CocoInstance(0, 2, hidden, np.zeros((H, W), bool), 0.0),
            CocoInstance(3, 3, rect(0, 40, 20, 60), rect(0, 40, 1, 60), 0.05)]


def load(data, tmp_path):
    path = tmp_path / "coco.json"
    path.write_text(json.dumps(data))
    with contextlib.redirect_stdout(io.StringIO()):
        return COCO(str(path))


def scores(coco, iou_type):
    evaluation = COCOeval(coco, coco.loadRes([{**a, "score": 1.0} for a in coco.dataset["annotations"]]), iou_type)
    with contextlib.redirect_stdout(io.StringIO()):
        evaluation.evaluate()
        evaluation.accumulate()
        evaluation.summarize()
    return evaluation.stats[0], evaluation.stats[8]


def test_ground_truth_scored_as_detections_gives_ap_and_ar_of_one(tmp_path):
    images = [{"id": i, "file_name": f"rgb/{i:06d}.png", "width": W, "height": H} for i in (0, 3)]
    for modal in (False, True):
        coco = load(scene_coco([1, 2, 3, 9], "mine", images, instances(), modal), tmp_path)
        for iou_type in ("bbox", "segm"):
            assert scores(coco, iou_type) == (1.0, 1.0)


def test_ids_from_one_hidden_left_out_amodal_and_modal_boxes(tmp_path):
    images = [{"id": i, "file_name": f"rgb/{i:06d}.png", "width": W, "height": H} for i in (0, 3)]
    amodal = scene_coco([1, 2, 3, 9], "mine", images, instances(), modal=False)
    modal = scene_coco([1, 2, 3, 9], "mine", images, instances(), modal=True)
    assert amodal["categories"] == [{"id": i, "name": str(i), "supercategory": "mine"} for i in (1, 2, 3, 9)]
    assert [a["id"] for a in amodal["annotations"]] == [1, 2, 3, 4, 5]  # the hidden instance is not written
    assert [a["category_id"] for a in amodal["annotations"]] == [1, 2, 3, 1, 3]
    behind_amodal, behind_modal = amodal["annotations"][0], modal["annotations"][0]
    assert behind_amodal["bbox"] == [20, 15, 25, 20]  # the whole box, part of it behind the front one
    assert behind_modal["bbox"] == [30, 15, 15, 20]  # what is seen of it
    assert behind_amodal["area"] == behind_modal["area"] == (rect(20, 15, 45, 35) & ~rect(10, 10, 30, 40)).sum()
    assert [a["ignore"] for a in amodal["annotations"]] == [False, False, False, False, True]
    coco = load(amodal, tmp_path)
    decoded = coco.annToMask(coco.dataset["annotations"][2]) > 0
    assert np.array_equal(decoded, instances()[2].mask_visib)
