"""Photos to a metric, z-up splat asset: SfM (pycolmap), ArUco scale, plane alignment, 3DGS training,
and a synthetic capture to try it on."""
