"""vslam.features"""
