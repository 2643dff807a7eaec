"""Marker-based optical motion capture: images or 2D centroids in, labelled 3D trajectories out."""

__version__ = "0.1.0"
