"""DOPE (Deep Object Pose Estimation): training data and targets from BOP or DOPE/NDDS datasets, the network
and its training, ONNX export, inference (onnxruntime or torch + PnP) with overlays, and ADD/ADD-S evaluation."""
