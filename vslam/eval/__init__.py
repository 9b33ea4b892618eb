"""vslam.eval"""
