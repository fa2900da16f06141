"""BOP object models: ``models/obj_XXXXXX.ply`` (the object's surface in mm, with normals and vertex colours),
``models_eval/obj_XXXXXX.ply`` (the same surface resampled as BOP makes its evaluation models) and their
``models_info.json`` entries.

BOP's models_eval come from MeshLab's "Uniform Mesh Resampling" (marching cubes on the model's distance
field, 0.25 mm cells) followed by quadric edge-collapse decimation to 2.5 % of the faces: vertices about
1.5 mm apart whatever the source tessellation. Here marching cubes runs directly at that spacing, which
gives the same density without the decimation (which can leave holes): every vertex lies on the surface,
evenly spread, and a closed model stays closed.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import open3d as o3d
import trimesh
from skimage.measure import marching_cubes

from pegasus_gen.io.files import write_atomic

EVAL_SPACING = 0.0015  # m between the vertices of an evaluation model (BOP's models_eval density)
EVAL_CACHE_VERSION = 1  # part of the cache key: bump when eval_model or model_extent change their output


def write_model_ply(path: str | os.PathLike, mesh: trimesh.Trimesh) -> Path:
    """``model_ply_bytes`` of ``mesh`` written to ``path``."""
    data = model_ply_bytes(mesh)
    return write_atomic(path, lambda f: f.write(data))


def model_ply_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Binary PLY of ``mesh`` (metres) in millimetres: vertices (float x y z nx ny nz, uchar red green blue
    when the mesh has vertex colours), faces ``vertex_indices``; the layout bop_toolkit's loader reads."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * 1000.0
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    colored = mesh.visual.kind == "vertex"
    fields = [(n, "<f4") for n in ("x", "y", "z", "nx", "ny", "nz")] + \
        ([(n, "u1") for n in ("red", "green", "blue")] if colored else [])
    table = np.zeros(len(vertices), dtype=fields)
    for i, n in enumerate(("x", "y", "z")):
        table[n] = vertices[:, i]
        table["n" + n] = normals[:, i]
    if colored:
        rgb = np.asarray(mesh.visual.vertex_colors)[:, :3]
        for i, n in enumerate(("red", "green", "blue")):
            table[n] = rgb[:, i]
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}"]
        + [f"property {'float' if t == '<f4' else 'uchar'} {n}" for n, t in fields]
        + [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]) + "\n"
    face_table = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_table["n"] = 3
    face_table["v"] = faces
    return header.encode("ascii") + table.tobytes() + face_table.tobytes()


def eval_model(mesh: trimesh.Trimesh, max_cells: int = 200) -> trimesh.Trimesh:
    """``mesh`` (metres) resampled for pose-error evaluation, as BOP's models_eval: marching cubes on its
    distance field (signed for a closed mesh; for an open one, the surface half a cell out of it) with cubic
    cells of max(EVAL_SPACING, longest side / ``max_cells``) metres. Returns a mesh in the same frame and
    units, without colours."""
    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    cell = max(EVAL_SPACING, float((hi - lo).max()) / max_cells)
    lo, hi = lo - 2.31 * cell, hi + 2 * cell  # odd offset: the model's planes seldom pass through grid nodes
    axes = [lo[i] + cell * np.arange(int(np.ceil((hi[i] - lo[i]) / cell)) + 1) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    if mesh.is_watertight:
        field, level = scene.compute_signed_distance(o3d.core.Tensor(grid)).numpy(), 0.0
    else:
        field, level = scene.compute_distance(o3d.core.Tensor(grid)).numpy(), 0.5 * cell
    field = field.reshape(len(axes[0]), len(axes[1]), len(axes[2]))
    vertices, faces, _, _ = marching_cubes(field, level=level, spacing=(cell, cell, cell))
    resampled = trimesh.Trimesh(vertices + lo, faces, process=True)
    resampled.update_faces(resampled.nondegenerate_faces())  # a corner of the field exactly at the level
    resampled.remove_unreferenced_vertices()
    return resampled


def models_info_entry(mesh: trimesh.Trimesh, symmetries_discrete=(), symmetries_continuous=()) -> dict:
    """models_info entry in mm: diameter (largest vertex distance), min_x.., size_x.., symmetries.

    symmetries_discrete: 4x4 transforms (16 numbers, translation in m); symmetries_continuous:
    objects with ``axis`` and ``offset`` (m).
    """
    return {**model_extent(mesh), **symmetry_fields(symmetries_discrete, symmetries_continuous)}


def model_extent(mesh: trimesh.Trimesh) -> dict:
    """The geometric models_info fields of ``mesh`` (metres) in mm: diameter, min_x.., size_x.."""
    v = np.asarray(mesh.vertices, dtype=np.float64) * 1000.0
    hull = np.asarray(trimesh.convex.convex_hull(v).vertices) if len(v) > 3 else v  # the diameter lies on the hull
    diameter = max(float(np.linalg.norm(hull[i:i + 256, None, :] - hull[None, :, :], axis=-1).max())
                   for i in range(0, len(hull), 256))  # in row blocks: a fine model's hull has thousands
    lo, hi = v.min(0), v.max(0)
    return {"diameter": diameter, "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}


def symmetry_fields(symmetries_discrete=(), symmetries_continuous=()) -> dict:
    """The symmetry fields of a models_info entry (mm), present only when there are symmetries."""
    info = {}
    if len(symmetries_discrete):
        mats = []
        for sym in symmetries_discrete:
            m = np.asarray(sym, dtype=np.float64).reshape(4, 4).copy()
            m[:3, 3] *= 1000.0
            mats.append([float(x) for x in m.ravel()])
        info["symmetries_discrete"] = mats
    if len(symmetries_continuous):
        info["symmetries_continuous"] = [
            {"axis": [float(a) for a in s.axis], "offset": [float(o) * 1000.0 for o in s.offset]}
            for s in symmetries_continuous]
    return info


def cached_eval_model(surface_file: str | os.PathLike, mesh: trimesh.Trimesh, cache: str | os.PathLike
                      ) -> tuple[bytes, dict, dict]:
    """(the models_eval PLY of ``mesh`` (``model_ply_bytes`` of ``eval_model``), ``model_extent`` of ``mesh``,
    that of its evaluation model): computed once per surface and kept in the folder ``cache``, keyed by the
    SHA-256 of ``surface_file`` (the file ``mesh`` was loaded from) and EVAL_CACHE_VERSION, so a dataset made from
    assets used before costs a file read instead of marching cubes and a convex hull. A cache that cannot be
    read is recomputed; one that cannot be written is skipped."""
    digest = hashlib.sha256(f"{EVAL_CACHE_VERSION}\0".encode() + Path(surface_file).read_bytes()).hexdigest()
    ply, info = Path(cache) / digest / "eval.ply", Path(cache) / digest / "info.json"
    try:
        entries = json.loads(info.read_text())
        return ply.read_bytes(), dict(entries["model"]), dict(entries["eval"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    resampled = eval_model(mesh)
    data, entries = model_ply_bytes(resampled), {"model": model_extent(mesh), "eval": model_extent(resampled)}
    try:
        write_atomic(ply, lambda f: f.write(data))
        write_atomic(info, lambda f: f.write(json.dumps(entries).encode()))  # last: it marks the entry complete
    except OSError:  # a library this user cannot write to
        pass
    return data, entries["model"], entries["eval"]
