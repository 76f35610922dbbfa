"""Geometry: rigid transforms, homography estimation, corner error, pose correction (PnP)."""
