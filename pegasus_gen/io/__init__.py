"""Files, images and charts: atomic writes, JSON reading, PNG encoding, OpenCV line charts.
No domain imports: everything above may use it."""
