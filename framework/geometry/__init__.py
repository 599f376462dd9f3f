"""Geometry: rigid transforms, exact vectorised distances, obstacle shapes."""
