"""The exceptions vslam raises for problems a user can cause or must handle.

The command line catches :class:`VslamError` and prints its message (never a traceback),
so every message should say which file or value is wrong and what to do about it.
"""
from __future__ import annotations


class VslamError(Exception):
    """Base class of every error vslam raises on purpose."""


class DatasetError(VslamError):
    """A sequence cannot be read: missing files, bad layout, unreadable images, bad timestamps."""


class CalibrationError(DatasetError):
    """Camera calibration is missing or malformed."""


class TrajectoryError(VslamError):
    """A trajectory file is missing, empty or malformed, or two trajectories do not overlap."""


class ConfigError(VslamError):
    """A configuration file or ``--set key=value`` override is invalid."""


class GeometryError(VslamError):
    """A geometric estimate is impossible: too few points, degenerate configuration, NaN/inf input."""


class MapFormatError(VslamError):
    """A saved map is truncated, corrupted or of an unsupported version."""


class OutputError(VslamError):
    """An output cannot be written: the folder is a file or not writable, the disk is full, it is
    the input folder, or another run is using it."""


class MergeError(VslamError):
    """Two maps cannot be merged: no place of one is recognized and verified in the other."""
