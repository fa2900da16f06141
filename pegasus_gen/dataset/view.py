"""`pegasus view`: overlay images of a BOP dataset (mask contours, 3D boxes, axes) and an HTML gallery."""

from __future__ import annotations

import html
import logging
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import bop_frames, mask_name, model_boxes
from pegasus_gen.formats.drawing import colour_of, draw_instance
from pegasus_gen.io.files import write_atomic
from pegasus_gen.io.images import read_rgb, write_image

log = logging.getLogger(__name__)

def _mask(path: Path) -> np.ndarray | None:
    m = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    return None if m is None else m > 0


def _missing_note(missing: list[str]) -> str:
    """The gallery's warning about files it could not show (also logged), empty when none."""
    if not missing:
        return ""
    unique = sorted(set(missing))
    text = f"{len(unique)} file(s) missing or unreadable, not drawn: {', '.join(unique[:5])}" + \
        (" ..." if len(unique) > 5 else "")
    log.warning("view: %s", text)
    return f'<p style="color:#f88">{html.escape(text)}</p>'


def _check_frame(frame) -> None:
    """Refuse (PegasusError) a frame that cannot be drawn: a camera matrix that is not finite with fx, fy > 0, or a
    pose that is not finite."""
    K = frame.K
    if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise PegasusError(f"{frame.scene / 'scene_camera.json'}: image {frame.im_id}: cam_K {K.ravel().tolist()} is "
                           "not a camera matrix (finite, fx and fy > 0)")
    for inst in frame.instances:
        if not np.all(np.isfinite(inst.T)):
            raise PegasusError(f"{frame.scene / 'scene_gt.json'}: image {frame.im_id}: instance {inst.index}: "
                               "cam_R_m2c / cam_t_m2c are not finite")


def view(root: str | Path, out: str | Path, split: str = "train_pbr", max_images: int = 10) -> Path:
    """Overlays of up to ``max_images`` images per scene written to ``out``/SSSSSS_IIIIII.jpg and a gallery
    ``out``/index.html linking them; returns the gallery's path."""
    root, out = Path(root), Path(out)
    if not (root / split).is_dir():
        raise PegasusError(f"{root}: no {split}/ folder, so not a BOP dataset (or choose --split)")
    boxes = model_boxes(root)
    cards, missing = [], []
    frames = list(bop_frames(root / split, max_images))
    for frame in frames:
        _check_frame(frame)
    for frame in tqdm(frames, desc="view", unit="image"):
        image = read_rgb(frame.image)
        caption = []
        for inst in frame.instances:
            label = f"{inst.obj_id}" + (f" {inst.visib_fract:.0%}" if inst.visib_fract is not None else "")
            caption.append(f"obj {label}")
            if inst.obj_id not in boxes:
                missing.append(f"models_info.json: obj {inst.obj_id} (no box drawn)")
            bbox_min, bbox_size = boxes.get(inst.obj_id, (np.zeros(3), np.zeros(3)))
            name = mask_name(frame.im_id, inst.index)
            masks = [_mask(frame.scene / folder / name) for folder in ("mask", "mask_visib")]
            missing += [f"{frame.scene.name}/{folder}/{name}" for folder, m in zip(("mask", "mask_visib"), masks)
                        if m is None]
            draw_instance(image, frame.K, inst.T, bbox_min, bbox_size, *masks, colour_of(inst.obj_id), label)
        file = f"{frame.scene.name}_{frame.im_id:06d}.jpg"
        write_image(out / file, image, jpg_quality=90)
        cards.append((file, f"scene {frame.scene.name} image {frame.im_id}", ", ".join(caption)))
    figures = "\n".join(
        f'<figure><a href="{html.escape(f)}"><img src="{html.escape(f)}" loading="lazy"></a>'
        f"<figcaption><b>{html.escape(t)}</b><br>{html.escape(c)}</figcaption></figure>" for f, t, c in cards)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(str(root))}</title>
<style>body{{font-family:sans-serif;background:#222;color:#ddd}} main{{display:flex;flex-wrap:wrap;gap:8px}}
figure{{margin:0;width:320px}} img{{width:320px}} figcaption{{font-size:12px}}</style></head>
<body><h2>{html.escape(str(root))} ({split}): {len(cards)} images</h2>
{_missing_note(missing)}
<p>thin contour: full mask, thick: visible mask; box: model bounding box at the GT pose; axes x red, y green,
z blue; label: obj_id and visible fraction</p>
<main>
{figures}
</main></body></html>
"""
    return write_atomic(out / "index.html", lambda f: f.write(page.encode()))
