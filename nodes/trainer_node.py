"""trainer_node: trains DOPE on the dataset named on ``dataset`` (or the ``data`` parameter), exports ONNX,
and publishes the model's path on ``model`` (String, transient-local).

Parameters: ``data`` (empty: wait for ``dataset``), ``object``, ``out``, ``variant``, ``epochs``,
``batch_size``, ``size``, ``device`` and ``options`` (more TrainConfig fields as space-separated key=value,
values parsed as YAML: "focal_px=330 schedule=cosine symmetry_axis=[0,0,1]"). Publishes
``trainer/progress`` (String JSON: step, epoch, loss, state) once a second from the run's loss.csv.
"""

from __future__ import annotations

import json
from pathlib import Path

from dope_training.export import export_checkpoint
from dope_training.train import TrainConfig, read_losses, train
from dope_training.train_config import parse_options
from nodes.background import BackgroundJob
from nodes.ros import Node, declare, latched, msgs, run_node

PARAMETERS = (
    ("data", ""), ("object", ""), ("out", "runs/dope"), ("variant", "light"), ("epochs", 10),
    ("batch_size", 8), ("size", 0), ("device", "auto"), ("loader_workers", -1), ("options", ""))


class TrainerNode(Node):
    def __init__(self, **kwargs):
        super().__init__("trainer_node", **kwargs)
        p = declare(self, PARAMETERS)
        self.params = p
        self.job = None
        self.progress_pub = self.create_publisher(msgs.String, "trainer/progress", 10)
        self.model_pub = self.create_publisher(msgs.String, "model", latched())
        self.create_subscription(msgs.String, "dataset", lambda m: self.start(m.data), latched())
        self.create_timer(1.0, self.tick)
        if p["data"]:
            self.start(p["data"])

    def start(self, data: str) -> None:
        if self.job is not None:
            return
        p = self.params

        def work():  # the config is built (and checked) in the job: a bad parameter fails it, visibly
            run = train(TrainConfig(data=[data], object=str(p["object"]), out=p["out"], variant=p["variant"],
                                    epochs=p["epochs"], batch_size=p["batch_size"], size=p["size"],
                                    **parse_options(p["options"]),
                                    device=p["device"], loader_workers=p["loader_workers"]))
            return export_checkpoint(run / "last.pt", run / "model.onnx")[0]

        self.get_logger().info(f"trainer_node: training on {data}")
        self.job = BackgroundJob(work)

    def tick(self) -> None:
        if self.job is None:
            return
        rows = read_losses(Path(self.params["out"]) / "loss.csv")
        last = rows[-1] if rows else {}
        self.progress_pub.publish(msgs.String(data=json.dumps(
            {"step": last.get("step", 0), "epoch": last.get("epoch", 0), "loss": last.get("loss", float("nan")),
             "state": self.job.state, "error": self.job.error})))
        self.job.announce(self, self.model_pub, "model")


NODE_CLASS = TrainerNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)
