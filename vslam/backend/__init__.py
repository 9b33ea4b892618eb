"""vslam.backend"""
