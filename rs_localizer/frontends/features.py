"""Natural-feature front end following the paper's real-data protocol (sec. 4.2).

1. :func:`feature_map_from_views`: reconstruct the scene from *global-shutter* views at known
   poses with known depth (:func:`rs_localizer.sim.feature_map.build_feature_map` renders them):
   detect ORB or SIFT features and give every keypoint its 3D point by back-projecting it.
   Keypoints near depth discontinuities are
   dropped; observations of the same 3D point (within ``merge_radius``) share a landmark id.
2. :class:`FeatureFrontend`: detect the same kind of features in each rolling-shutter frame and
   match them to the map descriptors with Lowe's ratio test (the second neighbour is the best
   descriptor of a *different* landmark), one match per landmark, emitting correspondences
   ``(pixel, landmark 3D point, landmark id)``.

The map is an ``.npz`` file (:mod:`rs_localizer.maps.features`: :meth:`FeatureMap.save` /
:meth:`FeatureMap.load`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..camera import CameraModel
from ..correspondences import Correspondences, FrontendHooks
from ..maps.features import FeatureMap
from .image import to_gray

__all__ = [
    "FEW_MATCHES_FRACTION",
    "FEW_MATCHES_MIN_KEYPOINTS",
    "FeatureFrontend",
    "feature_map_from_views",
    "make_detector",
    "representative_descriptors",
]


#: an image with at least this many keypoints of which fewer than ``FEW_MATCHES_FRACTION``
#: match the map counts as a few-matches image (``FeatureFrontend.few_match_frames``): a map
#: whose descriptors do not come from this detector (another SIFT implementation, another
#: descriptor normalization, another detector), or a view of an unmapped place
FEW_MATCHES_MIN_KEYPOINTS = 200
FEW_MATCHES_FRACTION = 0.02


def make_detector(kind: str = "orb", n_features: int = 2000) -> Any:
    """OpenCV feature detector/descriptor: ``orb`` (binary, Hamming) or ``sift`` (float, L2)."""
    kind = kind.lower()
    if kind == "orb":
        return cv2.ORB_create(
            nfeatures=int(n_features), scaleFactor=1.2, nlevels=8, fastThreshold=10
        )
    if kind == "sift":
        return cv2.SIFT_create(nfeatures=int(n_features))
    raise ValueError(f"unknown feature type {kind!r}; expected 'orb' or 'sift'")


def _norm(kind: str) -> int:
    return cv2.NORM_HAMMING if kind.lower() == "orb" else cv2.NORM_L2


def _merge_landmarks(points: np.ndarray, radius: float) -> np.ndarray:
    """Landmark id per point: connected components of the ``radius`` neighbourhood graph."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    return labels.astype(np.int64)


def feature_map_from_views(
    views: Iterable[tuple[np.ndarray, Callable]],
    kind: str = "orb",
    n_features: int = 2000,
    merge_radius: float = 0.004,
    edge_margin_px: float = 2.0,
    descriptors_per_landmark: int = 1,
) -> FeatureMap:
    """Reconstruct a feature map from posed views with known depth.

    Args:
        views: iterable of ``(gray (H, W) uint8, backproject)``; ``backproject(uv (M, 2) px)``
            returns ``(X (M, 3) world points in metres, surface (M,) int: the surface each ray
            hits, < 0 for none)`` (a depth camera, a mesh, or a renderer's ray caster).
        kind: ``orb`` or ``sift``. n_features: features per view.
        merge_radius: observations closer than this (m) become one landmark.
        edge_margin_px: drop keypoints whose neighbours this far away hit another surface or
            nothing (depth discontinuities, silhouettes).
        descriptors_per_landmark: keep this many medoid descriptors per landmark (0 = all
            observations; more makes matching slower, rarely better for nearby views).
    Returns:
        :class:`FeatureMap`.
    Raises:
        ValueError: no features in any view.
    """
    det = make_detector(kind, n_features)
    pts, descs = [], []
    m = float(edge_margin_px)
    offsets = np.array([[0, 0], [m, 0], [-m, 0], [0, m], [0, -m]])
    for gray, backproject in views:
        kps, des = det.detectAndCompute(gray, None)
        if des is None or not kps:
            continue
        uv = np.array([k.pt for k in kps], dtype=float)
        probe = (uv[:, None, :] + offsets[None]).reshape(-1, 2)
        X, quad = backproject(probe)
        X = X.reshape(len(uv), 5, 3)
        quad = quad.reshape(len(uv), 5)
        ok = (quad[:, 0] >= 0) & (quad == quad[:, :1]).all(axis=1)
        pts.append(X[ok, 0])
        descs.append(des[ok])
    if not pts:
        raise ValueError("no features found in the map views")
    points = np.concatenate(pts)
    descriptors = np.concatenate(descs)
    labels = _merge_landmarks(points, merge_radius)
    if descriptors_per_landmark:
        keep = representative_descriptors(descriptors, labels, int(descriptors_per_landmark), kind)
        points, descriptors, labels = points[keep], descriptors[keep], labels[keep]
    return FeatureMap(points, descriptors, labels, kind.lower())


def representative_descriptors(
    des: np.ndarray, labels: np.ndarray, k: int, kind: str
) -> np.ndarray:
    """Indices (sorted, int64) of up to ``k`` medoid descriptors per landmark: those with the
    smallest summed distance (Hamming for ``orb``, L2 otherwise) to the landmark's other
    descriptors ``des`` (N, D); ``labels`` (N,) landmark of each row."""
    order = np.argsort(labels, kind="stable")
    bounds = np.flatnonzero(np.diff(labels[order])) + 1
    keep = []
    binary = kind.lower() == "orb"
    for grp in np.split(order, bounds):
        if len(grp) <= k:
            keep.extend(grp.tolist())
            continue
        d = des[grp]
        if binary:
            bits = np.unpackbits(d, axis=1).astype(np.int16)
            D = (bits[:, None, :] != bits[None, :, :]).sum(axis=2)
        else:
            D = np.linalg.norm(d[:, None, :].astype(float) - d[None, :, :], axis=2)
        keep.extend(grp[np.argsort(D.sum(axis=1), kind="stable")[:k]].tolist())
    return np.sort(np.array(keep, dtype=np.int64))


class FeatureFrontend(FrontendHooks):
    """Match each image's features to a :class:`FeatureMap` (ratio test, one match per
    landmark).

    Args:
        feature_map: the map (or a path to its ``.npz``).
        ratio: Lowe's ratio (best distance < ratio * best distance to another landmark).
        n_features: features detected per image. knn: neighbours searched per feature.
        matcher: ``bf`` (exact brute force, OpenCV ``BFMatcher``) or ``flann`` (approximate
            nearest neighbours, OpenCV ``FlannBasedMatcher``: four randomized k-d trees, for
            large float (SIFT) maps; the index is built once here).
        flann_checks: leaves FLANN visits per query (more: closer to brute force, slower).
            On the 100000-descriptor map of ``bench_feature_map`` 32 found 99 % of the
            matches of 64 in 56 % of the matching time, with rotation errors within the
            spread over frames (docs/feature_maps.md).

    Raises:
        ValueError: an unknown ``matcher``, or ``flann`` with a binary (ORB) map.

    ``process(image, camera) -> (points2d (N, 2), points3d (N, 3), ids (N,))``; the ids are
    landmark ids, ``last_scores`` holds ``1 - ratio`` per match (higher is better).

    ``few_match_frames`` counts the images with at least :data:`FEW_MATCHES_MIN_KEYPOINTS`
    keypoints of which fewer than :data:`FEW_MATCHES_FRACTION` matched the map (a map whose
    descriptors do not come from this detector gives that on every image); the first one
    leaves a warning for :meth:`pop_warning` (once per front end).
    """

    name = "features"

    def __init__(
        self,
        feature_map: FeatureMap | str | Path,
        ratio: float = 0.8,
        n_features: int = 2000,
        knn: int = 3,
        matcher: str = "bf",
        flann_checks: int = 32,
    ):
        if not isinstance(feature_map, FeatureMap):
            feature_map = FeatureMap.load(feature_map)
        self.map = feature_map
        self.ratio = float(ratio)
        self.knn = int(knn)
        self.detector = make_detector(feature_map.kind, n_features)
        self.train = np.ascontiguousarray(feature_map.descriptors)
        if matcher == "bf":
            self.matcher = cv2.BFMatcher(_norm(feature_map.kind), crossCheck=False)
        elif matcher == "flann":
            if feature_map.kind.lower() == "orb":
                raise ValueError("matcher 'flann' is for float (sift) maps; use 'bf' for orb")
            self.train = np.ascontiguousarray(self.train, dtype=np.float32)
            self.matcher = cv2.FlannBasedMatcher(
                dict(algorithm=1, trees=4), dict(checks=int(flann_checks))
            )
            self.matcher.add([self.train])
            self.matcher.train()
        else:
            raise ValueError(f"unknown matcher {matcher!r}; expected 'bf' or 'flann'")
        self.matcher_name = matcher
        self.last_scores = np.zeros(0)
        self.few_match_frames = 0
        self._few_warned = False
        self._warning: str | None = None

    def pop_warning(self) -> str | None:
        """The warning left by the first few-matches image (see the class doc), once; None
        when there is none (or it was taken already)."""
        text, self._warning = self._warning, None
        return text

    def _count_matches(self, n_keypoints: int, n_matches: int) -> None:
        """Count an image of ``n_keypoints`` keypoints with ``n_matches`` map matches as a
        few-matches image (class doc); the first leaves the warning."""
        if n_keypoints < FEW_MATCHES_MIN_KEYPOINTS or n_matches >= (
            FEW_MATCHES_FRACTION * n_keypoints
        ):
            return
        self.few_match_frames += 1
        if not self._few_warned:
            self._few_warned = True
            self._warning = (
                f"feature map: {n_matches} of {n_keypoints} {self.map.kind.upper()} keypoints "
                "of an image matched the map; if this goes on, the map's descriptors do not "
                f"come from OpenCV's {self.map.kind.upper()} (another implementation, "
                "normalization or detector) or the camera sees an unmapped place (counted "
                "as frontend_few_match_frames; warned once)"
            )

    @classmethod
    def from_file(cls, path: str | Path, **kw: Any) -> FeatureFrontend:
        return cls(FeatureMap.load(path), **kw)

    def process(
        self,
        image: np.ndarray,
        camera: CameraModel | None = None,
        encoding: str = "rgb8",
    ) -> Correspondences:
        """Correspondences of one image (:class:`~rs_localizer.correspondences.Correspondences`
        with the scores ``1 - ratio``; pixels stay distorted; ``camera`` is unused: every
        image alone)."""
        empty = Correspondences(
            np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0)
        )
        self.last_scores = np.zeros(0)
        gray = to_gray(image, encoding)
        kps, des = self.detector.detectAndCompute(gray, None)
        if des is None or not kps:
            return empty
        found = self._match(des)
        self._count_matches(len(kps), len(found[0]))
        if not len(found[0]):
            return empty
        q, t, s = found
        lm = self.map.landmark_ids
        uv = np.array([kps[i].pt for i in q], dtype=float)
        self.last_scores = s
        return Correspondences(uv, self.map.points[t], lm[t], self.last_scores)

    def _match(self, des: np.ndarray) -> tuple:
        """Ratio-test matches of the descriptors ``des`` (K, D), one per landmark: (query
        rows (M,), map rows (M,), scores ``1 - ratio`` (M,))."""
        lm = self.map.landmark_ids
        best_q, best_t, best_s = [], [], []
        if self.matcher_name == "flann":
            found = self.matcher.knnMatch(np.asarray(des, np.float32), k=self.knn)
        else:
            found = self.matcher.knnMatch(des, self.train, k=self.knn)
        for q, nbrs in enumerate(found):
            if not nbrs:
                continue
            first = nbrs[0]
            second = next((n for n in nbrs[1:] if lm[n.trainIdx] != lm[first.trainIdx]), None)
            if second is None or second.distance <= 0:
                continue
            r = first.distance / second.distance
            if r < self.ratio:
                best_q.append(q)
                best_t.append(first.trainIdx)
                best_s.append(1.0 - r)
        if not best_q:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        q = np.array(best_q)
        t = np.array(best_t)
        s = np.array(best_s)
        # one match per landmark: keep the best-scored
        order = np.argsort(-s, kind="stable")
        _, first = np.unique(lm[t[order]], return_index=True)
        keep = np.sort(order[first])
        return q[keep], t[keep], s[keep]
