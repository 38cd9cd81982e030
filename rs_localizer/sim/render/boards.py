"""Printable images of planar boards (:mod:`rs_localizer.maps.boards`), also the textures of
the synthetic board tests."""

from __future__ import annotations

import cv2
import numpy as np

from ... import cv_compat as cvc
from ...maps.boards import CharucoBoardModel, CheckerboardModel, TagBoard

__all__ = ["board_image"]


def board_image(
    board: CheckerboardModel | CharucoBoardModel | TagBoard,
    pixels_per_metre: float,
    margin_px: int = 0,
) -> np.ndarray:
    """Printable image of a planar board (also the texture of the synthetic tests).

    Args:
        board: :class:`CheckerboardModel` (full outer squares drawn), :class:`CharucoBoardModel`
            or a :class:`TagBoard` made by :meth:`TagBoard.grid`.
        pixels_per_metre: scale; the board's extent times it must be an integer (to 1e-6).
        margin_px: white margin (pixels) around the board.
    Returns:
        ``(image (H, W) uint8, A (3, 3))`` with ``A @ [x, y, 1]`` the pixel (centre convention:
        pixel ``(0, 0)`` covers ``[-0.5, 0.5]^2``) of board-frame point ``(x, y, 0)``.
    Raises:
        ValueError: a tag map (not a grid), or an extent that is not a whole number of pixels.
    """
    ppm, m = float(pixels_per_metre), int(margin_px)

    def whole(x, what):
        v = x * ppm
        if abs(v - round(v)) > 1e-6 or round(v) <= 0:
            raise ValueError(f"{what} of {x} m is {v} px at {ppm} px/m; need a whole number")
        return int(round(v))

    if isinstance(board, CheckerboardModel):
        sq = whole(board.square_size, "square")
        nx, ny = board.cols + 1, board.rows + 1
        cells = ((np.add.outer(np.arange(ny), np.arange(nx)) % 2) * 255).astype(np.uint8)
        img = np.kron(cells, np.ones((sq, sq), np.uint8))
        img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
        origin = m - 0.5 + sq  # inner corner 0 is one square in
    elif isinstance(board, CharucoBoardModel):
        w = whole(board.cols * board.square_size, "board width")
        h = whole(board.rows * board.square_size, "board height")
        whole(board.marker_size, "marker")
        img = cvc.board_image(board.cv_board, (w + 2 * m, h + 2 * m), m)
        origin = m - 0.5
    elif isinstance(board, TagBoard) and board.grid is not None:
        cols, rows, s, g, ids = board.grid
        w = whole(cols * s + (cols - 1) * g, "board width")
        h = whole(rows * s + (rows - 1) * g, "board height")
        whole(s, "tag")
        cvb = cvc.grid_board(cols, rows, s, g, board.dictionary, ids)
        img = cvc.board_image(cvb, (w + 2 * m, h + 2 * m), m)
        origin = m - 0.5
    else:
        raise ValueError("board_image needs a checkerboard, a charuco board or a tag grid")
    A = np.array([[ppm, 0, origin], [0, ppm, origin], [0, 0, 1.0]])
    return img, A
