"""DOPE training data: targets on the keypoints, BOP samples against the poses, augmentation that
moves keypoints with the pixels and adds no mirrored borders."""

import json

import cv2
import numpy as np
import pytest
import torch
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation
from scipy.stats import norm
from skimage import color

from dope_training.data import (
    SRGB_TO_LINEAR,
    Augment,
    DopeDataset,
    Sample,
    blur_light,
    canonical_pose,
    input_scale,
    jitter_colour,
    load_bop,
)
from dope_training.targets import (
    cell_centres,
    cells_to_pixels,
    distance_code,
    distance_from_code,
    make_targets,
    off_axis_factor,
    read_map,
)
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.errors import PegasusError


def test_belief_peaks_on_the_keypoint_and_affinities_point_to_the_centroid():
    rng = np.random.default_rng(3)
    points = rng.uniform(20, 180, (2, 9, 2))
    beliefs, affinities = make_targets(points, np.ones((2, 9), bool), 200, 200, stride=8)
    assert beliefs.shape == (9, 25, 25) and affinities.shape == (16, 25, 25)
    cx, cy = cell_centres(200, 200, 8)
    for k in range(9):
        for inst in points:  # each keypoint is a local peak; the 3x3 weighted mean around it lands on it
            i, j = int(round((inst[k, 1] + 0.5) / 8 - 0.5)), int(round((inst[k, 0] + 0.5) / 8 - 0.5))
            window = beliefs[k, i - 1:i + 2, j - 1:j + 2]
            assert beliefs[k, i, j] == window.max() >= np.exp(-1) - 1e-6  # at worst half a cell off in x and y
            mean = [(window * c[i - 1:i + 2, j - 1:j + 2]).sum() / window.sum() for c in (cx, cy)]
            assert np.hypot(*(np.array(mean) - inst[k])) < 2.0
    last = points[1]  # later instances win where fields overlap
    for k in range(8):
        near = np.hypot(cx - last[k, 0], cy - last[k, 1]) <= 8
        want = (last[8] - last[k]) / np.linalg.norm(last[8] - last[k])
        got = np.stack([affinities[2 * k][near], affinities[2 * k + 1][near]], 1)
        np.testing.assert_allclose(got, np.tile(want, (len(got), 1)), atol=1e-6)
        assert not affinities[2 * k][~near & (np.hypot(cx - points[0, k, 0], cy - points[0, k, 1]) > 8)].any()


@pytest.fixture(scope="module")
def dataset(library, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "ds"
    return generate(load_config(None, [f"output={out}", f"library={library.root}", "scenes=1", "frames_per_scene=2",
                                       "camera.width=320", "camera.height=240", "device=cpu",
                                       "environments=[wooden_table]",
                                       "objects=[{asset: 1, count: [1, 1]}, {asset: 7, count: [1, 2]}]"]))


def test_bop_samples_put_keypoints_on_the_posed_model_box(dataset):
    samples = load_bop(dataset, ["noodle_cup_red"], min_visibility=0.0)
    assert len(samples) == 2 and all(s.obj_ids == [1] for s in samples)
    scene = dataset / "train_pbr" / "000000"
    gt = json.loads((scene / "scene_gt.json").read_text())
    info = json.loads((dataset / "models" / "models_info.json").read_text())["1"]
    centre_mm = np.array([info[f"min_{a}"] + info[f"size_{a}"] / 2 for a in "xyz"])
    for im_id, sample in enumerate(samples):
        entry = next(e for e in gt[str(im_id)] if e["obj_id"] == 1)
        p = np.array(entry["cam_R_m2c"]).reshape(3, 3) @ centre_mm + entry["cam_t_m2c"]
        np.testing.assert_allclose(sample.keypoints[0][8], (sample.K @ p)[:2] / p[2], atol=1e-6)
        assert sample.depths[0] == pytest.approx(p[2] / 1000.0, rel=1e-9)  # the box centre's depth, m
        gt_idx = [e["obj_id"] for e in gt[str(im_id)]].index(1)
        mask = cv2.imread(str(scene / "mask" / f"{im_id:06d}_{gt_idx:06d}.png"), 0) > 0
        hull = cv2.convexHull(sample.keypoints[0][:8].astype(np.float32))
        ys, xs = np.nonzero(mask)
        inside = [cv2.pointPolygonTest(hull, (float(x), float(y)), True) > -1.5 for x, y in zip(xs, ys)]
        assert np.mean(inside) > 0.995  # the model's box encloses its silhouette


def test_visibility_filter_and_unknown_objects(dataset):
    everything = load_bop(dataset, [1, 7], min_visibility=0.0)
    visible = load_bop(dataset, [1, 7], min_visibility=0.9)
    assert sum(map(len, (s.visibility for s in visible))) <= sum(map(len, (s.visibility for s in everything)))
    assert all(v >= 0.9 for s in visible for v in s.visibility)
    with pytest.raises(PegasusError, match="no object named 'mug'"):
        load_bop(dataset, ["mug"])
    with pytest.raises(PegasusError, match="no object with obj_id 42"):
        load_bop(dataset, [42])


def test_augmented_crops_carry_their_keypoints_and_plain_borders(tmp_path):
    rng = np.random.default_rng(0)
    image = np.full((240, 320, 3), 40, np.uint8)
    keypoints = rng.uniform(30, [290, 210], (9, 2))
    for x, y in keypoints:
        cv2.circle(image, (int(round(x)), int(round(y))), 3, (255, 255, 255), -1)
    cv2.imwrite(str(tmp_path / "im.png"), image)
    sample = Sample(tmp_path / "im.png", np.eye(3), [keypoints], [1], [1.0])
    still = Augment(brightness=0, contrast=0, saturation=0, hue_deg=0, noise_std=0, rotation_deg=40)
    data = DopeDataset([sample], size=160, augment=still)
    for epoch in range(5):
        data.epoch = epoch
        crop, moved, M = data.item(0)
        moved = moved[0]
        inside = (moved >= 2).all(1) & (moved < 158).all(1)
        values = [crop[int(round(y)), int(round(x))].min() for x, y in moved[inside]]
        assert inside.sum() >= 3 and min(values) > 200  # each keypoint still sits on its dot
        source = cv2.warpAffine(np.full((240, 320), 255, np.uint8), M, (160, 160))
        outside = source == 0
        if outside.any():  # beyond the source image: one plain colour, never a mirrored copy
            assert len(np.unique(crop[outside].reshape(-1, 3), axis=0)) == 1
    image_t, beliefs, affinities, distance, weight = data[0]
    assert tuple(image_t.shape) == (3, 160, 160) and tuple(beliefs.shape) == (9, 20, 20)
    assert tuple(distance.shape) == tuple(weight.shape) == (1, 20, 20) and float(weight.max()) == 0.0  # no depth
    assert float(image_t.max()) <= 1.0 and float(beliefs.max()) > 0.5
    for sigma in (4.0, 8.0):  # sigma_px reaches the targets: a Gaussian's sum over the cells is 2 pi sigma^2 / 8^2
        wide, sums = DopeDataset([sample], size=160, augment=still, sigma_px=sigma), []
        for epoch in range(5):
            wide.epoch = epoch
            _, moved, _ = wide.item(0)
            clear = (moved[0] >= 3 * sigma).all(1) & (moved[0] < 160 - 3 * sigma).all(1)
            sums += list(wide[0][1].numpy()[clear].sum(axis=(1, 2)))
        assert len(sums) >= 5
        np.testing.assert_allclose(sums, 2 * np.pi * sigma**2 / 64, rtol=0.05)



@pytest.mark.parametrize("linear_light", [False, True])
def test_blur_softens_about_half_the_crops_and_moves_nothing(tmp_path, linear_light):
    image = np.zeros((240, 320, 3), np.uint8)
    image[:, 160:] = 255  # one sharp vertical edge through the instance
    keypoints = np.array([[140.0, 100.0], [180.0, 100.0], [140.0, 140.0], [180.0, 140.0]] * 2 + [[160.0, 120.0]])
    cv2.imwrite(str(tmp_path / "im.png"), image)
    sample = Sample(tmp_path / "im.png", np.eye(3), [keypoints], [1], [1.0])
    plain = dict(brightness=0, contrast=0, saturation=0, hue_deg=0, noise_std=0)  # only the blur changes pixels
    sharp = DopeDataset([sample], size=128, augment=Augment(**plain))
    soft = DopeDataset([sample], size=128, augment=Augment(**plain, blur_px=2.0, linear_light=linear_light))
    light = SRGB_TO_LINEAR if linear_light else np.arange(256.0)  # what the blur keeps: the light, or the codes

    def steepest(crop):  # the largest step between neighbouring pixels along x
        return np.abs(np.diff(crop.astype(int), axis=1)).max()

    blurred = 0
    for epoch in range(40):
        a, keys_a, M_a = sharp.item(0, epoch)
        b, keys_b, M_b = soft.item(0, epoch)
        assert np.array_equal(M_a, M_b) and np.array_equal(keys_a, keys_b)  # the same crop, the same targets
        if not np.array_equal(a, b):
            blurred += 1
            assert steepest(b) < steepest(a)
            assert abs(light[b].mean() - light[a].mean()) < 2e-3 * light[255]  # it spreads, adds or removes none
    assert 10 <= blurred <= 30  # half of 40 draws: 20 +- 3 standard deviations


def test_blur_in_linear_light_keeps_the_light_and_moves_a_dark_objects_outline_into_it():
    grey = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)[None]  # [1, 256, 3]: every code
    # sRGB's decoding against scikit-image's (the luminance Y of a grey is its linear light)
    np.testing.assert_allclose(SRGB_TO_LINEAR, color.rgb2xyz(grey)[0, :, 1], atol=1e-6)
    assert np.array_equal(blur_light(grey, 1e-3), grey)  # too narrow a blur to mix pixels: every code comes back

    image = np.full((64, 64, 3), 200, np.uint8)
    image[16:48, 16:48] = 40  # a dark square on a bright ground, its left edge at x = 15.5

    def crossing(row, level):  # where the row first falls below level (px, linear between pixels)
        i = np.flatnonzero((row[:-1] >= level) & (row[1:] < level))[0]
        return i + (row[i] - level) / (row[i] - row[i + 1])

    for sigma in (1.0, 1.5, 2.0):
        light, codes = blur_light(image, sigma), cv2.GaussianBlur(image, (0, 0), sigmaX=sigma)
        # the light is kept (to its codes' rounding); blurring the codes loses 7-15 times this much of it
        assert abs(SRGB_TO_LINEAR[light].mean() - SRGB_TO_LINEAR[image].mean()) < 1e-3
        # the codes' midpoint (120) lies where a share f of the bright ground's light is mixed in: inside the
        # square by -Phi^-1(f) sigma for a Gaussian; blurring the codes leaves it on the edge
        f = (SRGB_TO_LINEAR[120] - SRGB_TO_LINEAR[40]) / (SRGB_TO_LINEAR[200] - SRGB_TO_LINEAR[40])
        inside = crossing(light[32, :, 0].astype(float), 120) - 15.5
        assert abs(inside + norm.ppf(f) * sigma) < 0.1 and inside > 0.45
        assert abs(crossing(codes[32, :, 0].astype(float), 120) - 15.5) < 0.1


def test_negative_crops_look_away_from_the_instances_and_keep_the_targets_of_any_they_hold(tmp_path):
    image = np.full((480, 640, 3), 40, np.uint8)
    keypoints = np.array([[60.0, 60.0]] * 8 + [[60.0, 60.0]])  # one instance near the top-left corner
    keypoints[:8] += np.random.default_rng(1).uniform(-8, 8, (8, 2))
    cv2.imwrite(str(tmp_path / "im.png"), image)
    sample, empty = Sample(tmp_path / "im.png", np.eye(3), [keypoints], [1], [1.0]), Sample(tmp_path / "im.png",
                                                                                            np.eye(3))
    centres = {}
    for share in (0.0, 1.0):
        data, centres[share] = DopeDataset([sample], size=128, negatives=share, focal_px=1.0), []  # image scale 1
        for epoch in range(40):
            data.epoch = epoch
            _, moved, M = data.item(0)
            A = np.vstack([M, [0, 0, 1]])
            centres[share].append((np.linalg.inv(A) @ [63.5, 63.5, 1])[:2])  # the crop's centre in the image
            peak, x = data[0][1].numpy()[8].max(), moved[0, 8]
            if ((x >= 8) & (x < 120)).all():  # the instance is labelled whenever the crop holds it
                assert peak > 0.3
            elif ((x < -16) | (x >= 144)).any():
                assert peak < 0.01
    near = [np.linalg.norm(c - keypoints[8]) < 60 for c in centres[0.0]]  # 0.2 of the crop at scale 0.75
    far = [np.linalg.norm(c - keypoints[8]) > 150 for c in centres[1.0]]
    assert all(near) and np.mean(far) > 0.7  # random points of the image: mostly far from the instance
    data = DopeDataset([empty], size=128)
    assert data[0][1].numpy().max() == 0.0  # an image without the object: a crop with nothing to find


def test_occluders_paste_another_image_over_part_of_the_instance_and_keep_its_targets(tmp_path):
    black, white = np.zeros((400, 400, 3), np.uint8), np.full((400, 400, 3), 255, np.uint8)
    cv2.imwrite(str(tmp_path / "black.png"), black)
    cv2.imwrite(str(tmp_path / "white.png"), white)
    corners = np.array([[x, y] for x in (170.0, 230.0) for y in (180.0, 220.0)] * 2)  # a 60 x 40 px box
    keypoints = np.vstack([corners, [[200.0, 200.0]]])
    samples = [Sample(tmp_path / "black.png", np.eye(3), [keypoints], [1], [1.0]),
               Sample(tmp_path / "white.png", np.eye(3))]
    plain = Augment(brightness=0, contrast=0, saturation=0, hue_deg=0, noise_std=0)  # pixel values kept
    kept, hidden = (DopeDataset(samples, size=128, focal_px=1.0, augment=plain, occluders=share) for share in (0, 1))
    covers = []
    for epoch in range(30):
        kept.epoch = hidden.epoch = epoch
        crop0, moved0, M0 = kept.item(0)
        crop1, moved1, M1 = hidden.item(0)
        assert crop0.max() == 0 and np.array_equal(M0, M1)  # the same crop; without occluders no white pixel
        for a, b in zip(kept[0][1:], hidden[0][1:]):
            assert torch.equal(a, b)  # beliefs, affinities and distance targets untouched by the occluder
        pasted = (crop1 == 255).all(axis=2)
        assert ((crop1 == 0) | (crop1 == 255)).all() and pasted.any()  # only the other image's pixels
        x0, y0 = np.floor(moved1.min(axis=(0, 1))).astype(int)
        x1, y1 = np.ceil(moved1.max(axis=(0, 1))).astype(int)
        cover = pasted[max(y0, 0):y1, max(x0, 0):x1].mean()
        assert cover > 0  # over the instance's box
        covers.append(cover)
    assert 0.05 < np.median(covers) < 0.6  # part of the instance hidden, never all of it on the whole


def test_focal_length_policy_shows_objects_at_the_same_size_from_any_camera(tmp_path):
    # Two cameras, fx 300 and 600 px, see the same 2 cm pair of dots at 0.5 m: 12 and 24 px apart in their
    # images. With focal_px = 450 both crops show them 18 px apart; DOPE's policy (fit the shorter side)
    # shows them at different sizes.
    K = {300: np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]]),
         600: np.array([[600.0, 0, 160], [0, 600.0, 120], [0, 0, 1]])}
    spans = {}
    for fx, camera in K.items():
        gap = fx * 0.02 / 0.5
        keypoints = np.array([[160.0 - gap / 2, 120.0]] * 4 + [[160.0 + gap / 2, 120.0]] * 5)
        cv2.imwrite(str(tmp_path / f"{fx}.png"), np.zeros((240, 320, 3), np.uint8))
        sample = Sample(tmp_path / f"{fx}.png", camera, [keypoints], [1], [1.0])
        for focal in (450.0, 0.0):
            assert input_scale((240, 320), camera, 160, focal) == pytest.approx(450 / fx if focal else 160 / 240)
            _, moved, M = DopeDataset([sample], size=160, augment=Augment(enabled=False), focal_px=focal).item(0)
            spans[fx, focal] = moved[0, 8, 0] - moved[0, 0, 0]
            np.testing.assert_allclose(M[:, :2], np.eye(2) * input_scale((240, 320), camera, 160, focal))
    assert spans[300, 450.0] == pytest.approx(18.0) and spans[600, 450.0] == pytest.approx(18.0)
    assert spans[600, 0.0] == pytest.approx(2 * spans[300, 0.0])


def test_canonical_labels_of_a_symmetric_object_depend_only_on_what_the_camera_sees():
    rng = np.random.default_rng(4)
    for axis in ([0, 0, 1], [0, 1, 0], [1, 1, 0]):
        a = np.array(axis, float) / np.linalg.norm(axis)
        for _ in range(20):
            T = np.eye(4)
            T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
            T[:3, 3] = rng.uniform([-0.2, -0.2, 0.4], [0.2, 0.2, 0.9])
            canonical = canonical_pose(T, axis)
            turn = np.linalg.inv(T) @ canonical  # a rotation about the axis through the origin, nothing else
            assert np.allclose(turn[:3, 3], 0) and np.allclose(turn[:3, :3] @ a, a)
            for angle in rng.uniform(-np.pi, np.pi, 3):  # the same shape turned about its axis: same labels
                S = np.eye(4)
                S[:3, :3] = Rotation.from_rotvec(angle * a).as_matrix()
                np.testing.assert_allclose(canonical_pose(T @ S, axis), canonical, atol=1e-9)
            camera = -canonical[:3, :3].T @ canonical[:3, 3]  # in the canonical object frame
            towards = camera - (camera @ a) * a
            reference = np.eye(3)[np.argmin(np.abs(a))] - a[np.argmin(np.abs(a))] * a
            assert towards @ reference / np.linalg.norm(towards) / np.linalg.norm(reference) > 1 - 1e-9


@pytest.mark.parametrize("off_axis", [False, True])
def test_distance_targets_give_back_each_instances_depth_at_any_crop_scale(tmp_path, off_axis):
    # One camera (fx 500, fy 520) sees two instances at 0.6 and 1.1 m; every augmented crop (random scale and
    # turn) labels the cells at each centroid with a code that, read at the crop's own focal length (the
    # camera's times the crop's scale, taken from the length of M's first column), gives that depth back; with
    # off_axis, that depth times the off-axis factor of the instance's centre's ray in the frame (not the crop's).
    K = np.array([[500.0, 0, 320], [0, 520.0, 240], [0, 0, 1]])
    cv2.imwrite(str(tmp_path / "im.png"), np.zeros((480, 640, 3), np.uint8))
    centres = ((300.0, 230.0), (340.0, 250.0))
    near, far = (np.array([[x, y]] * 9, np.float64) for x, y in centres)
    sample = Sample(tmp_path / "im.png", K, [near, far], [1, 1], [1.0, 1.0], [0.6, 1.1])
    data = DopeDataset([sample], size=128, focal_px=400.0, off_axis=off_axis)
    factors = [off_axis_factor(((x - 320) / 500, (y - 240) / 520)) if off_axis else 1.0 for x, y in centres]
    for epoch in range(6):
        data.epoch = epoch
        _, moved, M = data.item(0)
        *_, code, weight = (t.numpy()[0] for t in data[0])
        focal = np.sqrt(K[0, 0] * K[1, 1]) * np.hypot(*M[:, 0])
        for (x, y), depth, factor in zip(moved[:, 8], (0.6, 1.1), factors):
            if 8 <= x < 120 and 8 <= y < 120:
                i, j = int(y // 8), int(x // 8)
                assert weight[i, j] > 0.3
                assert distance_from_code(code[i, j], focal) == pytest.approx(depth * factor, rel=1e-5)
    assert distance_from_code(distance_code(0.8, 450.0), 450.0) == pytest.approx(0.8)
    assert distance_code(0.8, 900.0) == pytest.approx(distance_code(0.4, 450.0))  # twice the focal: looks as near


@pytest.mark.parametrize("theta_deg, azimuth_deg", [(0, 0), (15, 30), (25, 200), (35, 290)])
def test_the_off_axis_factor_makes_a_ball_that_looks_as_large_read_as_far(theta_deg, azimuth_deg):
    # A ball 2 cm across whose centre lies theta off the optical axis projects to an ellipse; at depth
    # z = 0.9 m / off_axis_factor its image is as large (area) as the same ball's on the axis at 0.9 m, while at
    # z = 0.9 m itself it is 1 / cos(theta) as large. The images are measured by projecting the ball's points
    # (pinhole, f 600 px) and taking their convex hull.
    def image_area(centre):
        d = np.random.default_rng(0).normal(size=(20000, 3))
        points = centre + 0.01 * d / np.linalg.norm(d, axis=1, keepdims=True)
        return ConvexHull(600 * points[:, :2] / points[:, 2:]).volume
    t, a = np.radians(theta_deg), np.radians(azimuth_deg)
    ray = np.tan(t) * np.array([np.cos(a), np.sin(a)])
    assert float(off_axis_factor(ray)) == pytest.approx(np.sqrt(np.cos(t)))
    on_axis = image_area(np.array([0.0, 0.0, 0.9]))
    at_factor = image_area(np.r_[ray, 1.0] * 0.9 / off_axis_factor(ray))
    at_same_depth = image_area(np.r_[ray, 1.0] * 0.9)
    assert at_factor / on_axis == pytest.approx(1.0, abs=2e-3)
    assert at_same_depth / on_axis == pytest.approx(1 / np.cos(t), abs=2e-3)


def test_a_distance_map_is_read_between_the_cell_centres():
    values = np.arange(12.0).reshape(3, 4)  # cell (row i, column j) holds 4 i + j
    for x, y in np.random.default_rng(0).uniform([0, 0], [3, 2], (20, 2)):  # fractional cells inside the map
        assert read_map(values, cells_to_pixels([x, y], 8), 8) == pytest.approx(4 * y + x)
    assert read_map(values, (-40.0, -40.0), 8) == 0.0 and read_map(values, (500.0, 500.0), 8) == 11.0


@pytest.mark.parametrize("hue_deg", [6.0, 30.0])
def test_the_hue_turn_spans_its_range_and_no_more(hue_deg):
    # a saturated colour (scikit-image's HSV as the independent reference), every other jitter off
    image = np.zeros((8, 8, 3), np.uint8)
    image[:] = (200, 60, 40)
    still = Augment(brightness=0, contrast=0, saturation=0, hue_deg=hue_deg, noise_std=0)
    hue = color.rgb2hsv(image[:1, :1])[0, 0, 0] * 360
    turns = []
    for seed in range(300):
        out = jitter_colour(image, np.random.default_rng(seed), still)
        assert (out == out[0, 0]).all()  # one turn for the whole crop
        turns.append((color.rgb2hsv(out[:1, :1])[0, 0, 0] * 360 - hue + 180) % 360 - 180)
    turns = np.array(turns)
    step = 2.0 + 1.5  # OpenCV's 8-bit hue steps by 2 degrees; rounding the RGB codes moves it a little more
    assert np.abs(turns).max() <= hue_deg + step
    assert turns.min() < step - hue_deg and turns.max() > hue_deg - step  # both ways, to the ends
