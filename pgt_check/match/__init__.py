"""Matching: keypoint correspondences between a render (image0) and a photo (image1)."""
