"""vslam.frontend"""
