"""sim_controller_node: starts the simulated UR controller (a child process, see
``robot_bridge.sim.process``) for the launch's lifetime. Parameters: ``host``, ``time_scale``, ``basket``
(floor centre, base frame; [] for none), ``log``."""

from __future__ import annotations

from nodes.ros import Node, run_node
from robot_bridge.sim.process import SimControllerProcess


class SimControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__("sim_controller_node", **kwargs)
        host = self.declare_parameter("host", "127.0.0.1").value
        time_scale = float(self.declare_parameter("time_scale", 1.0).value)
        basket = list(self.declare_parameter("basket", [-0.25, -0.28, 0.0]).value or [])
        log = self.declare_parameter("log", "").value
        self.process = SimControllerProcess(host, log or None, time_scale=time_scale).start()
        if len(basket) == 3:
            self.process.command(f"sim basket {basket[0]} {basket[1]} {basket[2]}")

    def destroy_node(self) -> None:
        self.process.stop()
        super().destroy_node()


NODE_CLASS = SimControllerNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)
