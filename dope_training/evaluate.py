"""Pose accuracy of a trained DOPE network on a BOP split (``pegasus eval``): ADD and ADD-S.

ADD and ADD-S: see ``pegasus_gen.geometry.pose_error``. The object's metric is ADD-S when models_info gives
it symmetries or the network was trained as symmetric (``TargetObject.symmetric``), else ADD; both are
reported. Every ground-truth instance of the object seen at visib_fract >=
``min_visibility`` counts: each is matched to the estimate of smallest ADD-S in its image (greedily, each
estimate at most once); an instance with no estimate left is a miss (infinite error, failing every
threshold); estimates left over are false positives. Pass rates at 2, 5 and 10 cm; AUC: the area under the
pass-rate curve over thresholds 0..10 cm divided by 10 cm (1.0 = every error 0). With depth refinement
(``refine``) the refined poses are matched and scored the same way, a rejected refinement being a miss.
The report's ``estimates`` are the poses output for the evaluated images in BOP19's results form (scene_id,
im_id, obj_id, score, R row-major, t in mm, time: the image's inference seconds): the refined poses the
refinement accepted with ``refine``, else the PnP poses. Errors are computed over the vertices of the
dataset's ``models_eval`` (BOP's evaluation models), or of ``models`` without them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh
from tqdm import tqdm

from dope_training.infer import DopeModel
from pegasus_gen.dataset.bop import bop_frames
from pegasus_gen.errors import PegasusError
from pegasus_gen.geometry.pose_error import add_error, adds_error
from pegasus_gen.io import images
from pegasus_gen.io.files import read_json, write_atomic
from pegasus_gen.io.plots import line_chart

THRESHOLDS_M = (0.02, 0.05, 0.10)
AUC_MAX_M = 0.10
MAX_MODEL_POINTS = 2000


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
    """[N, 3] metres: the vertices of the BOP evaluation model (models_eval, else models; mm), at most
    MAX_MODEL_POINTS (evenly strided)."""
    path = next((p for p in (root / f / f"obj_{obj_id:06d}.ply" for f in ("models_eval", "models")) if p.is_file()),
                root / "models" / f"obj_{obj_id:06d}.ply")
    if not path.is_file():
        raise PegasusError(f"{path}: the model of obj_id {obj_id} is missing")
    vertices = np.asarray(trimesh.load(path, process=False).vertices, dtype=np.float64) / 1000.0
    return vertices[::max(1, len(vertices) // MAX_MODEL_POINTS)]


@dataclass
class Match:
    """One ground-truth instance and its estimate (None: missed)."""

    scene: str
    im_id: int
    gt_index: int
    add_m: float
    adds_m: float
    score: float | None
    T_est: np.ndarray | None
    T_gt: np.ndarray


def match_instances(points: np.ndarray, truths: list[np.ndarray], estimates: list[np.ndarray]) -> tuple[list, int]:
    """Greedy one-to-one matching by ADD-S of truths and estimates (T_cam_obj [4, 4] each): [(truth index,
    estimate index or None, add, adds)] in truth order, and the count of estimates left over."""
    pairs = sorted((adds_error(points, e, t), i, j) for i, t in enumerate(truths) for j, e in enumerate(estimates))
    taken_t, taken_e, out = set(), set(), []
    for adds, i, j in pairs:
        if i not in taken_t and j not in taken_e:
            taken_t.add(i)
            taken_e.add(j)
            out.append((i, j, add_error(points, estimates[j], truths[i]), adds))
    out += [(i, None, np.inf, np.inf) for i in range(len(truths)) if i not in taken_t]
    return sorted(out, key=lambda m: m[0]), len(estimates) - len(taken_e)


def summary(errors: np.ndarray) -> dict:
    """AUC (0-10 cm), pass rates and median of finite errors [N] (m, inf = miss)."""
    found = errors[np.isfinite(errors)]
    return {"auc_0_10cm": auc(errors),
            **{f"pass_{round(t * 100)}cm": float(r) for t, r in zip(THRESHOLDS_M, pass_rates(errors, THRESHOLDS_M))},
            "median_m": float(np.median(found)) if len(found) else None}


def evaluate(model: DopeModel, root: str | Path, split: str = "test", min_visibility: float = 0.1,
             max_images: int | None = None, min_score: float = 0.1, refine: bool = False) -> dict:
    """The report (see the module docstring) as a dict; ``max_images`` per scene. With ``refine`` every
    estimate is also refined with the frame's depth image (``DopeModel.estimate``) and the report gains
    ``refined``: the same figures for the refined poses, where an estimate the refinement rejects counts
    as a miss (a robot would not act on it)."""
    root = Path(root)
    if not (root / split).is_dir():
        raise PegasusError(f"{root}: no {split}/ folder (choose --split)")
    obj = model.object
    info = read_json(root / "models" / "models_info.json").get(str(obj.obj_id))
    if info is None:
        raise PegasusError(f"{root}: models_info.json has no obj_id {obj.obj_id} (the model was trained for "
                           f"{obj.name!r})")
    size = np.array([info["size_x"], info["size_y"], info["size_z"]]) / 1000.0
    if not np.allclose(size, obj.bbox_size, atol=1e-3):
        raise PegasusError(f"{root}: obj_id {obj.obj_id} is {np.round(size, 3).tolist()} m, the model's object "
                           f"{obj.name!r} {np.round(obj.bbox_size, 3).tolist()} m: another object")
    symmetric = bool(info.get("symmetries_discrete") or info.get("symmetries_continuous") or obj.symmetric)
    points = model_points(root, obj.obj_id)
    matches, refined_errors, false_positives, rejected, images_seen, results = [], [], 0, 0, 0, []
    frames = [f for f in bop_frames(root / split, max_images)
              if any(i.obj_id == obj.obj_id for i in f.instances)]
    for frame in tqdm(frames, desc="eval", unit="img"):
        truths = [i for i in frame.instances if i.obj_id == obj.obj_id
                  and (i.visib_fract is None or i.visib_fract >= min_visibility)]
        if not truths:
            continue
        image = cv2.imread(str(frame.image), cv2.IMREAD_COLOR)
        if image is None:
            raise PegasusError(f"{frame.image}: cannot read the image")
        depth = frame.read_depth() if refine else None
        started = time.perf_counter()
        estimates = model.estimate(image[..., ::-1].copy(), frame.K, min_score=min_score, depth_m=depth)
        seconds = time.perf_counter() - started
        images_seen += 1
        for e in estimates:
            T = e.refined if refine else e.T
            if T is not None:
                results.append({"scene_id": int(frame.scene.name), "im_id": frame.im_id, "obj_id": obj.obj_id,
                                "score": float(e.score), "R": T[:3, :3].ravel().tolist(),
                                "t": (T[:3, 3] * 1000.0).tolist(), "time": seconds})
        solved = [e for e in estimates if e.T is not None]  # DOPE + PnP alone
        pairs, extra = match_instances(points, [t.T for t in truths], [e.T for e in solved])
        false_positives += extra
        for i, j, add, adds in pairs:
            est = solved[j] if j is not None else None
            matches.append(Match(frame.scene.name, frame.im_id, truths[i].index, add, adds,
                                 est.score if est else None, est.T if est else None, truths[i].T))
        if refine:
            refined = [e.refined for e in estimates if e.refined is not None]
            rejected += len(estimates) - len(refined)
            refined_errors += [(add, adds) for _, _, add, adds in match_instances(points, [t.T for t in truths],
                                                                                   refined)[0]]
    add = np.array([m.add_m for m in matches])
    adds = np.array([m.adds_m for m in matches])
    report = {"model": str(model.path), "backend": model.backend, "data": str(root), "split": split,
              "object": {"obj_id": obj.obj_id, "name": obj.name, "symmetric": symmetric},
              "metric": "ADD-S" if symmetric else "ADD", "images": images_seen, "instances": len(matches),
              "detected": int(np.isfinite(add).sum()), "misses": int((~np.isfinite(add)).sum()),
              "false_positives": false_positives, "min_visibility": min_visibility,
              "result": summary(adds if symmetric else add), "ADD": summary(add), "ADD-S": summary(adds),
              "per_instance": [{"scene": m.scene, "im_id": m.im_id, "gt_index": m.gt_index,
                                "add_m": m.add_m if np.isfinite(m.add_m) else None,
                                "adds_m": m.adds_m if np.isfinite(m.adds_m) else None, "score": m.score}
                               for m in matches],
              "estimates": results}
    if refine:
        r_add, r_adds = (np.array([e[k] for e in refined_errors], float).reshape(-1) for k in (0, 1))
        report["refined"] = {"rejected": rejected, "misses": int((~np.isfinite(r_add)).sum()),
                             "result": summary(r_adds if symmetric else r_add), "ADD": summary(r_add),
                             "ADD-S": summary(r_adds)}
        for entry, (e_add, e_adds) in zip(report["per_instance"], refined_errors):
            entry["refined_add_m"] = e_add if np.isfinite(e_add) else None
            entry["refined_adds_m"] = e_adds if np.isfinite(e_adds) else None
    return report


def write_report(report: dict, out: str | Path) -> tuple[Path, Path]:
    """``out``/eval.json and ``out``/eval_curve.png (pass rate against threshold for ADD and ADD-S, and with
    depth refinement when the report has it)."""
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
    return json_path, images.write_image(out / "eval_curve.png", chart)
