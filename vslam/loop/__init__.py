"""vslam.loop"""
