"""Benchmark definitions (importable so that `vslam bench` can run them)."""
