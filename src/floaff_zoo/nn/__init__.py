"""Networks and point operations (pure torch; nothing here knows about files or Lightning)."""

from floaff_zoo.nn.ops import (
    ball_query,
    farthest_point_sample,
    index_points,
    knn,
    square_distance,
    three_interpolate,
)

__all__ = [
    "ball_query",
    "farthest_point_sample",
    "index_points",
    "knn",
    "square_distance",
    "three_interpolate",
]
