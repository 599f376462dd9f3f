"""Path tools every planner and device may use: certified motion batches, thinning, spline smoothing.

They live in the core so that plugin packages share them without importing
one another (the import contracts in ``pyproject.toml``):

* :func:`certify_edges` (:mod:`.certify`): which of many motions keep a
  margin, mostly decided by covering balls (safe_prm's roadmaps, optMIS's
  search space, the segmented pathmap's links);
* :func:`thin` (:mod:`.thinning`): Douglas-Peucker with every kept chord
  certified (safe_prm's smoothing, the MAVLink vehicle's mission items);
* :func:`smooth_paths` (:mod:`.splines`): natural cubic splines through a
  path's knots, every sample motion certified, falling back to shorter
  windows or the chord (optMIS's paths).
"""

from __future__ import annotations

from .certify import certify_edges
from .splines import CHORD, GLOBAL, WINDOW, SmoothedPath, smooth_paths
from .thinning import thin

__all__ = ["CHORD", "GLOBAL", "WINDOW", "SmoothedPath", "certify_edges", "smooth_paths", "thin"]
