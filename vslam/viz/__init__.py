"""vslam.viz"""
