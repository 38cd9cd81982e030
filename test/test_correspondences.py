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
