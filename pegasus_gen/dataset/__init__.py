"""Dataset generation: config, physics drops, camera trajectories, rendering into BOP (+ COCO, DOPE
json), the BOP reader, validation and overlays."""
