"""Dataset readers: one module per format, all yielding :class:`vslam.datasets.frame.Frame`."""
