"""Geometry of the pipeline: cubic Bezier curves (evaluation, fitting, RANSAC) and multi-view
triangulation."""
