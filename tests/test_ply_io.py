"""3DGS PLY: bit-exact round trips, files written by another tool (plyfile), and every malformed case."""

import numpy as np
import pytest
from conftest import random_cloud
from plyfile import PlyData, PlyElement

from pegasus_gen.errors import SplatFileError
from pegasus_gen.geometry.cameras import frame_points, intrinsics_from_fov
from pegasus_gen.render.renderer import render
from pegasus_gen.splats.ply import read_ply, vertex_property_names, write_ply

FIELDS = ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh", "labels")


def assert_same_cloud(a, b, labels=True):
    for f in FIELDS if labels else FIELDS[:-1]:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_is_bit_exact(tmp_path, degree):
    cloud = random_cloud(np.random.default_rng(degree), 257, sh_degree=degree)
    first = write_ply(tmp_path / "a.ply", cloud)
    loaded = read_ply(first)
    assert loaded.sh_degree == degree
    assert_same_cloud(cloud, loaded, labels=False)
    second = write_ply(tmp_path / "b.ply", loaded)
    assert first.read_bytes() == second.read_bytes()


def test_labels_survive_when_written(tmp_path):
    cloud = random_cloud(np.random.default_rng(0), 50, labels=(0, 4, 9))
    assert_same_cloud(cloud, read_ply(write_ply(tmp_path / "l.ply", cloud, include_labels=True)))
    assert (read_ply(write_ply(tmp_path / "n.ply", cloud)).labels == 0).all()


def test_header_uses_inria_property_names_and_order(tmp_path):
    path = write_ply(tmp_path / "a.ply", random_cloud(np.random.default_rng(0), 3, sh_degree=3))
    header = path.read_bytes().split(b"end_header")[0].decode().splitlines()
    props = [line.split()[2] for line in header if line.startswith("property float")]
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert props[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert header[1] == "format binary_little_endian 1.0"


def other_tool_ply(path, cloud, text=False, byte_order="<", extra=True, drop=(), n_rest=None, mutate=None):
    """Write a 3DGS PLY with plyfile (independent of our writer), INRIA layout plus an unknown property."""
    n, k = len(cloud), cloud.sh.shape[1]
    rest = cloud.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major
    columns = {"x": cloud.means[:, 0], "y": cloud.means[:, 1], "z": cloud.means[:, 2],
               "nx": np.zeros(n), "ny": np.zeros(n), "nz": np.ones(n)}
    if extra:
        columns["confidence"] = np.linspace(0, 1, n)  # unknown to us, between known ones
    for c in range(3):
        columns[f"f_dc_{c}"] = cloud.sh[:, 0, c]
    for i in range(rest.shape[1] if n_rest is None else n_rest):
        columns[f"f_rest_{i}"] = rest[:, i] if i < rest.shape[1] else np.zeros(n)
    columns["opacity"] = cloud.opacity_logits
    for i in range(3):
        columns[f"scale_{i}"] = cloud.log_scales[:, i]
    for i in range(4):
        columns[f"rot_{i}"] = cloud.quats_wxyz[:, i]
    for name in drop:
        columns.pop(name)
    table = np.zeros(n, dtype=[(name, "f4") for name in columns])
    for name, values in columns.items():
        table[name] = values
    if mutate:
        mutate(table)
    element = PlyElement.describe(table, "vertex")
    PlyData([element], text=text, byte_order=byte_order, comments=["written by another tool"]).write(str(path))
    return path


@pytest.mark.parametrize("variant", [dict(), dict(text=True), dict(byte_order=">")],
                         ids=["binary_le", "ascii", "binary_be"])
def test_file_from_another_tool_loads_renders_and_round_trips(tmp_path, variant):
    cloud = random_cloud(np.random.default_rng(3), 400, sh_degree=3, extent=0.2)
    path = other_tool_ply(tmp_path / "other.ply", cloud, **variant)
    loaded = read_ply(path)
    assert_same_cloud(cloud, loaded, labels=False)
    K = intrinsics_from_fov(64, 48, 60)
    out = render(loaded, K, frame_points(loaded.means, K, 64, 48), 64, 48, device="cpu")
    assert (out.alpha > 0.5).mean() > 0.1 and np.isfinite(out.rgb).all()
    again = read_ply(write_ply(tmp_path / "ours.ply", loaded))
    assert_same_cloud(loaded, again)


def test_degree_is_inferred_from_f_rest_count(tmp_path):
    for degree in range(4):
        cloud = random_cloud(np.random.default_rng(degree), 10, sh_degree=degree)
        assert read_ply(other_tool_ply(tmp_path / f"d{degree}.ply", cloud)).sh_degree == degree


def test_an_element_before_the_vertices_is_skipped(tmp_path):
    cloud = random_cloud(np.random.default_rng(0), 20, sh_degree=1)
    path = write_ply(tmp_path / "a.ply", cloud)
    raw = path.read_bytes()
    header, body = raw.split(b"end_header\n", 1)
    lines = header.decode().splitlines()
    lines[2:2] = ["element camera 2", "property double fx", "property uchar id"]
    patched = tmp_path / "b.ply"
    patched.write_bytes(("\n".join(lines) + "\nend_header\n").encode() + b"\x00" * (2 * 9) + body)
    assert_same_cloud(cloud, read_ply(patched), labels=False)


def _expect_error(path, match):
    with pytest.raises(SplatFileError, match=match) as exc:
        read_ply(path)
    assert str(path) in str(exc.value)


def test_not_a_ply(tmp_path):
    (tmp_path / "r.ply").write_bytes(np.random.default_rng(0).bytes(100))
    _expect_error(tmp_path / "r.ply", "not a PLY")
    (tmp_path / "t.ply").write_text("x y z\n1 2 3\n")
    _expect_error(tmp_path / "t.ply", "not a PLY")


def test_missing_file(tmp_path):
    _expect_error(tmp_path / "nope.ply", "cannot read")


@pytest.mark.parametrize("prop", ["opacity", "rot_3", "f_dc_1", "x"])
def test_missing_property(tmp_path, prop):
    cloud = random_cloud(np.random.default_rng(0), 5, sh_degree=1)
    _expect_error(other_tool_ply(tmp_path / "m.ply", cloud, drop=[prop]), f"missing.*{prop}")


def test_wrong_f_rest_count(tmp_path):
    cloud = random_cloud(np.random.default_rng(0), 5, sh_degree=1)
    _expect_error(other_tool_ply(tmp_path / "w.ply", cloud, n_rest=10), "10 f_rest")


def test_f_rest_with_a_gap(tmp_path):
    cloud = random_cloud(np.random.default_rng(0), 5, sh_degree=1)
    _expect_error(other_tool_ply(tmp_path / "g.ply", cloud, n_rest=10, drop=["f_rest_3"]), "f_rest_0..f_rest_8")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values(tmp_path, bad):
    cloud = random_cloud(np.random.default_rng(0), 5, sh_degree=2)

    def poison(table):
        table["scale_1"][3] = bad

    _expect_error(other_tool_ply(tmp_path / "n.ply", cloud, mutate=poison), "NaN or inf.*scale_1.*vertex 3")


def test_truncated_binary_data(tmp_path):
    path = write_ply(tmp_path / "a.ply", random_cloud(np.random.default_rng(0), 30, sh_degree=3))
    path.write_bytes(path.read_bytes()[:-7])
    _expect_error(path, "truncated")


def test_truncated_ascii_data(tmp_path):
    cloud = random_cloud(np.random.default_rng(0), 6, sh_degree=0)
    path = other_tool_ply(tmp_path / "a.ply", cloud, text=True)
    text = path.read_text().splitlines()
    path.write_text("\n".join(text[:-2]) + "\n")
    _expect_error(path, "truncated|expected")


def test_vertex_property_names_count():
    for degree, n_rest in [(0, 0), (1, 9), (2, 24), (3, 45)]:
        assert len(vertex_property_names(degree)) == 17 + n_rest
