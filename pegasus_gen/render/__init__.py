"""Rendering: the `render` entry point (renderer), the numba CPU and gsplat CUDA rasterizers, the
differentiable torch rasterizer for training, mesh ray casting and silhouettes."""
