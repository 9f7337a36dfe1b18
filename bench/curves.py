"""bench/curves.py — error-against-time curves shared by the benches: loglog_at(points, x) is the
curve through points [(x, y), ...] read at x by log-log interpolation, None outside its range."""
import math


def loglog_at(points, x):
    pts = sorted(points)
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x0 <= x <= x1:
            f = 0.0 if x1 == x0 else (math.log(x) - math.log(x0)) / (math.log(x1) - math.log(x0))
            return math.exp(math.log(y0) + f * (math.log(y1) - math.log(y0)))
    if pts and abs(x - pts[0][0]) <= 1e-9 * x:
        return pts[0][1]
    return None
