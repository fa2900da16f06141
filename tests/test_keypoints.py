"""The object points a DOPE network learns (``dope_training.keypoints``): farthest-point sampling against a brute-force
reference and a hand case, a box's surface points at its corners, and a network trained on surface points (DOPE's 8
and more) carrying them into its checkpoint, its maps, its training targets and its inference's PnP."""

import json

import numpy as np
import pytest
import trimesh

from dope_training.checkpoint import load_checkpoint, target_object
from dope_training.data import canonical_pose
from dope_training.infer import DopeModel
from dope_training.keypoints import farthest_points, object_keypoints, surface_keypoints
from dope_training.targets import make_targets
from dope_training.train import TrainConfig, load_training_samples, train
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import model_boxes, read_model
from pegasus_gen.geometry.cuboid import cuboid_points, project_points
from pegasus_gen.geometry.pose_error import add_error
from pegasus_gen.io.images import read_rgb


def test_farthest_points_on_a_line_by_hand():
    points = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [10, 0, 0]], float)
    # from 0: 10 is farthest; then 3 (3 from 0, 7 from 10); then 1 and 2 are both 1 away: the lower index
    np.testing.assert_array_equal(farthest_points(points, [0, 0, 0], 3)[:, 0], [10, 3, 1])


def test_each_farthest_point_is_the_farthest_from_the_start_and_those_before_it():
    rng = np.random.default_rng(3)
    points, start = rng.normal(size=(300, 3)), rng.normal(size=3)
    chosen = farthest_points(points, start, 8)
    for k in range(8):
        before = np.vstack([start, chosen[:k]])
        gap = np.array([min(np.linalg.norm(p - q) for q in before) for p in points])  # brute force
        assert np.linalg.norm(chosen[k] - points[np.argmax(gap)]) == 0.0


def test_a_boxs_surface_keypoints_lie_on_its_faces_spread_out_from_a_corner():
    size, offset = np.array([0.10, 0.06, 0.04]), np.array([0.02, -0.01, 0.03])
    box = trimesh.creation.box(extents=size)
    box.apply_translation(offset)
    points = surface_keypoints(box, offset - size / 2, size)
    assert points.shape == (9, 3)
    np.testing.assert_allclose(points[8], offset, atol=1e-12)  # the box's centre last
    half = np.abs(points[:8] - offset)
    assert (half <= size / 2 + 1e-9).all() and (np.abs(half - size / 2) < 1e-9).any(axis=1).all()  # on a face
    corners = cuboid_points(offset - size / 2, size)[:8]
    first = np.linalg.norm(corners - points[0], axis=1)
    assert first.min() < 0.004  # the farthest from the centre: a corner (of 5,000 samples, within 4 mm)
    gaps = np.linalg.norm(points[:8, None] - points[None, :8], axis=2) + np.eye(8)
    assert gaps.min() > 0.03  # spread over the box, no two within 3 cm (random picks: a few mm)
    more = surface_keypoints(box, offset - size / 2, size, 16)
    assert more.shape == (17, 3)
    np.testing.assert_array_equal(more[:8], points[:8])  # more points add to the 8, the centre still last
    np.testing.assert_array_equal(more[16], points[8])
    assert object_keypoints(None, offset - size / 2, size).tolist() == cuboid_points(offset - size / 2, size).tolist()


@pytest.mark.parametrize("count", [8, 16])
def test_a_network_trained_on_surface_points_carries_them_into_its_targets_and_solves_pnp_with_them(
        dope_dataset, tmp_path, count):
    cfg = TrainConfig(data=[str(dope_dataset)], object="noodle_cup_red", out=str(tmp_path / "run"), size=64,
                      batch_size=2, epochs=1, loader_workers=0, device="cpu", keypoints="surface",
                      surface_points=count, min_visibility=0.0)
    obj_id = 1
    expected = surface_keypoints(read_model(dope_dataset, obj_id), *model_boxes(dope_dataset)[obj_id], count)
    assert expected.shape == (count + 1, 3)
    assert not np.allclose(expected[:8], cuboid_points(*model_boxes(dope_dataset)[obj_id])[:8])

    samples, target = load_training_samples(cfg)
    np.testing.assert_allclose(target.keypoints, expected)
    scene = dope_dataset / "train_pbr" / "000000"
    gt, cameras = (json.loads((scene / f).read_text()) for f in ("scene_gt.json", "scene_camera.json"))
    K = np.array(cameras["0"]["cam_K"]).reshape(3, 3)
    poses = []
    for g in gt["0"]:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = np.reshape(g["cam_R_m2c"], (3, 3)), np.array(g["cam_t_m2c"]) / 1000
        poses.append(T)
    first = next(s for s in samples if s.image.name == "000000.jpg")
    assert len(first.keypoints) == len(poses)
    for keypoints, T in zip(first.keypoints, poses):  # the training targets: the surface points' projections
        labelled = T if target.symmetry_axis is None else canonical_pose(T, target.symmetry_axis)
        np.testing.assert_allclose(keypoints, project_points(expected, labelled, K), atol=1e-9)

    run = train(cfg)
    np.testing.assert_allclose(load_checkpoint(run / "last.pt")["object"]["keypoints"], expected)
    model = DopeModel(run / "last.pt")
    np.testing.assert_allclose(model.points, expected)
    beliefs, affinities, *_ = model.maps(read_rgb(scene / "rgb" / "000000.jpg"), K)
    assert (len(beliefs), len(affinities)) == (count + 1, 2 * count)  # a map per point, two affinities per corner

    # Maps that mark the surface points' true projections exactly: inference must solve PnP with the same points
    image = read_rgb(scene / "rgb" / "000000.jpg")
    h, w = image.shape[:2]
    projected = np.array([project_points(expected, T, K) for T in poses])
    beliefs, affinities = make_targets(projected, np.ones(projected.shape[:2], bool), h, w)
    model.maps = lambda image, K: (beliefs, affinities, None, (1.0, 1.0))
    inside = [T for T, uv in zip(poses, projected[:, -1]) if 16 <= uv[0] <= w - 16 and 16 <= uv[1] <= h - 16]
    assert inside  # (the others' centres lie at or beyond the image's edge, where the decoder clips them)
    surface = np.asarray(model.object.surface_points)
    found = model.estimate(image, K)
    for T in inside:
        assert min(add_error(surface, p.T, T) for p in found) < 0.002  # m, of a 9 cm cup
    model.points = np.vstack([expected[:-1][::-1], expected[-1:]])  # the points in another order misread them
    misread = model.estimate(image, K)
    for T in inside:
        assert min(add_error(surface, p.T, T) for p in misread) > 0.01


def test_a_point_count_the_network_does_not_have_is_refused():
    obj = {"obj_id": 1, "name": "cup", "bbox_min": [-0.05] * 3, "bbox_size": [0.1] * 3}
    points = np.random.default_rng(0).normal(size=(13, 3)).tolist()
    assert len(target_object({**obj, "keypoints": points}, "model", 12).keypoints) == 13
    with pytest.raises(PegasusError, match=r"not \[9, 3\].*finds 8 points"):
        target_object({**obj, "keypoints": points}, "model")
    with pytest.raises(PegasusError, match="not the cuboid's 8"):
        target_object(obj, "model", 12)
    with pytest.raises(ValueError, match="surface_points needs keypoints surface"):
        TrainConfig(data=["d"], object="cup", surface_points=12)


def test_surface_keypoints_need_a_bop_model(tmp_path):
    (tmp_path / "ndds").mkdir()
    cfg = TrainConfig(data=[str(tmp_path / "ndds")], object="cup", object_size=(0.1, 0.1, 0.1), keypoints="surface")
    with pytest.raises(PegasusError, match="labels the cuboid only"):
        load_training_samples(cfg)
