"""Photo backgrounds behind the objects in DOPE's training crops: the objects' pixels kept, everything else from a
photo, the crop's geometry and targets unchanged; the photos load offline, from a folder or scikit-image; a share
of them is held out of training, and a BOP dataset's copy shows them behind its objects."""

import json

import cv2
import numpy as np
import pytest
import torch

from dope_training.backgrounds import load_photos, masks_union, photo_backed, photo_view, split_photos, warp_alpha
from dope_training.data import Augment, DopeDataset, Sample, load_bop
from pegasus_gen.errors import PegasusError

PLAIN = Augment(brightness=0, contrast=0, saturation=0, hue_deg=0, noise_std=0)  # pixel values kept


def test_objects_keep_their_pixels_and_the_rest_shows_the_photo(tmp_path):
    image = np.full((300, 400, 3), 40, np.uint8)
    mask = np.zeros((300, 400), np.uint8)
    cv2.circle(mask, (200, 150), 45, 255, -1)
    image[mask > 0] = (10, 120, 250)
    cv2.imwrite(str(tmp_path / "im.png"), image[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    corners = np.array([[x, y] for x in (160.0, 240.0) for y in (110.0, 190.0)] * 2)
    sample = Sample(tmp_path / "im.png", np.eye(3), [np.vstack([corners, [[200.0, 150.0]]])], [1], [1.0],
                    [1.0], [tmp_path / "mask.png"])
    photo = np.full((64, 64, 3), 200, np.uint8)
    plain, pasted = (DopeDataset([sample], size=128, focal_px=1.0, augment=PLAIN, backgrounds=share, photos=[photo])
                     for share in (0.0, 1.0))
    for epoch in range(12):
        plain.epoch = pasted.epoch = epoch
        crop0, moved0, M0 = plain.item(0)
        crop1, moved1, M1 = pasted.item(0)
        assert np.array_equal(M0, M1) and np.array_equal(moved0, moved1)  # the same crop of the same instance
        for a, b in zip(plain[0][1:], pasted[0][1:]):
            assert torch.equal(a, b)  # every target untouched
        alpha = warp_alpha(masks_union(sample.masks), M1, 128)
        inside, outside = alpha > 0.999, alpha < 0.001
        assert inside.sum() > 500 and outside.sum() > 500
        assert np.array_equal(crop1[inside], crop0[inside])  # the object as rendered
        assert (crop1[outside] == 200).all() and not (crop0 == 200).all(axis=2).any()  # the photo, only there


def test_preloaded_frames_give_the_same_items_as_frames_read_from_disk_and_need_the_disk_no_more(tmp_path):
    rng = np.random.default_rng(3)
    samples = []
    for i in range(3):
        image = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
        mask = np.zeros((120, 160), np.uint8)
        cv2.circle(mask, (70 + 5 * i, 60), 25, 255, -1)
        cv2.imwrite(str(tmp_path / f"im{i}.png"), image)
        cv2.imwrite(str(tmp_path / f"mask{i}.png"), mask)
        corners = np.array([[x, y] for x in (50.0, 90.0) for y in (40.0, 80.0)] * 2) + [5 * i, 0]
        samples.append(Sample(tmp_path / f"im{i}.png", np.eye(3), [np.vstack([corners, [[70.0 + 5 * i, 60.0]]])],
                              [1], [1.0], [1.0], [tmp_path / f"mask{i}.png"]))
    photos = [rng.integers(0, 256, (90, 70, 3), dtype=np.uint8)]
    read, held = (DopeDataset(samples, size=64, focal_px=1.0, negatives=0.3, occluders=0.5, backgrounds=0.5,
                              photos=photos) for _ in range(2))
    assert not held.preload(3 * 120 * 160 * 4 - 1)  # one byte short: nothing decoded, still read from disk
    assert held.preload(3 * 120 * 160 * 4)
    expected = [[read[(epoch, i)] for i in range(3)] for epoch in range(6)]
    for path in tmp_path.iterdir():
        path.unlink()
    for epoch in range(6):
        for i in range(3):
            for a, b in zip(expected[epoch][i], held[(epoch, i)]):
                assert torch.equal(a, b)


def test_bop_samples_carry_the_visible_masks_of_every_labelled_instance(library, tmp_path):
    from pegasus_gen.dataset.config import load_config
    from pegasus_gen.dataset.generate import generate

    root = generate(load_config(None, [f"output={tmp_path / 'ds'}", f"library={library.root}", "scenes=1",
                                       "frames_per_scene=1", "camera.width=160", "camera.height=120", "device=cpu",
                                       "environments=[wooden_table]",
                                       "objects=[{asset: 1, count: [1, 1]}, {asset: 7, count: [2, 2]}]"]))
    [sample] = load_bop(root, [1], min_visibility=0.0)
    assert sample.obj_ids == [1] and len(sample.masks) == 3  # the target's and both other objects'
    scene = root / "train_pbr" / "000000"
    union = np.zeros((120, 160), bool)
    for path in sample.masks:
        assert path.parent == scene / "mask_visib"
        union |= cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 0
    alpha = warp_alpha(masks_union(sample.masks), np.array([[1.0, 0, 0], [0, 1.0, 0]]), 120)[:, :120]
    assert ((alpha > 0.5) == union[:, :120]).mean() > 0.99  # the union, closed by a pixel at most


def test_photos_load_offline_from_scikit_image_or_a_folder(tmp_path):
    photos = load_photos()
    assert len(photos) >= 15 and all(p.ndim == 3 and p.shape[2] == 3 and p.dtype == np.uint8 for p in photos)
    assert len({p.shape for p in photos}) > 3  # different photographs, not one repeated
    for name, value in (("a.png", 30), ("sub/b.jpg", 90)):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        cv2.imwrite(str(tmp_path / name), np.full((50, 70, 3), value, np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    assert sorted(int(p.mean()) for p in load_photos(tmp_path)) == [30, 90]
    with pytest.raises(PegasusError, match="no such folder"):
        load_photos(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(PegasusError, match="no images"):
        load_photos(tmp_path / "empty")


def test_photo_views_vary_in_place_scale_and_turn():
    rng = np.random.default_rng(0)
    photo = np.random.default_rng(1).integers(0, 256, (200, 300, 3), dtype=np.uint8)
    views = [photo_view([photo], 64, rng) for _ in range(20)]
    assert all(v.shape == (64, 64, 3) and v.dtype == np.uint8 for v in views)
    assert len({v.tobytes() for v in views}) == 20
    with pytest.raises(PegasusError, match="needs background photos"):
        DopeDataset([], size=64, backgrounds=0.5)


def test_every_fourth_photo_from_the_first_is_held_out_of_training():
    photos = [np.full((4, 4, 3), i, np.uint8) for i in range(10)]
    training, held_out = split_photos(photos)
    assert [int(p[0, 0, 0]) for p in held_out] == [0, 4, 8]
    assert [int(p[0, 0, 0]) for p in training] == [1, 2, 3, 5, 6, 7, 9]
    training, held_out = split_photos(photos[:1])
    assert len(training) == 1 and held_out == []  # one photo is not split
    training, held_out = split_photos(load_photos())
    assert len(held_out) >= 4 and len(training) >= 3 * len(held_out) - 3
    assert not {p.tobytes() for p in training} & {p.tobytes() for p in held_out}


def test_a_photo_view_takes_the_height_and_width_asked_for():
    photo = np.random.default_rng(1).integers(0, 256, (200, 300, 3), dtype=np.uint8)
    view = photo_view([photo], (48, 80), np.random.default_rng(0))
    assert view.shape == (48, 80, 3) and view.dtype == np.uint8 and view.std() > 20


def _bop_scene(root, images):
    """A BOP dataset at ``root``: one scene of ``images``, (rgb [H, W, 3] uint8, masks: list of [H, W] 0/1) each."""
    scene = root / "train_pbr" / "000000"
    (scene / "rgb").mkdir(parents=True)
    (scene / "mask_visib").mkdir()
    gt, cams, info = {}, {}, {}
    for im_id, (rgb, masks) in enumerate(images):
        cv2.imwrite(str(scene / "rgb" / f"{im_id:06d}.png"), rgb[:, :, ::-1])
        for n, mask in enumerate(masks):
            cv2.imwrite(str(scene / "mask_visib" / f"{im_id:06d}_{n:06d}.png"), mask * 255)
        gt[str(im_id)] = [{"obj_id": 1, "cam_R_m2c": np.eye(3).ravel().tolist(), "cam_t_m2c": [0, 0, 500]}] * len(masks)
        cams[str(im_id)] = {"cam_K": [500, 0, 40, 0, 500, 30, 0, 0, 1], "depth_scale": 1.0}
        info[str(im_id)] = [{"visib_fract": 1.0}] * len(masks)
    for name, doc in (("scene_gt", gt), ("scene_camera", cams), ("scene_gt_info", info)):
        (scene / f"{name}.json").write_text(json.dumps(doc))
    (root / "models").mkdir()
    (root / "models" / "models_info.json").write_text(json.dumps({"1": {"diameter": 50.0}}))
    (root / "camera.json").write_text(json.dumps({"fx": 500}))
    return scene


def test_a_photo_backed_copy_keeps_the_labelled_objects_and_shows_the_photo_everywhere_else(tmp_path):
    rng = np.random.default_rng(2)
    images = []
    for i in range(3):
        rgb = rng.integers(0, 100, (60, 80, 3), dtype=np.uint8)
        masks = [np.zeros((60, 80), np.uint8) for _ in range(2)]
        cv2.circle(masks[0], (20 + 5 * i, 30), 9, 1, -1)
        cv2.circle(masks[1], (60, 25 + 5 * i), 7, 1, -1)
        images.append((rgb, masks))
    scene = _bop_scene(tmp_path / "ds", images)
    out = photo_backed(tmp_path / "ds", "train_pbr", tmp_path / "backed", [np.full((40, 50, 3), 200, np.uint8)])
    copy = out / "train_pbr" / "000000"
    for im_id, (rgb, masks) in enumerate(images):
        backed = cv2.imread(str(copy / "rgb" / f"{im_id:06d}.png"))[:, :, ::-1]
        objects = (masks[0] | masks[1]) > 0
        assert np.array_equal(backed[objects], rgb[objects])  # the labelled objects as they were
        assert (backed[~objects] == 200).all()  # the photo everywhere else
    for name in ("scene_gt.json", "scene_camera.json", "scene_gt_info.json"):
        assert (copy / name).read_bytes() == (scene / name).read_bytes()
    assert (out / "models" / "models_info.json").is_file() and (out / "camera.json").is_file()
    with pytest.raises(PegasusError, match="exists"):
        photo_backed(tmp_path / "ds", "train_pbr", out, [np.zeros((8, 8, 3), np.uint8)])


def test_a_photo_backed_copy_that_fails_leaves_nothing(tmp_path):
    blank = np.zeros((60, 80), np.uint8)
    ring = blank.copy()
    cv2.circle(ring, (40, 30), 9, 1, -1)
    _bop_scene(tmp_path / "ds", [(np.zeros((60, 80, 3), np.uint8), [ring]), (np.zeros((60, 80, 3), np.uint8), [])])
    with pytest.raises(PegasusError, match="no visible masks"):
        photo_backed(tmp_path / "ds", "train_pbr", tmp_path / "backed", [np.zeros((8, 8, 3), np.uint8)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]  # neither the copy nor its partial folder
