"""generator_node: runs ``pegasus generate`` with a config and publishes its progress.

Parameters: ``config`` (YAML path, may be empty), ``output``, ``scenes``, ``frames_per_scene``, ``width``,
``height``, ``device``, ``library``, ``environments`` and ``objects`` (YAML text, as the config keys) (empty /
0: the config's), ``overrides`` (more key=value items, as the CLI takes, in one string split like a shell
line), ``resume``. Publishes
``generator/progress`` (String JSON: frames written, frames planned, state) once a second and, when the
dataset is complete, its path on ``dataset`` (String, transient-local so late subscribers get it).
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path

from nodes.background import BackgroundJob
from nodes.ros import Node, declare, latched, msgs, run_node
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.errors import PegasusError

PARAMETERS = (("config", ""), ("output", ""), ("scenes", 0), ("frames_per_scene", 0), ("width", 0), ("height", 0),
              ("device", ""), ("library", ""), ("environments", ""), ("objects", ""), ("overrides", ""),
              ("resume", False))
CONFIG_KEYS = {"width": "camera.width", "height": "camera.height"}  # parameter -> config key, where they differ


class GeneratorNode(Node):
    def __init__(self, **kwargs):
        super().__init__("generator_node", **kwargs)
        p = declare(self, PARAMETERS)
        overrides = [f"{CONFIG_KEYS.get(name, name)}={p[name]}" for name, default in PARAMETERS
                     if name not in ("config", "overrides", "resume") and p[name] != default]
        try:
            overrides += shlex.split(p["overrides"])
        except ValueError as exc:  # an unclosed quote
            raise PegasusError(f"generator_node: overrides {p['overrides']!r}: {exc}") from None
        resume = p["resume"]
        self.cfg = load_config(p["config"] or None, overrides)
        self.planned = self.cfg.scenes * self.cfg.frames_per_scene
        self.progress_pub = self.create_publisher(msgs.String, "generator/progress", 10)
        self.dataset_pub = self.create_publisher(msgs.String, "dataset", latched())
        self.job = BackgroundJob(lambda: generate(self.cfg, resume=resume))
        self.create_timer(1.0, self.tick)

    def frames_written(self) -> int:
        split = Path(self.cfg.output) / "train_pbr"
        return sum(1 for _ in split.glob("*/rgb/*")) if split.is_dir() else 0

    def tick(self) -> None:
        self.progress_pub.publish(msgs.String(data=json.dumps(
            {"frames": self.frames_written(), "planned": self.planned, "state": self.job.state,
             "error": self.job.error})))
        self.job.announce(self, self.dataset_pub, "dataset")


NODE_CLASS = GeneratorNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)
