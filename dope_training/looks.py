"""The zoomed looks at an estimate, whichever a checkpoint holds: the offsets look (``dope_training.zoom``) or the
outline look (``dope_training.outline``), alone or several applied in turn (``ZoomChain``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from dope_training.outline import OutlineRefiner, outline_refiner
from dope_training.zoom import ZoomRefiner, offsets_refiner, read_checkpoint


def load(path: str | Path, device: str | torch.device = "cpu") -> ZoomRefiner | OutlineRefiner:
    """The look saved at ``path`` by ``pegasus train-zoom`` (either kind: the same ``refine(image, K, T)``); a
    PegasusError when it is not a zoom checkpoint (nothing in it is run)."""
    doc, g = read_checkpoint(path)
    device = torch.device(device)
    if doc.get("look") == "outline":
        return outline_refiner(doc, g, device)
    return offsets_refiner(doc, g, path, device)


class ZoomChain:
    """Looks of one object (``load``) applied in turn: ``refine`` as theirs."""

    def __init__(self, looks: list):
        self.looks = looks

    @property
    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The object's decimated mesh that the looks fit (vertices [V, 3] m, model frame; faces [F, 3])."""
        return self.looks[-1].geometry.vertices, self.looks[-1].geometry.faces

    def refine(self, image: np.ndarray, K: np.ndarray, T: np.ndarray) -> np.ndarray:
        """T [4, 4] moved by each look in turn (see ``ZoomRefiner.refine``)."""
        for look in self.looks:
            T = look.refine(image, K, T)
        return T
