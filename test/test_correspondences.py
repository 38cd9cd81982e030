"""Correspondences' pixel array is ``points2d``; the former name ``pixels`` works and warns."""

import warnings

import numpy as np
import pytest

from rs_localizer.correspondences import Correspondences, FrontendHooks, accepts_pixels_keyword


def _rows():
    return np.arange(6.0).reshape(3, 2), np.ones((3, 3)), np.arange(3)


def test_points2d_is_the_pixel_array_without_a_warning():
    uv, xyz, ids = _rows()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = Correspondences(points2d=uv, points=xyz, ids=ids)
        assert c.points2d is uv and c.uv is uv and c.points is xyz and c.ids is ids
        a, b, i = c
        assert c[0] is uv and a is uv and b is xyz and i is ids and len(c) == 3
        FrontendHooks().observe(0, uv, None)


def test_pixels_keyword_and_attribute_are_deprecated_aliases():
    uv, xyz, _ = _rows()
    with pytest.warns(DeprecationWarning, match="points2d") as rec:
        c = Correspondences(pixels=uv, points=xyz)
    assert c.points2d is uv
    assert rec[0].filename == __file__  # (the warning names the caller's line)
    with pytest.warns(DeprecationWarning, match="points2d") as rec:
        assert c.pixels is uv
    assert rec[0].filename == __file__


def test_pixels_and_points2d_together_or_missing_rows_are_refused():
    uv, xyz, _ = _rows()
    with pytest.raises(TypeError), pytest.warns(DeprecationWarning):
        Correspondences(uv, xyz, pixels=uv)
    with pytest.raises(TypeError):
        Correspondences(points=xyz)
    with pytest.raises(TypeError):
        Correspondences(uv)


def test_observe_takes_the_deprecated_pixels_keyword():
    uv = _rows()[0]

    class Frontend:
        seen = None

        @accepts_pixels_keyword
        def observe(self, stamp_ns, points2d, feedback):
            self.seen = (stamp_ns, points2d, feedback)

    fe = Frontend()
    with pytest.warns(DeprecationWarning, match="points2d"):
        fe.observe(5, pixels=uv, feedback="e")
    assert fe.seen[0] == 5 and fe.seen[1] is uv and fe.seen[2] == "e"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fe.observe(6, points2d=uv, feedback=None)
        fe.observe(7, uv, None)
    assert fe.seen[0] == 7 and fe.seen[1] is uv
    with pytest.warns(DeprecationWarning):
        FrontendHooks().observe(0, pixels=uv, feedback=None)


def test_groups_are_checked_and_kept_with_their_rows():
    """``groups`` (one marker's corners: the marker's id) is one int64 per row, unpacking stays
    the 3-tuple, and :meth:`Correspondences.take` keeps each per-row field's rows in the order
    asked (indices or a mask), a field not one per row dropped."""
    uv = np.arange(16.0).reshape(8, 2)
    xyz = np.arange(24.0).reshape(8, 3)
    ids = np.arange(8) + 100
    scores = np.linspace(0.1, 0.8, 8)
    groups = np.array([7, 7, 7, 7, 3, 3, 3, 3], np.int32)
    c = Correspondences(uv, xyz, ids, scores, groups)
    assert c.groups.dtype == np.int64 and np.array_equal(c.groups, groups)
    a, b, i = c
    assert a is uv and b is xyz and i is ids
    assert Correspondences(uv, xyz).groups is None
    rows = np.array([6, 1, 4])
    t = c.take(rows)
    assert np.array_equal(t.points2d, uv[rows]) and np.array_equal(t.points, xyz[rows])
    assert np.array_equal(t.ids, ids[rows]) and np.array_equal(t.scores, scores[rows])
    assert t.groups.tolist() == [3, 7, 3]
    mask = np.array([False, True, False, False, True, True, False, False])
    m = c.take(mask)
    assert m.groups.tolist() == [7, 3, 3] and m.ids.tolist() == [101, 104, 105]
    # a field without one entry per row (scores of another length) is not indexed
    odd = Correspondences(uv, xyz, None, np.ones(3), groups).take(rows)
    assert odd.scores is None and odd.ids is None and odd.groups.tolist() == [3, 7, 3]
    assert Correspondences(uv, xyz).take(rows).groups is None
    for bad in (np.zeros(7, int), np.zeros(8), np.zeros((8, 1), int)):
        with pytest.raises(ValueError, match="groups"):
            Correspondences(uv, xyz, groups=bad)
    assert Correspondences(np.zeros((0, 2)), np.zeros((0, 3)), groups=[]).groups.shape == (0,)
