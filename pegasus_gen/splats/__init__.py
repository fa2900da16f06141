"""The Gaussian-splat cloud and its forms: arrays + rigid transforms, INRIA PLY, SH rotation,
splats from surfaces, meshes and procedural textures."""
