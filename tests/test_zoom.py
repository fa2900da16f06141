"""The zoomed second look (dope_training.zoom): its crop centres the estimate with the object's diameter
object_px long, its offsets and the move they give are inverses, the drawn estimates spread as configured, a
position network keeps the rotation and a rotation network turns it, a network trained on a few frames brings
estimates back, occluders hide part of the object in its training crops and nothing else, DOPE's poses pass
through it with their rotation kept, the colour and normals views render the
model's colours and surface where its silhouette lies, and bad input is refused."""

from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from dope_training import zoom_train
from dope_training.infer import DopeModel
from dope_training.looks import load
from dope_training.zoom import (
    OFFSET_STD,
    POSITION,
    WITH_ROTATION,
    ZoomGeometry,
    ZoomNet,
    ZoomRefiner,
    moved,
    offsets,
    save,
    surfaced,
    zoom_input,
)
from dope_training.zoom_config import ZoomConfig
from dope_training.zoom_train import drawn_estimate, object_geometry, occluded, train_zoom
from pegasus_gen.cli.main import main
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import bop_frames
from pegasus_gen.io.images import read_rgb

K = np.array([[570.0, 0, 320], [0, 575.0, 240], [0, 0, 1]])


def _ball(radius: float = 0.05, crop_px: int = 128, object_px: float = 88.0) -> ZoomGeometry:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    return ZoomGeometry(np.asarray(mesh.vertices), np.asarray(mesh.faces), np.zeros(3), 2 * radius, crop_px,
                        object_px)


def _pose(seed: int, centre=None) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = centre if centre is not None else [rng.uniform(-0.2, 0.2), rng.uniform(-0.15, 0.15),
                                                   rng.uniform(0.5, 1.3)]
    return T


def test_the_crop_centres_the_estimate_and_the_diameter_spans_object_px():
    g = _ball()
    for seed in range(3):
        T = _pose(seed, centre=[0.0, 0.0, 0.6 + 0.3 * seed])  # on the optical axis: a ball's outline is a circle
        uv = K[:2, :2] @ (T[:2, 3] / T[2, 3]) + K[:2, 2]
        ys, xs = np.mgrid[0:480, 0:640]
        blob = np.exp(-((xs - uv[0]) ** 2 + (ys - uv[1]) ** 2) / (2 * 6.0 ** 2))
        image = np.repeat(np.rint(255 * blob)[..., None], 3, axis=2).astype(np.uint8)
        crop, view, _ = zoom_input(image, T, K, g)
        assert view.shape == (g.crop_px, g.crop_px, 1)
        silhouette = view[..., 0]
        middle = (g.crop_px - 1) / 2
        weights = crop[..., 0].astype(float)
        cy, cx = (np.mgrid[0:g.crop_px, 0:g.crop_px] * weights).reshape(2, -1).sum(1) / weights.sum()
        assert abs(cx - middle) < 0.1 and abs(cy - middle) < 0.1  # the image's point there lands in the middle
        cover = silhouette / 255.0
        sy, sx = (np.mgrid[0:g.crop_px, 0:g.crop_px] * cover).reshape(2, -1).sum(1) / cover.sum()
        assert abs(sx - middle) < 0.05 and abs(sy - middle) < 0.05
        # the ball's outline: a circle object_px across at fx's scale (fy 1 % longer stretches it 1 % vertically),
        # and z^2 / (z^2 - r^2) larger in area as a ball seen from z looks (the filled triangles' edges add 0.4 %)
        z, r = T[2, 3], g.diameter / 2
        area = np.pi * (g.object_px / 2) ** 2 * K[1, 1] / K[0, 0] * z ** 2 / (z ** 2 - r ** 2)
        assert cover.sum() == pytest.approx(area, rel=0.01)


def test_offsets_and_the_move_they_give_are_inverse_with_or_without_the_turn():
    cfg = ZoomConfig(data=["x"], object="1", rotation_std_deg=30.0)
    g = replace(_ball(), centre=np.array([0.01, -0.02, 0.03]))  # the model's box centre off its origin
    rng = np.random.default_rng(1)
    for seed in range(20):
        truth = _pose(seed)
        estimate = drawn_estimate(truth, K, g, cfg, rng)
        off = offsets(truth, estimate, K, g)  # in float32: a micrometre, a microradian
        centre = truth[:3, :3] @ g.centre + truth[:3, 3]
        back = moved(estimate, K, g, off[:3])  # the position alone: the rotation kept
        np.testing.assert_allclose(back[:3, :3] @ g.centre + back[:3, 3], centre, atol=1e-6)
        np.testing.assert_array_equal(back[:3, :3], estimate[:3, :3])
        back = moved(estimate, K, g, off)  # with the turn: the truth itself, turned about the same centre
        np.testing.assert_allclose(back, truth, atol=1e-6)
        # the turn is the rotation between the two, as an angle about an axis (scipy's rotation vector)
        angle = np.degrees(np.arccos(np.clip((np.trace(truth[:3, :3] @ estimate[:3, :3].T) - 1) / 2, -1, 1)))
        assert np.degrees(np.linalg.norm(off[3:])) == pytest.approx(angle, abs=1e-3)
        np.testing.assert_allclose(offsets(truth, truth, K, g), 0.0, atol=1e-6)


def test_the_drawn_estimates_spread_as_configured():
    cfg = ZoomConfig(data=["x"], object="1", centre_std=0.03, distance_std=0.05, rotation_std_deg=10.0)
    g = _ball()
    rng = np.random.default_rng(2)
    truths = [_pose(seed) for seed in range(2000)]
    drawn = [drawn_estimate(T, K, g, cfg, rng) for T in truths]
    off = np.array([offsets(T, E, K, g) for T, E in zip(truths, drawn)])
    # the crop's units: the estimate's centre aside as a share of the diameter's pixels, log distance (clipped at 3 std)
    assert np.std(off[:, :2]) == pytest.approx(cfg.centre_std, rel=0.08)
    assert np.std(off[:, 2]) == pytest.approx(cfg.distance_std, rel=0.08) and np.abs(off[:, 2]).max() <= 0.15 + 1e-6
    turns = [np.degrees(Rotation.from_matrix(E[:3, :3] @ T[:3, :3].T).magnitude()) for T, E in zip(truths, drawn)]
    assert np.median(turns) == pytest.approx(0.674 * cfg.rotation_std_deg, rel=0.08)  # |N(0, std)|'s median


def test_an_occluder_pastes_the_other_crop_moved_by_half_over_part_of_the_object_and_nothing_else():
    g = _ball(crop_px=96, object_px=66.0)
    rng = np.random.default_rng(0)
    crop, view, _ = zoom_input(rng.integers(0, 256, (480, 640, 3), dtype=np.uint8), _pose(0), K, g)
    other = rng.integers(0, 256, crop.shape, dtype=np.uint8)
    moved_other = np.roll(other, (48, 48), axis=(0, 1))
    silhouette = view[..., 0] > 127
    ys, xs = np.nonzero(silhouette)
    hidden = []
    for seed in range(300):
        out = occluded(crop, view, other, np.random.default_rng(seed))
        changed = (out != crop).any(axis=-1)
        np.testing.assert_array_equal(out[changed], moved_other[changed])  # the other crop's pixels, moved by half
        where = np.nonzero(changed)
        # the cut-out lies on the silhouette's box grown at most twice: never in a far corner (or off the crop)
        assert not changed.any() or (np.abs(where[0].mean() - ys.mean()) < np.ptp(ys)
                                     and np.abs(where[1].mean() - xs.mean()) < np.ptp(xs))
        hidden.append((changed & silhouette).sum() / silhouette.sum())
    # from none of the object to most of it (measured: median 0.13, 90th percentile 0.48, largest 0.94)
    assert 0.05 < np.median(hidden) < 0.3 and np.percentile(hidden, 90) > 0.3 and max(hidden) > 0.7
    assert np.mean(np.array(hidden) == 0) < 0.25


def test_train_zoom_occludes_the_share_of_crops_it_is_asked_to(dope_dataset, tmp_path, monkeypatch):
    calls = []

    def counted(crop, view, other, rng):
        calls.append(crop.shape)
        return occluded(crop, view, other, rng)

    monkeypatch.setattr(zoom_train, "occluded", counted)
    cfg = dict(data=[str(dope_dataset)], object="noodle_cup_red", epochs=1, per_instance=8, batch_size=8,
               crop_px=64, object_px=44.0, backgrounds=0.0, device="cpu", seed=0)
    train_zoom(ZoomConfig(**cfg, out=str(tmp_path / "none.pt")))
    assert calls == []  # the default hides nothing
    train_zoom(ZoomConfig(**cfg, occluders=1.0, out=str(tmp_path / "all.pt")))
    crops = torch.load(tmp_path / "all.pt", weights_only=True)["config"]["samples"]
    assert len(calls) == crops // 8 * 8 and set(calls) == {(64, 64, 3)}  # every crop of every batch


def test_a_pose_reaching_behind_the_camera_plane_stays_where_it_is():
    refiner = ZoomRefiner(ZoomNet(64, pretrained=False), _ball(crop_px=64, object_px=44.0), 1, "ball",
                          torch.device("cpu"))
    image = np.zeros((480, 640, 3), np.uint8)
    for z in (0.03, -0.5):  # the ball's near side at or behind the camera plane; the ball behind the camera
        T = _pose(0, centre=[0.0, 0.0, z])
        np.testing.assert_array_equal(refiner.refine(image, K, T), T)
    T = _pose(0, centre=[0.0, 0.0, 0.5])
    assert not np.array_equal(refiner.refine(image, K, T), T)  # in front of it: moved (by an untrained network)


def test_a_position_network_keeps_the_rotation_and_a_rotation_network_turns_it():
    image = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    T = _pose(0, centre=[0.02, -0.01, 0.6])
    for outputs, turned in ((POSITION, False), (WITH_ROTATION, True)):
        torch.manual_seed(0)  # untrained networks: their outputs are small but not zero
        refiner = ZoomRefiner(ZoomNet(64, outputs, pretrained=False), _ball(crop_px=64, object_px=44.0), 1, "ball",
                              torch.device("cpu"))
        out = refiner.refine(image, K, T)
        assert not np.allclose(out[:3, 3], T[:3, 3])
        assert np.allclose(out[:3, :3], T[:3, :3], atol=1e-12) != turned
    with pytest.raises(PegasusError, match="outputs"):
        ZoomNet(64, 4, pretrained=False)


def _halves(g: ZoomGeometry) -> ZoomGeometry:
    """The ball red where its model x > 0, blue elsewhere."""
    return surfaced(g, np.where(g.vertices[:, :1] > 0, [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]]))


def test_the_colour_view_shows_the_models_colours_where_its_silhouette_lies_and_turns_with_the_estimate():
    g = _halves(_ball())
    image = np.zeros((480, 640, 3), np.uint8)
    T = np.eye(4)
    T[:3, 3] = [0.03, -0.02, 0.7]
    _, view, _ = zoom_input(image, T, K, g, "colour")
    assert view.shape == (g.crop_px, g.crop_px, 4)
    cover, colour = view[..., 0] / 255.0, view[..., 1:] / 255.0
    # the colour lies where the silhouette does: no colour off the model, the colours' sum there within the
    # shading's range (ambient 0.35 at the rim to 1 facing the camera) times coverage
    total = colour.sum(-1)
    assert total[cover == 0].max() <= 1 / 255 and (total[cover == 1] >= 0.35 - 0.02).all()
    middle = g.crop_px // 2
    red, blue = colour[middle, middle + 20], colour[middle, middle - 20]  # model x > 0 lies right in the image
    assert red[0] > 0.8 and red[2] < 0.05 and blue[2] > 0.8 and blue[0] < 0.05, (red, blue)
    # facing the camera squarely at the middle, towards the rim the faces turn away and darken
    assert colour[middle, middle + 2].sum() > 0.97 and colour[middle, middle + 40].sum() < 0.8
    T[:3, :3] = Rotation.from_euler("z", 180, degrees=True).as_matrix()  # turned half about the view axis
    _, turned, _ = zoom_input(image, T, K, g, "colour")
    assert turned[middle, middle + 20, 3] > 200 and turned[middle, middle - 20, 1] > 200  # the halves swap
    np.testing.assert_allclose(turned[..., 0], view[..., 0], atol=1)  # a ball's silhouette: unchanged
    with pytest.raises(PegasusError, match="vertex colours"):
        zoom_input(image, T, K, _ball(), "colour")
    with pytest.raises(PegasusError, match="view"):
        zoom_input(image, T, K, g, "depth")


def test_the_normals_view_shows_the_models_surface_facing_the_camera_whatever_its_faces_winding():
    image = np.zeros((480, 640, 3), np.uint8)
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 0.7]
    g = surfaced(_ball())
    _, view, _ = zoom_input(image, T, K, g, "normals")
    assert view.shape == (g.crop_px, g.crop_px, 4)
    cover, n = view[..., 0] / 255.0, view[..., 1:] / 255.0 * 2 - 1  # back to the normals, times coverage
    middle = g.crop_px // 2
    assert (view[cover == 0, 1:] == 0).all()  # nothing off the model
    # a ball's normal is its point's direction from the centre: towards the camera at the middle, sideways at the
    # rim (image x right is camera x; the ball's rim lies 44 px from the middle)
    np.testing.assert_allclose(n[middle, middle], [0, 0, -1], atol=0.05)
    right, below = n[middle, middle + 40], n[middle + 40, middle]
    assert right[0] > 0.8 and abs(right[1]) < 0.1 and below[1] > 0.8 and abs(below[0]) < 0.1, (right, below)
    inside = cover == 1
    np.testing.assert_allclose(np.linalg.norm(n[inside], axis=-1), 1, atol=0.05)  # unit normals
    # the same model with every face wound the other way: the same view
    flipped = surfaced(replace(g, faces=g.faces[:, ::-1].copy(), raycaster=None))
    _, again, _ = zoom_input(image, T, K, flipped, "normals")
    np.testing.assert_array_equal(again, view)
    # a box's face seen squarely, then turned 30 degrees about the camera's y: its normal turns with it
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    cube = surfaced(ZoomGeometry(np.asarray(box.vertices), np.asarray(box.faces), np.zeros(3), 0.173, 128, 88.0))
    _, square, _ = zoom_input(image, T, K, cube, "normals")
    np.testing.assert_allclose(square[middle, middle, 1:] / 255.0 * 2 - 1, [0, 0, -1], atol=0.02)
    T[:3, :3] = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    _, turned, _ = zoom_input(image, T, K, cube, "normals")
    np.testing.assert_allclose(turned[middle, middle, 1:] / 255.0 * 2 - 1,
                               [-np.sin(np.radians(30)), 0, -np.cos(np.radians(30))], atol=0.02)
    with pytest.raises(PegasusError, match="ray caster"):
        zoom_input(image, T, K, _ball(), "normals")


def test_a_normals_view_network_reads_seven_channels_and_its_checkpoint_renders_the_view(tmp_path):
    g = surfaced(_ball(crop_px=64, object_px=44.0))
    net = ZoomNet(64, WITH_ROTATION, pretrained=False, view="normals")
    assert net.trunk.stem[1].in_channels == 7
    save(tmp_path / "z.pt", net, g, 1, "ball", {})
    refiner = load(tmp_path / "z.pt")
    assert refiner.net.view == "normals" and refiner.geometry.colours is None
    image = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    T = _pose(0, centre=[0.0, 0.0, 0.6])
    net.eval()
    crop, view, _ = zoom_input(image, T, K, g, "normals")
    with torch.no_grad():  # the loaded network, with its own ray caster, gives what the saved one gave
        expected = net(torch.from_numpy(np.concatenate([crop, view], -1).transpose(2, 0, 1)[None].copy()).float()
                       / 255.0).numpy()[0]
    np.testing.assert_allclose(refiner.refine(image, K, T, iterations=1),
                               moved(T, K, g, expected * OFFSET_STD), atol=1e-6)


def test_a_colour_view_network_reads_seven_channels_and_its_checkpoint_keeps_the_colours(tmp_path):
    g = _halves(_ball(crop_px=64, object_px=44.0))
    net = ZoomNet(64, WITH_ROTATION, pretrained=False, view="colour")
    assert net.trunk.stem[1].in_channels == 7 and net(torch.zeros(2, 7, 64, 64)).shape == (2, WITH_ROTATION)
    save(tmp_path / "z.pt", net, g, 1, "ball", {})
    refiner = load(tmp_path / "z.pt")
    assert refiner.net.view == "colour"
    np.testing.assert_array_equal(refiner.geometry.colours, g.colours)
    image = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    T = _pose(0, centre=[0.0, 0.0, 0.6])
    net.eval()
    crop, view, _ = zoom_input(image, T, K, g, "colour")
    with torch.no_grad():  # the loaded network gives what the saved one gave
        expected = net(torch.from_numpy(np.concatenate([crop, view], -1).transpose(2, 0, 1)[None].copy()).float()
                       / 255.0).numpy()[0]
    np.testing.assert_allclose(refiner.refine(image, K, T, iterations=1),
                               moved(T, K, g, expected * OFFSET_STD), atol=1e-6)


def test_the_colour_view_needs_a_model_with_vertex_colours(dope_dataset, tmp_path):
    info = next(iter((dope_dataset / "models").glob("obj_*.ply")))
    obj_id = int(info.stem.split("_")[1])
    g = object_geometry(dope_dataset, obj_id, 64, 44.0, view="colour")
    assert g.colours.shape == (len(g.vertices), 3) and g.colours.std() > 0.01  # the model's own colours
    root = tmp_path / "plain"
    (root / "models").mkdir(parents=True)
    (root / "models" / "models_info.json").write_text((dope_dataset / "models" / "models_info.json").read_text())
    trimesh.creation.box((0.1, 0.1, 0.1)).export(root / "models" / info.name)  # no colours
    with pytest.raises(PegasusError, match="no vertex colours"):
        object_geometry(root, obj_id, 64, 44.0, view="colour")


def median_offsets(refiner, dataset, per_instance: int) -> tuple[np.ndarray, np.ndarray]:
    """The median |offsets| [3] of estimates drawn around each instance of ``refiner``'s object seen at more than
    half in ``dataset``'s train_pbr (fresh estimates, not the ones it was trained on), before and after
    ``refiner.refine``."""
    cfg = ZoomConfig(data=["x"], object="1", rotation_std_deg=5.0)
    rng = np.random.default_rng(7)
    before, after = [], []
    for frame in bop_frames(dataset / "train_pbr"):
        image = read_rgb(frame.image)
        for inst in (i for i in frame.instances if i.obj_id == refiner.obj_id and i.visib_fract > 0.5):
            for _ in range(per_instance):
                estimate = drawn_estimate(inst.T, frame.K, refiner.geometry, cfg, rng)
                before.append(np.abs(offsets(inst.T, estimate, frame.K, refiner.geometry)[:3]))
                after.append(np.abs(offsets(inst.T, refiner.refine(image, frame.K, estimate), frame.K,
                                            refiner.geometry)[:3]))
    return np.median(before, axis=0), np.median(after, axis=0)


def estimates_with_look(overfit_dope, dope_dataset, look) -> tuple:
    """``overfit_dope``'s estimates on the first frame of ``dope_dataset``, without and with ``look`` (one look's
    checkpoint or several, as ``DopeModel(zoom=)`` takes them): (frame, image, the estimates without, the model with
    the look, its estimates of the same detections in the same order), the two lists of one length and not empty."""
    plain = DopeModel(overfit_dope / "last.pt")
    looked = DopeModel(overfit_dope / "last.pt", zoom=look)
    frame = next(iter(bop_frames(dope_dataset / "train_pbr")))
    image = read_rgb(frame.image)
    first, second = plain.estimate(image, frame.K), looked.estimate(image, frame.K, min_score=0.0)
    assert second == sorted(second, key=lambda p: -p.score)  # by detection score x outline support
    for p in second:
        assert 0.0 <= p.support <= 1.0 and p.score == p.detection_score * p.support
    # the same detections, paired by their keypoints (the outline support reorders them)
    second = [next(s for s in second if np.array_equal(s.keypoints, f.keypoints, equal_nan=True)) for f in first]
    assert len(first) == len(second) > 0
    return frame, image, first, looked, second


def test_a_zoom_network_brings_estimates_back_towards_the_truth(zoom_run, dope_dataset):
    before, after = median_offsets(load(zoom_run), dope_dataset, 8)
    assert (after < 0.4 * before).all(), (before, after)  # measured: 0.13-0.16 (at 6 epochs 0.19-0.42)


def test_dope_poses_pass_through_the_zoom_network_with_their_rotation_kept(overfit_dope, zoom_run, dope_dataset):
    frame, image, first, zoomed, second = estimates_with_look(overfit_dope, dope_dataset, zoom_run)
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a.T[:3, :3], b.T[:3, :3])
        np.testing.assert_allclose(b.T, zoomed.zoom.refine(image, frame.K, a.T), atol=1e-9)
        assert np.linalg.norm(a.T[:3, 3] - b.T[:3, 3]) > 1e-5  # it moved them
    with pytest.raises(PegasusError, match="undistorted"):
        zoomed.estimate(image, frame.K, dist=np.zeros(5))


def test_a_zoom_network_of_another_object_or_a_file_that_is_none_is_refused(overfit_dope, zoom_run, tmp_path,
                                                                            capsys):
    doc = torch.load(zoom_run, weights_only=True)
    doc["obj_id"] = 7
    other = tmp_path / "other.pt"
    torch.save(doc, other)
    with pytest.raises(PegasusError, match="obj_id 7"):
        DopeModel(overfit_dope / "last.pt", zoom=other)
    for bad in (overfit_dope / "last.pt", tmp_path / "missing.pt"):  # a DOPE checkpoint, nothing
        with pytest.raises(PegasusError, match="zoom checkpoint"):
            load(bad)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint")
    assert main(["eval", "--model", str(overfit_dope / "last.pt"), "--zoom", str(garbage), "--data",
                 str(tmp_path), "--out", str(tmp_path / "eval")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "garbage.pt" in err


def test_train_zoom_refuses_bad_input_with_one_line(dope_dataset, tmp_path, capsys):
    for args in (["--data", str(tmp_path), "--object", "1"],  # not a BOP dataset
                 ["--data", str(dope_dataset), "--object", "no_such_object"],
                 ["--data", str(dope_dataset), "--object", "1", "--crop-px", "100"],  # not a multiple of 32
                 ["--data", str(dope_dataset), "--object", "1", "--out", str(tmp_path)]):  # a folder
        assert main(["train-zoom", *args, "--out", str(tmp_path / "z.pt")] if "--out" not in args
                    else ["train-zoom", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, err
    assert not (tmp_path / "z.pt").exists()
