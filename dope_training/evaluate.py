"""Pose accuracy of a trained DOPE network on a BOP split (``pegasus eval``): ADD and ADD-S.

ADD and ADD-S: see ``pegasus_gen.geometry.pose_error``. The object's metric is ADD-S when models_info gives
it symmetries or the network was trained as symmetric (``TargetObject.symmetric``), else ADD; both are
reported. Every image of the split is run. Every ground-truth instance of the object seen at visib_fract >=
``min_visibility`` counts; instances seen less are ignored (an estimate on one is neither right nor a false
positive). An estimate is *on* an instance when its projected origin (the model's centre) lies inside the
instance's projected model box (the 2D box of its model points at the true pose): a detection, whatever its
pose error. Each counted instance is matched to the estimate on it of smallest ADD-S (greedily, each
estimate at most once); an instance with none is a miss (infinite error, failing every threshold); an
estimate left over is a false positive (a duplicate included) unless it lies on an ignored instance.
Figures: BOP's recall at 0.1 d (the share of counted instances whose error is below 10 % of the model's
diameter d, from models_info), false positives per image, misses, pass rates at 2, 5 and 10 cm, and the
AUC: the area under the pass-rate curve over thresholds 0..10 cm divided by 10 cm (1.0 = every error 0).
When the dataset names its targets (``{split}_targets_bop19.json``, as BOP's test splits do) the report's
``top_n`` also gives the same figures under BOP's rule: per image only the object's ``inst_count`` highest-scoring
estimates (of those at or above ``min_score``) are kept, and only images where it is a target count (a method is
told how many instances of each object an image holds); ``off_target`` counts the kept estimates on no counted
instance, the false positives that remain when the counts are known.
With depth refinement
(``refine``) the refined poses are matched and scored the same way, a rejected refinement being a miss.
With refinement against the RGB image (``refine_rgb``: the silhouette of the dataset's model of the object
fitted to the image's colour edges, ``dope_training.refine_rgb``; after the zoom network where there is one) the whole
report is that of the refined poses, each scored by its detection score (``decode``: centroid and corners) times
the share of its outline the image supports (``RgbRefinement.support``), and ``min_score`` applies to that score.
Each estimate's score is ``ObjectPose.score``: with zoomed looks also the detection score times its outline's support.
The report's ``estimates`` are the poses output for the evaluated images in BOP19's results form (scene_id, im_id,
obj_id, score, R row-major, t in mm, time: the image's inference seconds): the refined poses the refinement accepted
with ``refine``, else the PnP (or RGB-refined) poses. Errors are computed over the vertices of the dataset's
``models_eval`` (BOP's evaluation models), or of ``models`` without them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from dope_training.infer import DopeModel, rgb_refined
from dope_training.refine_rgb import decimated
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import bop_frames, models_info, read_model, read_targets_bop19, result_row
from pegasus_gen.formats.drawing import draw_instance
from pegasus_gen.geometry.pose_error import add_error, adds_error
from pegasus_gen.io import images
from pegasus_gen.io.files import write_atomic
from pegasus_gen.io.plots import line_chart

THRESHOLDS_M = (0.02, 0.05, 0.10)
AUC_MAX_M = 0.10
MAX_MODEL_POINTS = 2000
GALLERY_IMAGES = 12
TRUTH_COLOUR = (40, 220, 40)
ESTIMATE_COLOUR = (255, 60, 200)


def pass_rates(errors: np.ndarray, thresholds) -> np.ndarray:
    """Fraction of ``errors`` [N] (inf = miss) at or below each threshold."""
    errors = np.asarray(errors, float)
    return np.array([(errors <= t).mean() if len(errors) else 0.0 for t in thresholds])


def auc(errors: np.ndarray, max_threshold: float = AUC_MAX_M) -> float:
    """Area under the pass-rate curve over thresholds 0..max_threshold, divided by max_threshold: the mean
    over instances of max(0, 1 - error / max_threshold)."""
    errors = np.asarray(errors, float)
    return float(np.clip(1 - errors / max_threshold, 0, 1).mean()) if len(errors) else 0.0


def model_points(root: Path, obj_id: int) -> np.ndarray:
    """[N, 3] metres: the vertices of the BOP evaluation model (models_eval, else models), at most
    MAX_MODEL_POINTS (evenly strided)."""
    vertices = np.asarray(read_model(root, obj_id, evaluation=True).vertices, dtype=np.float64)
    return vertices[::max(1, len(vertices) // MAX_MODEL_POINTS)]


@dataclass
class Match:
    """One counted ground-truth instance and its estimate (None: missed)."""

    scene: str
    im_id: int
    gt_index: int
    add_m: float
    adds_m: float
    score: float | None
    T_est: np.ndarray | None
    T_gt: np.ndarray


def projected_box(points: np.ndarray, T_cam_obj: np.ndarray, K: np.ndarray) -> np.ndarray:
    """[4] (u_min, v_min, u_max, v_max) px: the 2D box of ``points`` [N, 3] (m, object frame) at T_cam_obj
    [4, 4] seen with K [3, 3]; empty (inf, inf, -inf, -inf) when any point lies behind the camera."""
    cam = points @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    if np.any(cam[:, 2] <= 1e-6):
        return np.array([np.inf, np.inf, -np.inf, -np.inf])
    uv = cam @ K.T
    uv = uv[:, :2] / uv[:, 2:]
    return np.concatenate([uv.min(0), uv.max(0)])


def is_on(T_est: np.ndarray, box: np.ndarray, K: np.ndarray) -> bool:
    """Whether the estimate's origin (T_est [4, 4], m) projects (K [3, 3]) inside ``box`` [4] px."""
    t = T_est[:3, 3]
    if t[2] <= 1e-6:
        return False
    u, v = (K @ t)[:2] / t[2]
    return bool(box[0] <= u <= box[2] and box[1] <= v <= box[3])


def match_instances(points: np.ndarray, truths: list[np.ndarray], estimates: list[np.ndarray], K: np.ndarray,
                    ignored: list[np.ndarray] = ()) -> tuple[list, int]:
    """Match estimates to counted ``truths`` (T_cam_obj [4, 4] each; see the module docstring): greedily by
    ADD-S among the pairs where the estimate is on the truth (its origin projects inside the truth's model box,
    ``points`` [N, 3] m, K [3, 3]). Returns [(truth index, estimate index or None, add, adds)] in truth order
    (None with inf errors: a miss) and the count of false positives: estimates left over that lie on none of
    the ``ignored`` instances (T_cam_obj [4, 4] each)."""
    boxes = [projected_box(points, t, K) for t in truths]
    pairs = sorted((adds_error(points, e, t), i, j) for i, t in enumerate(truths) for j, e in enumerate(estimates)
                   if is_on(e, boxes[i], K))
    taken_t, taken_e, out = set(), set(), []
    for adds, i, j in pairs:
        if i not in taken_t and j not in taken_e:
            taken_t.add(i)
            taken_e.add(j)
            out.append((i, j, add_error(points, estimates[j], truths[i]), adds))
    out += [(i, None, np.inf, np.inf) for i in range(len(truths)) if i not in taken_t]
    ignored_boxes = [projected_box(points, t, K) for t in ignored]
    false_positives = sum(1 for j, e in enumerate(estimates) if j not in taken_e
                          and not any(is_on(e, b, K) for b in ignored_boxes))
    return sorted(out, key=lambda m: m[0]), false_positives


def match_top_n(points: np.ndarray, truths: list[np.ndarray], estimates: list[tuple[float, np.ndarray]], count: int,
                K: np.ndarray, ignored: list[np.ndarray] = ()) -> tuple[list, int]:
    """:func:`match_instances` under BOP's rule: of ``estimates`` [(score, T_cam_obj [4, 4])] only the ``count``
    highest-scoring (the image's inst_count of the object) are matched; the rest are neither hits nor false
    positives."""
    kept = sorted(estimates, key=lambda e: -e[0])[:count]
    return match_instances(points, truths, [T for _, T in kept], K, ignored)


def recall(errors: np.ndarray, threshold: float) -> float:
    """BOP's recall: the share of ``errors`` [N] (m, inf = miss) below ``threshold`` (m; e.g. 0.1 d)."""
    errors = np.asarray(errors, float)
    return float((errors < threshold).mean()) if len(errors) else 0.0


def summary(errors: np.ndarray, diameter_m: float) -> dict:
    """Recall at 0.1 d (``diameter_m``), AUC (0-10 cm), pass rates and median of finite errors [N] (m, inf =
    miss)."""
    found = errors[np.isfinite(errors)]
    return {"recall_0_1d": recall(errors, 0.1 * diameter_m), "auc_0_10cm": auc(errors),
            **{f"pass_{round(t * 100)}cm": float(r) for t, r in zip(THRESHOLDS_M, pass_rates(errors, THRESHOLDS_M))},
            "median_m": float(np.median(found)) if len(found) else None}


def pose_breakdown(matches: list[Match], symmetric: bool, points: np.ndarray, diameter_m: float) -> dict:
    """How the estimates found on an instance miss its pose: over the matched instances with an estimate, the
    median distance ratio (estimated / true distance from the camera: a wrong scale shows as a ratio off 1),
    the median lateral error (m: how far the estimate's centre, moved along its own viewing ray to the true
    distance, lies from the true centre), for asymmetric objects the median rotation error (degrees) and the
    share beyond 90 degrees (the object's orientation mistaken), and ``within_0_1d``: the shares of the found
    whose error in one part of the pose alone is within 0.1 d (``diameter_m``), the other parts taken from the
    truth: ``distance`` (|estimated - true distance|), ``aside`` (the lateral error) and ``rotation`` (ADD, or
    ADD-S when ``symmetric``, of the estimated rotation at the true position, over ``points`` [N, 3] m). An
    instance within 0.1 d needs all three; the three shares say which part loses the recall. Medians and shares
    are None where nothing was found."""
    found = [m for m in matches if m.T_est is not None]
    if not found:
        return {"found": 0, "distance_ratio_median": None, "lateral_error_m_median": None,
                "rotation_error_deg_median": None, "rotation_over_90deg": None,
                "within_0_1d": {"distance": None, "aside": None, "rotation": None}}
    t_est = np.array([m.T_est[:3, 3] for m in found])
    t_gt = np.array([m.T_gt[:3, 3] for m in found])
    distance_est, distance_gt = np.linalg.norm(t_est, axis=1), np.linalg.norm(t_gt, axis=1)
    ratio = distance_est / distance_gt
    towards = t_est / ratio[:, None]  # the estimate's centre moved along its own ray to the true distance
    lateral = np.linalg.norm(towards - t_gt, axis=1)
    rotation = []  # ADD(-S) of the estimated rotation at the true position
    for m in found:
        turned = m.T_gt.copy()
        turned[:3, :3] = m.T_est[:3, :3]
        rotation.append((adds_error if symmetric else add_error)(points, turned, m.T_gt))
    bound = 0.1 * diameter_m
    out = {"found": len(found), "distance_ratio_median": float(np.median(ratio)),
           "lateral_error_m_median": float(np.median(lateral)), "rotation_error_deg_median": None,
           "rotation_over_90deg": None,
           "within_0_1d": {"distance": recall(np.abs(distance_est - distance_gt), bound),
                           "aside": recall(lateral, bound), "rotation": recall(rotation, bound)}}
    if not symmetric:
        cos = [(np.trace(m.T_est[:3, :3].T @ m.T_gt[:3, :3]) - 1) / 2 for m in found]
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        out.update(rotation_error_deg_median=float(np.median(angle)), rotation_over_90deg=float((angle > 90).mean()))
    return out


def describe_found(breakdown: dict) -> str:
    """A :func:`pose_breakdown` in words."""
    if not breakdown["found"]:
        return "none found"
    text = (f"found at x{breakdown['distance_ratio_median']:.2f} the distance, "
            f"{1000 * breakdown['lateral_error_m_median']:.0f} mm aside")
    if breakdown["rotation_error_deg_median"] is not None:
        text += (f", turned {breakdown['rotation_error_deg_median']:.0f} deg "
                 f"({breakdown['rotation_over_90deg']:.0%} beyond 90)")
    alone = breakdown["within_0_1d"]
    return text + (f"; within 0.1 d alone: distance {alone['distance']:.0%}, aside {alone['aside']:.0%}, "
                   f"rotation {alone['rotation']:.0%}")


@dataclass
class _Tally:
    """One set of estimates over the evaluated images: the counted instances' matches, false positives, BOP's
    top-n figures, the per-image record of the gallery and the BOP19 result rows."""

    matches: list = field(default_factory=list)
    false_positives: int = 0
    top_errors: list = field(default_factory=list)
    off_target: int = 0
    frames: list = field(default_factory=list)
    results: list = field(default_factory=list)


def evaluate(model: DopeModel, root: str | Path, split: str = "test", min_visibility: float = 0.1,
             max_images: int | None = None, min_score: float = 0.1, refine: bool = False,
             refine_rgb: bool = False, unrefined_min_score: float | None = None) -> dict:
    """The report (see the module docstring) as a dict; ``max_images`` per scene. With ``refine`` every
    estimate is also refined with the frame's depth image (``DopeModel.estimate``) and the report gains
    ``refined``: the same figures for the refined poses, where an estimate the refinement rejects counts
    as a miss (a robot would not act on it); with ``refine_rgb`` the report is that of the poses refined against
    the image (see the module docstring), and with ``unrefined_min_score`` too it gains ``unrefined``: the report of
    the same pass's poses before that refinement (DOPE's, and its zoom's), those scoring above
    ``unrefined_min_score`` (the detection score alone); each image's time there is that of both. ``frames`` lists
    per image its misses, false positives and instances failing 0.1 d, for the gallery of the worst
    (``write_eval_report``)."""
    root = Path(root)
    if not (root / split).is_dir():
        raise PegasusError(f"{root}: no {split}/ folder (choose --split)")
    if refine and refine_rgb:
        raise PegasusError("choose one refinement: against depth or against the RGB image")
    obj = model.object
    info = models_info(root).get(obj.obj_id)
    if info is None:
        raise PegasusError(f"{root}: models_info.json has no obj_id {obj.obj_id} (the model was trained for "
                           f"{obj.name!r})")
    if not np.allclose(info.bbox_size, obj.bbox_size, atol=1e-3):
        raise PegasusError(f"{root}: obj_id {obj.obj_id} is {np.round(info.bbox_size, 3).tolist()} m, the model's "
                           f"object {obj.name!r} {np.round(obj.bbox_size, 3).tolist()} m: another object")
    if info.diameter is None:
        raise PegasusError(f"{root}: models_info.json gives obj_id {obj.obj_id} no diameter")
    symmetric = info.symmetric or obj.symmetric
    diameter = info.diameter
    points = model_points(root, obj.obj_id)
    mesh = None
    if refine_rgb:
        model_mesh = read_model(root, obj.obj_id)
        mesh = decimated(model_mesh.vertices, model_mesh.faces)
    both = refine_rgb and unrefined_min_score is not None
    targets = read_targets_bop19(root, split)  # BOP's top-n rule
    tally, unrefined = _Tally(), _Tally()
    refined_errors, rejected = [], 0

    def add(t: _Tally, frame, truths: list, ignored: list, estimates: list, seconds: float) -> None:
        """Match one image's estimates (ObjectPose, best first) to its counted ``truths`` into ``t``."""
        for e in estimates:
            T = e.refined if refine else e.T
            if T is not None:
                t.results.append(result_row(int(frame.scene.name), frame.im_id, obj.obj_id, e.score, T, seconds))
        solved = [e for e in estimates if e.T is not None]  # DOPE + PnP alone
        pairs, extra = match_instances(points, [i.T for i in truths], [e.T for e in solved], frame.K, ignored)
        t.false_positives += extra
        count = targets.get((int(frame.scene.name), frame.im_id, obj.obj_id), 0) if targets is not None else 0
        if count:
            top_pairs, top_extra = match_top_n(points, [i.T for i in truths], [(e.score, e.T) for e in solved],
                                               count, frame.K, ignored)
            t.off_target += top_extra
            t.top_errors += [(add_m, adds_m) for _, _, add_m, adds_m in top_pairs]
        metric_errors = []
        for i, j, add_m, adds_m in pairs:
            est = solved[j] if j is not None else None
            t.matches.append(Match(frame.scene.name, frame.im_id, truths[i].index, add_m, adds_m,
                                   est.score if est else None, est.T if est else None, truths[i].T))
            metric_errors.append(adds_m if symmetric else add_m)
        t.frames.append({"scene": frame.scene.name, "im_id": frame.im_id, "image": str(frame.image),
                         "K": frame.K.tolist(), "false_positives": extra,
                         "misses": sum(j is None for _, j, _, _ in pairs),
                         "failed_0_1d": sum(e >= 0.1 * diameter for e in metric_errors),
                         "truths": [i.T.tolist() for i in truths],
                         "estimates": [{"T": e.T.tolist(), "score": float(e.score)} for e in solved]})

    def report_of(t: _Tally, rgb_refined_poses: bool, score: float) -> dict:
        """The report's figures of one tally (``score``: its detection score)."""
        add_m = np.array([m.add_m for m in t.matches])
        adds_m = np.array([m.adds_m for m in t.matches])
        report = {"model": str(model.path), "backend": model.backend, "data": str(root), "split": split,
                  "object": {"obj_id": obj.obj_id, "name": obj.name, "symmetric": symmetric,
                             "diameter_m": diameter, "bbox_min": list(obj.bbox_min),
                             "bbox_size": list(obj.bbox_size)},
                  "metric": "ADD-S" if symmetric else "ADD", "images": len(t.frames), "instances": len(t.matches),
                  "detected": int(np.isfinite(add_m).sum()), "misses": int((~np.isfinite(add_m)).sum()),
                  "false_positives": t.false_positives,
                  "false_positives_per_image": t.false_positives / len(t.frames) if t.frames else 0.0,
                  "min_visibility": min_visibility, "min_score": score, "rgb_refined": rgb_refined_poses,
                  "result": summary(adds_m if symmetric else add_m, diameter), "ADD": summary(add_m, diameter),
                  "ADD-S": summary(adds_m, diameter),
                  "found_poses": pose_breakdown(t.matches, symmetric, points, diameter),
                  "per_instance": [{"scene": m.scene, "im_id": m.im_id, "gt_index": m.gt_index,
                                    "add_m": m.add_m if np.isfinite(m.add_m) else None,
                                    "adds_m": m.adds_m if np.isfinite(m.adds_m) else None, "score": m.score}
                                   for m in t.matches],
                  "frames": t.frames, "estimates": t.results}
        if targets is not None:
            t_add, t_adds = (np.array([e[k] for e in t.top_errors], float).reshape(-1) for k in (0, 1))
            report["top_n"] = {"instances": len(t.top_errors), "misses": int((~np.isfinite(t_add)).sum()),
                               "off_target": t.off_target,
                               "off_target_per_image": t.off_target / len(t.frames) if t.frames else 0.0,
                               "result": summary(t_adds if symmetric else t_add, diameter),
                               "ADD": summary(t_add, diameter), "ADD-S": summary(t_adds, diameter)}
        return report

    lowest = min(min_score, unrefined_min_score) if both else min_score
    for frame in tqdm(list(bop_frames(root / split, max_images)), desc="eval", unit="img"):
        mine = [i for i in frame.instances if i.obj_id == obj.obj_id]
        seen = [i.visib_fract is None or i.visib_fract >= min_visibility for i in mine]
        truths = [i for i, s in zip(mine, seen) if s]
        ignored = [i.T for i, s in zip(mine, seen) if not s]
        image = images.read_rgb(frame.image)
        depth = frame.read_depth() if refine else None
        started = time.perf_counter()
        estimates = model.estimate(image, frame.K, min_score=lowest, depth_m=depth, mesh=mesh)
        seconds = time.perf_counter() - started
        if both:
            add(unrefined, frame, truths, ignored, [e for e in estimates if e.score > unrefined_min_score], seconds)
        add(tally, frame, truths, ignored, rgb_refined(estimates, min_score) if refine_rgb else estimates, seconds)
        if refine:
            refined = [e.refined for e in estimates if e.refined is not None]
            rejected += len(estimates) - len(refined)
            refined_errors += [(add_m, adds_m) for _, _, add_m, adds_m in match_instances(
                points, [t.T for t in truths], refined, frame.K, ignored)[0]]
    report = report_of(tally, refine_rgb, min_score)
    if both:
        report["unrefined"] = report_of(unrefined, False, unrefined_min_score)
    if refine:
        r_add, r_adds = (np.array([e[k] for e in refined_errors], float).reshape(-1) for k in (0, 1))
        report["refined"] = {"rejected": rejected, "misses": int((~np.isfinite(r_add)).sum()),
                             "result": summary(r_adds if symmetric else r_add, diameter),
                             "ADD": summary(r_add, diameter), "ADD-S": summary(r_adds, diameter)}
        for entry, (e_add, e_adds) in zip(report["per_instance"], refined_errors):
            entry["refined_add_m"] = e_add if np.isfinite(e_add) else None
            entry["refined_adds_m"] = e_adds if np.isfinite(e_adds) else None
    return report


def score_threshold(report: dict, max_false_positives_per_image: float, keep_found: float = 0.0) -> float:
    """The lowest detection score (``decode``) at which the report's estimates would leave at most
    ``max_false_positives_per_image`` false positives per image: counted as every estimate at or above it
    less the matched ones at or above it (each instance keeps its match while its score passes); and, with
    ``keep_found`` > 0, at least the highest score that still keeps that share of the report's found instances
    (ceil(keep_found x found) of them). Calibrate on generated held-out frames, never on the photos the figures
    are for."""
    scores = np.array([e["score"] for f in report["frames"] for e in f["estimates"]], float)
    matched = np.array([m["score"] for m in report["per_instance"] if m["score"] is not None], float)
    images = max(report["images"], 1)
    floor = report["min_score"]
    if keep_found > 0 and len(matched):
        floor = max(floor, float(np.sort(matched)[::-1][int(np.ceil(keep_found * len(matched))) - 1]))
    for t in np.unique(np.concatenate([[floor], scores[scores >= floor]])):
        if ((scores >= t).sum() - (matched >= t).sum()) / images <= max_false_positives_per_image:
            return float(t)
    return float(scores.max(initial=floor)) + 1e-6


def write_eval_report(report: dict, out: str | Path) -> tuple[Path, Path, Path | None]:
    """``out``/eval.json, ``out``/eval_curve.png (pass rate against threshold for ADD and ADD-S, and with
    depth refinement when the report has it) and ``out``/eval_worst.png (``write_gallery``; None when no
    image has a miss, a false positive or a pose beyond 0.1 d)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    json_path = write_atomic(out / "eval.json", lambda f: f.write(json.dumps(report, indent=1).encode()))
    thresholds = np.linspace(0, AUC_MAX_M, 201)
    series = {}
    for prefix, label in (("", ""), ("refined_", " + depth")):
        if prefix and "refined" not in report:
            continue
        for name in ("ADD", "ADD-S"):
            errors = [m[prefix + name.lower().replace("-", "") + "_m"] for m in report["per_instance"]]
            errors = np.array([np.inf if e is None else e for e in errors], float)
            figures = report["refined"] if prefix else report
            series[f"{name}{label} (AUC {figures[name]['auc_0_10cm']:.3f})"] = (thresholds * 100,
                                                                                pass_rates(errors, thresholds))
    chart = line_chart(series, f"{report['object']['name']}: {report['instances']} instances, "
                       f"{report['misses']} missed", "threshold (cm)", "pass rate", y_range=(0, 1))
    return json_path, images.write_image(out / "eval_curve.png", chart), write_gallery(report, out / "eval_worst.png")


def write_gallery(report: dict, path: str | Path, count: int = GALLERY_IMAGES, width: int = 320) -> Path | None:
    """The ``count`` images of ``report`` with the most misses, false positives and poses beyond 0.1 d, in
    a grid of ``width``-px tiles, to ``path`` (PNG): the truths' model boxes in green, the estimates' in
    magenta with their scores, a caption per tile. None (nothing written) when every image is right."""
    def badness(f):
        return f["misses"] + f["false_positives"] + f["failed_0_1d"]

    worst = sorted((f for f in report["frames"] if badness(f) > 0), key=lambda f: -badness(f))[:count]
    if not worst:
        return None
    obj = report["object"]
    bbox_min, bbox_size = np.array(obj["bbox_min"]), np.array(obj["bbox_size"])
    tiles, height = [], None
    for f in worst:
        image = images.read_rgb(f["image"])
        K = np.array(f["K"])
        for T in f["truths"]:
            draw_instance(image, K, np.array(T), bbox_min, bbox_size, None, None, TRUTH_COLOUR, "truth")
        for e in f["estimates"]:
            draw_instance(image, K, np.array(e["T"]), bbox_min, bbox_size, None, None, ESTIMATE_COLOUR,
                          f"{e['score']:.2f}")
        height = height or round(image.shape[0] * width / image.shape[1])
        tile = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        caption = (f"{f['scene']}/{f['im_id']}: {f['misses']} missed, {f['false_positives']} false pos., "
                   f"{f['failed_0_1d']} > 0.1d")
        cv2.rectangle(tile, (0, 0), (width, 16), (0, 0, 0), -1)
        cv2.putText(tile, caption, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    columns = min(3, len(tiles))
    tiles += [np.zeros_like(tiles[0])] * (-len(tiles) % columns)
    grid = np.vstack([np.hstack(tiles[r:r + columns]) for r in range(0, len(tiles), columns)])
    return images.write_image(path, grid)
