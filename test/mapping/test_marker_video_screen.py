"""Several videos of one place: the check that refuses a video of another place before the
map is built fits the videos' markers in common by the ones that agree, so a few markers one
video's initialization placed poorly do not make the same room look like another place.
Truth: the simulated room (rs_localizer.sim.marker_room)."""

import numpy as np

from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.mapping.marker_init import _consensus_fit
from rs_localizer.mapping.marker_model import fit_rigid
from rs_localizer.sim.marker_room import make_marker_room


def _layout(room, R, t, moved=(), by=0.0, seed=0):
    """The room's corners moved rigidly by ``(R, t)``, 1 cm noise, the ``moved`` markers
    shifted ``by`` m (placed poorly)."""
    rng = np.random.default_rng(seed)
    out = []
    for m, c in sorted(room.corners().items()):
        c = c @ R.T + t + rng.normal(0, 0.01, (4, 3))
        if m in moved:
            c = c + by * rng.normal(size=3) / np.sqrt(3)
        out.append(c)
    return out


def test_same_room_with_poorly_placed_markers_agrees():
    room = make_marker_room(20, seed=1)
    R = rotvec_to_matrix([0.2, -0.4, 1.1])
    dst = _layout(room, np.eye(3), np.zeros(3), seed=1)
    src = _layout(room, R, [1.0, -2.0, 0.5], moved=(3, 7, 11), by=1.5, seed=2)
    Rf, tf, per_marker, agree = _consensus_fit(src, dst, 0.25)
    assert np.linalg.norm(Rf @ [1.0, -2.0, 0.5] + tf) < 0.05
    assert agree.sum() == 17 and not agree[[3, 7, 11]].any()
    # the fit is the true motion back (the poorly placed markers do not turn it)
    ang = np.degrees(np.linalg.norm(matrix_to_rotvec(Rf @ R)))
    assert ang < 0.5 and np.all(per_marker[agree] < 0.05)
    # a plain least-squares fit of all the markers lies far off (what once refused it)
    S, D = np.concatenate(src), np.concatenate(dst)
    R0, t0 = fit_rigid(S, D)
    assert np.sqrt(np.mean(np.sum((S @ R0.T + t0 - D) ** 2, 1))) > 0.25


def test_another_room_with_the_same_ids_disagrees():
    room, other = make_marker_room(20, seed=1), make_marker_room(20, seed=9)
    dst = _layout(room, np.eye(3), np.zeros(3), seed=1)
    src = _layout(other, rotvec_to_matrix([0.0, 0.0, 0.7]), np.zeros(3), seed=2)
    _, _, _, agree = _consensus_fit(src, dst, 0.25)
    assert agree.sum() < 10
