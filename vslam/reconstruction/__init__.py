"""vslam.reconstruction"""
