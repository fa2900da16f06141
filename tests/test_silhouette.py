"""Mesh silhouettes take exactly the pixels whose centres a projected triangle holds: against a brute-force
barycentric test, and areas against shapes of known size."""

import numpy as np
import pytest
import trimesh

from pegasus_gen.render.silhouette import mesh_coverage, mesh_silhouette

K = np.array([[500.0, 0, 80], [0, 500.0, 60], [0, 0, 1]])


def inside_any(uv: np.ndarray, faces: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Brute force over every pixel centre: (inside, on an edge to 1e-9) [H, W] bool, barycentric coordinates."""
    ys, xs = np.mgrid[0:height, 0:width]
    p = np.stack([xs, ys], -1).reshape(-1, 1, 2).astype(np.float64)
    a, b, c = (uv[faces[:, k]][None] for k in range(3))
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[..., 0] * v1[..., 1] - v1[..., 0] * v0[..., 1]
    beta = (v2[..., 0] * v1[..., 1] - v1[..., 0] * v2[..., 1]) / den
    gamma = (v0[..., 0] * v2[..., 1] - v2[..., 0] * v0[..., 1]) / den
    bary = np.stack([1 - beta - gamma, beta, gamma], -1)
    inside = (bary > 1e-9).all(-1).any(-1).reshape(height, width)
    edge = ((bary > -1e-9).all(-1) & (np.abs(bary) <= 1e-9).any(-1)).any(-1).reshape(height, width)
    return inside, edge


def test_random_triangles_cover_exactly_the_pixel_centres_inside_them():
    rng = np.random.default_rng(0)
    for _ in range(20):
        n = 12
        cam = np.column_stack([rng.uniform(-0.2, 0.2, (n, 2)), rng.uniform(0.8, 1.5, n)])  # in front, both windings
        faces = rng.integers(0, n, (8, 3))
        faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
        mask = mesh_silhouette(cam, faces, K, np.eye(4), 160, 120)
        uv = cam[:, :2] / cam[:, 2:] * 500.0 + [80, 60]
        inside, edge = inside_any(uv, faces, 160, 120)
        assert (mask | edge == inside | edge).all()  # pixel centres on an edge may go either way
        assert inside.sum() > 0


def test_a_square_facing_the_camera_takes_the_pixel_centres_within_it():
    half = 0.0371  # m, at 1 m: 18.55 px either side of the principal point (80, 60)
    square = np.array([[-half, -half, 1.0], [half, -half, 1.0], [half, half, 1.0], [-half, half, 1.0]])
    mask = mesh_silhouette(square, np.array([[0, 1, 2], [0, 2, 3]]), K, np.eye(4), 160, 120)
    ys, xs = np.nonzero(mask)  # 80 - 18.55 .. 80 + 18.55: columns 62..98; 60 +- 18.55: rows 42..78
    assert (xs.min(), xs.max(), ys.min(), ys.max()) == (62, 98, 42, 78) and mask.sum() == 37 * 37


@pytest.mark.parametrize("supersample", [4, 8])
def test_coverage_sums_to_the_projected_area(supersample):
    # a sphere of radius r at distance d projects to a disc of radius f r / sqrt(d^2 - r^2); the icosphere
    # (vertices on the sphere) a little less (0.1 % here); counting sample points adds well under 0.3 %. A fill that
    # grew the outline by half a sample would add 1.2 % (at 4 x 4 samples per pixel)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.02)
    T = np.eye(4)
    T[2, 3] = 0.5
    disc = np.pi * (500.0 * 0.02 / np.sqrt(0.5**2 - 0.02**2)) ** 2
    area = mesh_coverage(sphere.vertices, sphere.faces, K, T, 160, 120, supersample).sum()
    assert 0.99 * disc < area < 1.003 * disc


def test_behind_the_camera_is_refused():
    with pytest.raises(ValueError, match="behind"):
        mesh_silhouette(np.array([[0, 0, -1.0], [1, 0, 1], [0, 1, 1]]), np.array([[0, 1, 2]]), K, np.eye(4), 16, 12)
