"""Image front ends: an image in, 2D-3D correspondences out.

Every front end has ``process(image, camera) -> (points_px (N, 2), points3d (N, 3), ids (N,))``
(distorted pixels, world points in metres, int64 ids), ready for
:func:`rs_localizer.estimate.estimate_rs_pose`. :func:`make_frontend` builds one by name.
"""

from .aruco import ArucoFrontend, to_gray

__all__ = ["ArucoFrontend", "FeatureFrontend", "FeatureMap", "build_feature_map", "to_gray",
           "make_frontend", "FRONTENDS"]

FRONTENDS = ("aruco", "features")


def __getattr__(name):  # features pulls in the renderer; import it lazily
    if name in ("FeatureFrontend", "FeatureMap", "build_feature_map"):
        from . import features

        return getattr(features, name)
    raise AttributeError(name)


def make_frontend(kind: str, map_path, **kw):
    """Front end by name: ``aruco`` (``map_path``: marker map YAML, scene YAML or built-in scene
    name) or ``features`` (``map_path``: a feature map ``.npz`` from :func:`build_feature_map`).
    Raises ValueError for an unknown kind."""
    if kind == "aruco":
        return ArucoFrontend.from_file(map_path, **kw)
    if kind == "features":
        from .features import FeatureFrontend

        return FeatureFrontend.from_file(map_path, **kw)
    raise ValueError(f"unknown front end {kind!r}; expected one of {FRONTENDS}")
