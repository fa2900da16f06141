"""sim_controller_node: starts the simulated UR controller (a child process, see
``robot_bridge.sim.process``) for the launch's lifetime. Parameters: ``host``, ``time_scale``, ``basket``
(floor centre x y z, base frame), ``log``. A host that is not a loopback address, a time scale out of range
or a basket the cell refuses (not 3 finite numbers) is a PegasusError."""

from __future__ import annotations

from nodes.ros import Node, declare, run_node
from pegasus_gen.errors import PegasusError
from robot_bridge.cell import SIM_CELL
from robot_bridge.sim.process import SimControllerProcess

PARAMETERS = (("host", "127.0.0.1"), ("time_scale", 1.0), ("basket", list(SIM_CELL.basket)), ("log", ""))


class SimControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__("sim_controller_node", **kwargs)
        p = declare(self, PARAMETERS)
        host, time_scale, basket, log = p["host"], p["time_scale"], list(p["basket"]), p["log"]
        self.process = SimControllerProcess(host, log or None, time_scale=time_scale).start()
        if len(basket) == 3:
            try:
                self.process.cell.set_basket(basket)
            except PegasusError as exc:
                self.process.stop()
                raise PegasusError(f"sim_controller_node: basket {basket}: {exc}") from None

    def destroy_node(self) -> None:
        self.process.stop()
        super().destroy_node()


NODE_CLASS = SimControllerNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)
