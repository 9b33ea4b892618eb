"""vslam.map"""
