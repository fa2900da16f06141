"""The asset library: manifests, splats + collision mesh + URDF per asset, importers, the built-in
demo assets and turntable previews."""
