"""The generation config: defaults, YAML + overrides, clear rejections."""

import pytest

from pegasus_gen.dataset.config import GenerateConfig, load_config
from pegasus_gen.errors import PegasusError


def test_defaults_and_overrides(tmp_path):
    path = tmp_path / "gen.yaml"
    path.write_text("scenes: 3\ncamera:\n  width: 320\n  height: 240\n"
                    "objects:\n  - {asset: noodle_cup_red, count: [1, 2]}\n")
    cfg = load_config(path, ["camera.fov_deg=45", "dynamic=true", "trajectory.distance=[0.3, 0.5]"])
    assert cfg.scenes == 3 and cfg.camera.width == 320 and cfg.camera.fov_deg == 45 and cfg.dynamic
    assert cfg.trajectory.distance == (0.3, 0.5) and cfg.objects[0].count == (1, 2)
    assert cfg.depth_scale == 0.1 and GenerateConfig().frames_per_scene == 10


@pytest.mark.parametrize("overrides,message", [
    (["scens=3"], "scens"),
    (["camera.width=0"], "camera.width"),
    (["depth_scale=-1"], "depth_scale"),
    (["image_format=bmp"], "image_format"),
    (["trajectory.distance=[0.9, 0.2]"], "distance"),
    (["objects=[{asset: 1, count: [3, 1]}]"], "count"),
    (["camera.width"], "key=value"),
])
def test_bad_values_are_rejected_by_name(overrides, message):
    with pytest.raises(PegasusError, match=message):
        load_config(None, overrides)


def test_bad_file(tmp_path):
    (tmp_path / "a.yaml").write_text("- just\n- a list\n")
    with pytest.raises(PegasusError, match="a.yaml: the config must be a mapping"):
        load_config(tmp_path / "a.yaml")
    with pytest.raises(PegasusError, match="cannot read"):
        load_config(tmp_path / "missing.yaml")
