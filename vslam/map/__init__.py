"""Map structures: keyframes, map points, covisibility graph."""
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import MapPoint, MapPointStore

__all__ = ["KeyFrame", "Map", "MapPoint", "MapPointStore"]
