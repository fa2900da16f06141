"""DOPE core: the cuboid's keypoint order, decoding belief/affinity maps back to the keypoints they were
drawn from, PnP from exact, noisy and incomplete keypoints, VGG19 weights from the hub cache, and the
ONNX export against torch. (Network shapes, size and loss: test_dope_model.py; targets: test_dope_data.py.)"""

import json

import cv2
import numpy as np
import onnx
import pytest
import torch

from dope_training.decode import CANDIDATES, find_keypoints, find_peaks
from dope_training.export import check_parity, export_onnx
from dope_training.model import DopeNetwork, ModelConfig, build_model, load_vgg19_weights
from dope_training.pnp import solve_pose, solve_pose_consensus
from dope_training.targets import make_targets
from pegasus_gen.geometry.cuboid import cuboid_points, project_points

K = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])  # 640 x 480
BOX_MIN, BOX_SIZE = np.array([-0.04, -0.03, -0.06]), np.array([0.08, 0.06, 0.10])  # off-centre in z
CUBOID = cuboid_points(BOX_MIN, BOX_SIZE)


def random_pose(rng: np.random.Generator, x=(-0.15, 0.15), depth=(0.4, 0.9)) -> np.ndarray:
    """T_cam_obj [4, 4]: a uniform-angle random rotation, the object in front of the camera."""
    axis = rng.normal(size=3)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(axis / np.linalg.norm(axis) * rng.uniform(0, np.pi))[0]
    T[:3, 3] = [rng.uniform(*x), rng.uniform(-0.1, 0.1), rng.uniform(*depth)]
    return T


def pose_error(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Translation error (m) and rotation error (degrees)."""
    cos = (np.trace(T[:3, :3].T @ truth[:3, :3]) - 1) / 2
    return float(np.linalg.norm(T[:3, 3] - truth[:3, 3])), float(np.degrees(np.arccos(np.clip(cos, -1, 1))))


def test_cuboid_follows_dopes_keypoint_order_and_projects_like_opencv():
    signs = [(1, -1, 1), (-1, -1, 1), (-1, 1, 1), (1, 1, 1), (1, -1, -1), (-1, -1, -1), (-1, 1, -1), (1, 1, -1)]
    centre = BOX_MIN + BOX_SIZE / 2
    np.testing.assert_allclose(CUBOID[8], [0, 0, -0.01])
    for k, sign in enumerate(signs):
        np.testing.assert_allclose(CUBOID[k], centre + np.array(sign) * BOX_SIZE / 2)
    assert CUBOID.min(0) == pytest.approx(BOX_MIN) and CUBOID.max(0) == pytest.approx(BOX_MIN + BOX_SIZE)
    T = random_pose(np.random.default_rng(0))
    rvec = cv2.Rodrigues(T[:3, :3])[0]
    np.testing.assert_allclose(project_points(CUBOID, T, K),
                               cv2.projectPoints(CUBOID, rvec, T[:3, 3], K, None)[0].reshape(-1, 2), atol=1e-9)
    on_axis = np.eye(4)
    on_axis[2, 3] = 1.0
    np.testing.assert_allclose(project_points(np.zeros((1, 3)), on_axis, K), [[319.5, 239.5]])


@pytest.mark.parametrize("instances", [1, 2])
def test_decoding_the_targets_gives_back_the_keypoints_and_their_instances(instances):
    rng = np.random.default_rng(instances)
    Kc = np.array([[250.0, 0, 99.5], [0, 250.0, 99.5], [0, 0, 1]])  # 200 x 200 input, 25 x 25 maps
    for _ in range(5):
        # two instances: same-kind keypoints > 5 cells apart (closer ones pull each other's sub-pixel position)
        xs = [(-0.01, 0.01)] if instances == 1 else [(-0.14, -0.12), (0.12, 0.14)]
        keypoints = np.stack([project_points(CUBOID, random_pose(rng, x, (0.6, 0.7)), Kc) for x in xs])
        beliefs, affinities = make_targets(keypoints, np.ones(keypoints.shape[:2], bool), 200, 200)
        detections = find_keypoints(beliefs, affinities)
        assert len(detections) == instances
        for truth in keypoints:
            found = min(detections, key=lambda d: np.linalg.norm(d.keypoints[8] - truth[8]))
            assert np.linalg.norm(found.keypoints - truth, axis=1).max() < 0.5  # px, every corner joined
            assert (found.scores > np.exp(-1) - 1e-6).all()  # the peak cell is at most half a cell off in x and y
        without_affinities = find_keypoints(beliefs, np.zeros_like(affinities))
        assert all(np.isnan(d.keypoints[:8]).all() and np.isfinite(d.keypoints[8]).all() for d in without_affinities)
    assert find_keypoints(np.zeros((9, 25, 25)), np.zeros((16, 25, 25))) == []


def test_a_detection_threshold_keeps_the_corners_of_the_instances_it_keeps_and_scores_them_with_the_centroid():
    rng = np.random.default_rng(4)
    Kc = np.array([[250.0, 0, 99.5], [0, 250.0, 99.5], [0, 0, 1]])
    keypoints = project_points(CUBOID, random_pose(rng, (-0.01, 0.01), (0.6, 0.7)), Kc)[None]
    beliefs, affinities = make_targets(keypoints, np.ones((1, 9), bool), 200, 200)
    beliefs[:8] *= 0.3  # weak corners under a confident centroid, as a trained network's often are
    beliefs[8] *= 0.8
    (alone,) = find_keypoints(beliefs, affinities, min_score=0.1)
    score = np.sqrt(alone.scores[8] * alone.scores[:8].mean())  # the geometric mean of centroid and corners
    assert alone.score == pytest.approx(score) and 0.3 < score < 0.45
    for threshold in (0.1, 0.25, score - 0.01):
        (found,) = find_keypoints(beliefs, affinities, min_score=threshold)
        assert np.isfinite(found.keypoints).all() and found.scores[8] > 0.7  # all nine keypoints still there
    assert find_keypoints(beliefs, affinities, min_score=score + 0.01) == []  # the score decides, not the centroid
    beliefs[:4] = 0.0  # half the corners gone: the same centroid scores lower
    (half,) = find_keypoints(beliefs, affinities, min_score=0.1)
    assert half.score == pytest.approx(np.sqrt(alone.scores[8] * alone.scores[4:8].sum() / 8))  # missing count as 0
    assert np.isnan(half.keypoints[:4]).all() and half.score < score / np.sqrt(1.5)


@pytest.mark.parametrize("sigma_px", [4.0, 8.0])
def test_sub_cell_positions_are_exact_on_gaussian_peaks_and_not_pulled_by_a_neighbour(sigma_px):
    """The log-parabola fit is exact on a Gaussian peak of any width, also with a same-kind peak 3 (0.5-cell
    Gaussians) or 5 (1-cell ones) cells away; a belief-weighted 5x5 mean was off by up to 0.26 px alone and
    pulled by up to 7 px by such a neighbour."""
    rng = np.random.default_rng(int(sigma_px))
    for _ in range(100):
        point = rng.uniform(72, 128, 2)  # both peaks 2 or more cells inside the 25 x 25 map
        neighbour = point + [rng.choice([-1, 1]) * (sigma_px * 6 + rng.uniform(0, 4)), rng.uniform(-4, 4)]
        beliefs, _ = make_targets(np.array([[point] * 9, [neighbour] * 9]), np.ones((2, 9), bool), 200, 200,
                                  sigma_px=sigma_px)
        found, _, _ = find_peaks(beliefs[0])
        assert len(found) == 2
        assert np.linalg.norm(found - point, axis=1).min() < 0.1  # px
        assert np.linalg.norm(found - neighbour, axis=1).min() < 0.1


def test_pnp_recovers_poses_from_exact_keypoints_and_holds_up_under_noise_and_missing_corners():
    rng = np.random.default_rng(0)
    for _ in range(10):
        truth = random_pose(rng)
        T, error_px = solve_pose(project_points(CUBOID, truth, K), CUBOID, K)
        dt, dr = pose_error(T, truth)
        assert dt < 1e-3 and dr < 0.1 and error_px < 1e-6
    # 2 px (std per axis) noise on all 9 keypoints, or on 7 with two corners missing, over 50 poses at 0.4-0.9 m;
    # measured over seeds 0-5: median 4.4-6.0 mm / 1.3-1.6 deg (9), 6.4-7.9 mm / 1.6-2.1 deg (7), worst 7.2 deg
    for missing, (median_mm, median_deg, worst_deg) in ((0, (10, 2.5, 8)), (2, (12, 3.0, 10))):
        errors = []
        for _ in range(50):
            truth = random_pose(rng)
            keypoints = project_points(CUBOID, truth, K) + rng.normal(0, 2.0, (9, 2))
            keypoints[rng.choice(8, missing, replace=False)] = np.nan
            T, error_px = solve_pose(keypoints, CUBOID, K)
            errors.append((*pose_error(T, truth), error_px))
        dt, dr, px = np.array(errors).T
        assert np.median(dt) < median_mm / 1000 and np.median(dr) < median_deg and dr.max() < worst_deg
        assert 1.0 < np.median(px) < 3.0  # the residual is the noise, not a wrong pose


def test_pnp_on_keypoints_that_all_coincide_is_no_pose_not_an_error():
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    assert solve_pose(np.tile([[200.0, 150.0]], (9, 1)), CUBOID, K) is None  # OpenCV 5's SQPnP asserts here


def test_pnp_drops_keypoints_that_do_not_fit_the_others():
    """Two of nine keypoints moved by 40-60 % of the box's projected size (peaks of something else joined to the
    instance): the pose is the one solved from the seven others alone."""
    rng = np.random.default_rng(2)
    for _ in range(30):
        truth = random_pose(rng)
        keypoints = project_points(CUBOID, truth, K) + rng.normal(0, 1.0, (9, 2))
        size = np.linalg.norm(np.ptp(keypoints[:8], axis=0))
        wrong = rng.choice(9, 2, replace=False)
        directions = rng.normal(size=(2, 2))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        keypoints[wrong] += directions * rng.uniform(0.4, 0.6, (2, 1)) * size
        T, error_px = solve_pose(keypoints, CUBOID, K)
        seven = keypoints.copy()
        seven[wrong] = np.nan
        reference, reference_px = solve_pose(seven, CUBOID, K)
        dt, dr = pose_error(T, reference)
        assert dt < 1e-6 and dr < 1e-4 and error_px == pytest.approx(reference_px)


def look_alike(T: np.ndarray) -> np.ndarray:
    """T [4, 4] turned by 180 degrees about the object's z axis through its box centre: the same box seen."""
    centre = BOX_MIN + BOX_SIZE / 2
    flip = np.eye(4)
    flip[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    flip[:3, 3] = 2 * centre * [1, 1, 0]  # x -> 2c - x about the centre, in x and y
    return T @ flip


def test_the_consensus_takes_the_weaker_peaks_where_most_corners_joined_a_look_alike():
    """Five of eight corners joined on the box turned half round (its look-alike: outlier dropping keeps them, they
    are the majority); each of them has the right peak as a weaker candidate: the consensus poses the object as it
    is (as PnP of the right peaks: within a degree), where PnP on the corners as joined is half a turn off."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        truth = random_pose(rng)
        right = project_points(CUBOID, truth, K) + rng.normal(0, 0.3, (9, 2))
        turned = project_points(CUBOID, look_alike(truth), K)
        joined = right.copy()
        wrong = rng.choice(8, 5, replace=False)
        joined[wrong] = turned[wrong]
        candidates = [np.array([[*joined[k], 0.6], [*right[k], 0.4]]) if k in wrong else np.array([[*right[k], 0.6]])
                      for k in range(8)]
        T, error_px, picked = solve_pose_consensus(joined, candidates, CUBOID, K, tau_px=4.0)
        np.testing.assert_array_equal(picked, right)  # every corner on its right peak
        np.testing.assert_allclose(T, solve_pose(right, CUBOID, K)[0], atol=1e-9)
        assert pose_error(T, truth)[1] < 1.0 and error_px < 1.0
        assert pose_error(solve_pose(joined, CUBOID, K)[0], truth)[1] > 30
        # the same answer for the same input: the hypotheses' draws are seeded
        np.testing.assert_array_equal(solve_pose_consensus(joined, candidates, CUBOID, K, tau_px=4.0)[0], T)


def test_the_consensus_without_other_candidates_is_pnp_of_the_corners_as_joined():
    rng = np.random.default_rng(6)
    for _ in range(10):
        keypoints = project_points(CUBOID, random_pose(rng), K) + rng.normal(0, 1.0, (9, 2))
        keypoints[rng.choice(8, 2, replace=False)] = np.nan  # corners not found have no candidate
        candidates = [np.array([[*p, 0.5]]) if np.isfinite(p).all() else np.zeros((0, 3)) for p in keypoints[:8]]
        T, error_px, picked = solve_pose_consensus(keypoints, candidates, CUBOID, K, tau_px=4.0)
        reference, reference_px = solve_pose(keypoints, CUBOID, K)
        np.testing.assert_array_equal(T, reference)
        assert error_px == reference_px and picked is keypoints
    keypoints[:8] = np.nan
    assert solve_pose_consensus(keypoints, [np.zeros((0, 3))] * 8, CUBOID, K, tau_px=4.0) is None


def test_each_instance_keeps_its_corners_other_peaks_within_reach_as_candidates():
    """An instance's corner 0 has a second, weaker peak of its kind beside the object and a third far away: the
    first is its candidate after the corner as joined, the far one is not; the other corners have theirs alone."""
    Kc = np.array([[250.0, 0, 99.5], [0, 250.0, 99.5], [0, 0, 1]])  # 200 x 200 input, 25 x 25 maps
    keypoints = project_points(CUBOID, random_pose(np.random.default_rng(7), (-0.01, 0.01), (0.6, 0.7)), Kc)
    spread = np.linalg.norm(keypoints[:8] - keypoints[8], axis=1).max()
    beside = keypoints[8] + (keypoints[8] - keypoints[0])  # corner 0 mirrored through the centroid
    far = keypoints[8] + [0, 3 * spread] if keypoints[8, 1] < 100 else keypoints[8] - [0, 3 * spread]
    beliefs, affinities = make_targets(keypoints[None], np.ones((1, 9), bool), 200, 200)
    extra = np.zeros((2, 9, 2))
    extra[:, 0] = beside, far
    others = make_targets(extra, np.eye(9, dtype=bool)[[0, 0]], 200, 200)[0][0]
    beliefs[0] = np.maximum(beliefs[0], 0.5 * others)  # two weaker peaks of corner 0's kind
    (found,) = find_keypoints(beliefs, affinities)
    first = found.candidates[0]
    assert len(first) == 2 and np.linalg.norm(first[0, :2] - keypoints[0]) < 0.5  # joined first
    assert np.linalg.norm(first[1, :2] - beside) < 0.5 and first[1, 2] < first[0, 2]
    for k in range(1, 8):
        assert len(found.candidates[k]) == 1 and np.allclose(found.candidates[k][0, :2], found.keypoints[k])
    assert all(len(c) <= CANDIDATES for c in found.candidates)


def test_pnp_refuses_too_few_keypoints_and_poses_behind_the_camera(monkeypatch):
    truth = random_pose(np.random.default_rng(1))
    keypoints = project_points(CUBOID, truth, K)
    keypoints[[0, 2, 4, 6, 8]] = np.nan
    assert solve_pose(keypoints, CUBOID, K) is None  # 4 points: below the rule's 5
    keypoints[8] = project_points(CUBOID[8:], truth, K)[0]
    assert solve_pose(keypoints, CUBOID, K) is not None
    monkeypatch.setattr(cv2, "solvePnPRefineLM", lambda obj, img, K, dist, rvec, tvec: (rvec, -tvec))
    assert solve_pose(keypoints, CUBOID, K) is None  # a solver's pose behind the camera is not a pose


def test_vgg19_weights_come_from_the_hub_cache_and_never_from_the_network(tmp_path, monkeypatch):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path))
    model = DopeNetwork(ModelConfig.of("full"))
    assert not load_vgg19_weights(model)  # empty cache: nothing loaded, nothing downloaded
    state = {f"features.{k}": torch.full_like(v, 0.5) for k, v in model.features.state_dict().items()}
    (tmp_path / "checkpoints").mkdir()
    torch.save(state, tmp_path / "checkpoints" / "vgg19-dcbb9e9d.pth")
    assert load_vgg19_weights(model)
    assert all(bool((p == 0.5).all()) for p in model.features.parameters())
    with pytest.raises(ValueError, match="light"):
        load_vgg19_weights(DopeNetwork(ModelConfig.of("light")))


def test_onnx_export_matches_torch_at_two_sizes_and_carries_its_normalisation(tmp_path):
    torch.manual_seed(0)
    model = DopeNetwork(ModelConfig.of("light"))
    path = export_onnx(model, tmp_path / "dope.onnx")
    assert [p.name for p in tmp_path.iterdir()] == ["dope.onnx"] and model.training
    assert check_parity(model, path, [(2, 64, 64), (2, 48, 96)]) < 1e-4
    graph = onnx.load(path)
    meta = {p.key: p.value for p in graph.metadata_props}
    assert meta["variant"] == "light" and meta["stride"] == "8" and "0..1" in meta["input"]
    assert json.loads(meta["mean"]) == pytest.approx([0.485, 0.456, 0.406])
    assert json.loads(meta["std"]) == pytest.approx([0.229, 0.224, 0.225])
    assert [o.name for o in graph.graph.output] == ["beliefs", "affinities"]
    assert build_model(json.loads(meta["config"])).config == model.config
