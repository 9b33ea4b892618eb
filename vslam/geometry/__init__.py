"""Pure geometry on NumPy arrays: no state, no I/O, imports nothing else of vslam except errors."""
