"""DOPE training on BOP datasets, ONNX export and inference (built in a later milestone)."""
