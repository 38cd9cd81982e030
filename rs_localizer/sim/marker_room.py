"""A room with square markers and a hand-held rolling-shutter walk-through, with exact ground
truth, as detections (no images): data for the marker mapper's tests and benchmark.

The room is 6 x 5 x 3 m by default (world z up, origin in a floor corner); markers of mixed
sizes hang on the four walls at irregular positions, heights and in-plane angles, some tilted
out of the wall, one lies on the floor. The camera walks a circle in the middle of the room,
turns once around and looks up and down (angular speed up to ~2 rad/s) (:class:`RoomWalk`);
a mapping video may open in front of the anchor marker, looking at it from several directions
(:class:`AnchorSweep`); a robot driving a loop at 0.4 m height gives a second video through
the same room (:class:`RobotDrive`); a hand-held video from one spot (:class:`OneSpot`) sees
the far markers from one direction only. Every corner is projected with the camera pose at the
capture time of its own line, through the lens distortion
(:func:`rs_localizer.sim.trajectory.project_rs`), then Gaussian pixel noise is added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import CameraModel
from ..geometry import matrix_to_rotvec, rotvec_to_matrix
from .trajectory import R_FORWARD, project_rs

__all__ = [
    "AnchorSweep",
    "MarkerRoom",
    "OneSpot",
    "RobotDrive",
    "RoomWalk",
    "make_front_room",
    "make_marker_room",
    "room_camera",
    "simulate_detections",
    "view_dependent_error",
]

SIZES = (0.12, 0.16, 0.2, 0.3)


def room_camera(readout_time: float = 0.03, line_delay: float | None = None) -> CameraModel:
    """640x480 camera, fx = fy = 500 px (65 deg horizontal field of view), mild barrel
    distortion, ``readout_time`` seconds top to bottom (or ``line_delay`` s per row)."""
    K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
    ld = readout_time / 480 if line_delay is None else line_delay
    return CameraModel(K=K, D=np.array([-0.04, 0.01, 0.0, 0.0, 0.0]), line_delay=ld)


@dataclass(frozen=True)
class MarkerRoom:
    """Markers: ``ids`` (M,), ``sides`` (M,) m, ``R`` (M, 3, 3) marker -> world, ``p`` (M, 3)
    centres (m). Marker 0 faces the camera's first view (the natural anchor)."""

    ids: np.ndarray
    sides: np.ndarray
    R: np.ndarray
    p: np.ndarray

    def corners(self) -> dict:
        """id -> (4, 3) world corners in ArUco order (TL, TR, BR, BL)."""
        out = {}
        for i, s, R, p in zip(self.ids, self.sides, self.R, self.p, strict=True):
            h = s / 2
            loc = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
            out[int(i)] = loc @ R.T + p
        return out


def _wall_frame(normal: np.ndarray) -> np.ndarray:
    """Marker -> world rotation for a marker whose face points along ``normal`` with its y
    axis up (z world) when the wall is vertical."""
    z = normal / np.linalg.norm(normal)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def make_marker_room(
    num_markers: int = 28, seed: int = 0, size: tuple = (6.0, 5.0, 3.0), anchor_side: float = 0.3
) -> MarkerRoom:
    """``num_markers`` markers (>= 6) in a room of ``size`` (x, y, z) metres: marker 0 (side
    ``anchor_side``) on the wall at x = size[0] facing the start view, one on the floor, the
    rest spread evenly (jittered) along the four walls, heights from 0.5 m to 0.6 m below the
    ceiling, in-plane angles up to 180 deg, a third tilted 15-35 deg out of the wall. Sides
    from 0.12 to 0.30 m.

    Raises:
        ValueError: for fewer than 6 markers.
    """
    if num_markers < 6:
        raise ValueError("the room needs at least 6 markers")
    rng = np.random.default_rng(seed)
    lx, ly, lz = size
    walls = [  # (inward normal, point on the wall, axis along the wall, length)
        (np.array([-1.0, 0, 0]), np.array([lx, 0, 0]), np.array([0, 1.0, 0]), ly),
        (np.array([1.0, 0, 0]), np.array([0.0, 0, 0]), np.array([0, 1.0, 0]), ly),
        (np.array([0, -1.0, 0]), np.array([0, ly, 0]), np.array([1.0, 0, 0]), lx),
        (np.array([0, 1.0, 0]), np.array([0, 0.0, 0]), np.array([1.0, 0, 0]), lx),
    ]
    Rs = [_wall_frame(np.array([-1.0, 0, 0]))]
    ps = [np.array([lx - 0.001, ly / 2 + 0.1, 1.45])]
    sides = [anchor_side]
    Rs.append(_wall_frame(np.array([0.0, 0, 1])) @ rotvec_to_matrix([0, 0, 0.7]))
    ps.append(np.array([lx / 2 + 1.3, ly / 2 - 0.2, 0.001]))
    sides.append(0.3)
    # positions: evenly spread along the perimeter (jittered), so that consecutive views share
    # markers
    n_wall = num_markers - 2
    along = (np.arange(n_wall) + rng.uniform(0.2, 0.8, n_wall)) * (2 * (lx + ly) / n_wall)
    order = [0, 2, 1, 3]  # walls in perimeter order: x = 6, y = 5, x = 0, y = 0
    while len(ps) < num_markers:
        j = len(ps) - 2
        u = along[j]
        for w in order:
            if u < walls[w][3]:
                break
            u -= walls[w][3]
        n, o, a, length = walls[w]
        u = float(np.clip(u, 0.35, length - 0.35))
        pos = o + a * u + np.array([0, 0, rng.uniform(0.5, lz - 0.6)])
        if min(np.linalg.norm(pos - q) for q in ps) < 0.3:
            pos[2] = lz - 0.1 - pos[2]
        R = _wall_frame(n) @ rotvec_to_matrix([0, 0, rng.uniform(-np.pi, np.pi)])
        if rng.random() < 1 / 3:  # tilted out of the wall about a random in-plane axis
            ax = rng.normal(size=2)
            ax = R[:, 0] * ax[0] + R[:, 1] * ax[1]
            R = rotvec_to_matrix(ax / np.linalg.norm(ax) * np.radians(rng.uniform(15, 35))) @ R
        side = float(rng.choice(SIZES))
        Rs.append(R)
        tilt_sin = np.sqrt(max(0.0, 1.0 - np.dot(R[:, 2], n) ** 2))
        ps.append(pos + n * (0.001 + side / 2 * tilt_sin))
        sides.append(side)
    return MarkerRoom(np.arange(num_markers), np.array(sides), np.array(Rs), np.array(ps))


def make_front_room(size: tuple = (5.0, 4.0, 2.6), side: float = 0.2) -> MarkerRoom:
    """A room's end seen from its middle: markers of ``side`` m on the front wall (x =
    size[0], 4 markers, ids 0-3; marker 0 the anchor), the two side walls (y = 0 and y =
    size[1], 2 each near the front, ids 4-7), the floor (2, ids 8-9) and one panel leaning
    back 25 deg from vertical near the front wall (id 10): a room whose markers fit more than
    one up direction (with x up the front and floor markers hang on "walls" and the side
    walls' are "floor" and "ceiling"). In-plane angles vary. Use with :class:`OneSpot` at
    ``spot=(1.0, size[1] / 2, 1.5)`` panning across the front wall."""
    lx, ly = size[:2]
    rng = np.random.default_rng(3)
    Rs, ps = [], []

    def add(normal, pos):
        R = _wall_frame(np.asarray(normal, float)) @ rotvec_to_matrix(
            [0, 0, rng.uniform(-np.pi, np.pi)]
        )
        Rs.append(R)
        ps.append(np.asarray(pos, float) + 0.001 * R[:, 2])

    for y, z in ((ly / 2, 1.5), (ly / 2 - 0.9, 1.1), (ly / 2 + 0.8, 1.7), (ly / 2 + 0.2, 0.7)):
        add([-1.0, 0, 0], [lx, y, z])
    for x, z in ((lx - 1.0, 1.3), (lx - 2.0, 1.6)):
        add([0, 1.0, 0], [x, 0.0, z])
        add([0, -1.0, 0], [x - 0.3, ly, z - 0.2])
    add([0, 0, 1.0], [lx - 1.6, ly / 2 - 0.4, 0.0])
    add([0, 0, 1.0], [lx - 1.1, ly / 2 + 0.5, 0.0])
    lean = rotvec_to_matrix([0, np.radians(-25.0), 0]) @ np.array([-1.0, 0, 0])
    add(lean, [lx - 0.4, ly / 2 - 1.2, 0.5])
    n = len(ps)
    return MarkerRoom(np.arange(n), np.full(n, side), np.array(Rs), np.array(ps))


@dataclass(frozen=True)
class RoomWalk:
    """Hand-held walk-through: the camera circles (radius 0.6 m) around the room's centre at
    1.4 m height with a bob, turns once around in ``duration`` seconds and looks around: yaw
    ``2 pi t / duration + 0.25 sin``, pitch and roll sinusoids. ``pose(t)`` is vectorized:
    (N, 3, 3) camera -> world, (N, 3) centre (m)."""

    duration: float = 5.0
    centre: tuple = (3.0, 2.5)
    yaw_wobble: float = 0.1
    yaw_wobble_hz: float = 1.2
    pitch: float = 0.25
    pitch_hz: float = 0.5

    def position(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        a = 2 * np.pi * t / self.duration
        return np.stack(
            [
                self.centre[0] + 0.6 * np.cos(a),
                self.centre[1] + 0.6 * np.sin(a),
                1.4 + 0.05 * np.sin(2 * np.pi * t),
            ],
            axis=-1,
        )

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        yaw = 2 * np.pi * t / self.duration + self.yaw_wobble * np.sin(
            2 * np.pi * self.yaw_wobble_hz * t
        )
        pitch = self.pitch * np.sin(2 * np.pi * self.pitch_hz * t) - 0.1
        roll = 0.05 * np.sin(2 * np.pi * 0.8 * t + 1.0)
        z = np.zeros_like(t)
        Rz = rotvec_to_matrix(np.stack([z, z, yaw], axis=-1))
        Ry = rotvec_to_matrix(np.stack([z, -pitch, z], axis=-1))
        Rx = rotvec_to_matrix(np.stack([roll, z, z], axis=-1))
        return Rz @ Ry @ Rx @ R_FORWARD

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.orientation(t), self.position(t)

    def max_angular_rate(self, fps: float = 30.0) -> float:
        """Largest angular speed (rad/s) over the walk, by finite differences."""
        t = np.linspace(0, self.duration, 2000)
        R = self.orientation(t)
        dt = t[1] - t[0]
        w = matrix_to_rotvec(np.swapaxes(R[:-1], 1, 2) @ R[1:]) / dt
        return float(np.max(np.linalg.norm(w, axis=1)))


@dataclass(frozen=True)
class RobotDrive(RoomWalk):
    """A robot driving one loop of an ellipse (semi-axes ``radii``, m) around ``centre`` in
    ``duration`` seconds with the camera at ``height`` m, looking along its heading turned
    ``look`` rad outwards (towards the walls) and tilted up by ``tilt`` rad, with a small yaw
    wobble: a second trajectory through the same room, lower and steadier than the hand-held
    walk. Same interface as :class:`RoomWalk`."""

    duration: float = 10.0
    radii: tuple = (1.2, 1.0)
    height: float = 0.4
    look: float = -0.6
    tilt: float = 0.2
    yaw_wobble: float = 0.05
    yaw_wobble_hz: float = 0.7

    def position(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        a = 2 * np.pi * t / self.duration
        return np.stack(
            [
                self.centre[0] + self.radii[0] * np.cos(a),
                self.centre[1] + self.radii[1] * np.sin(a),
                np.full_like(t, self.height),
            ],
            axis=-1,
        )

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        a = 2 * np.pi * t / self.duration
        heading = np.arctan2(self.radii[1] * np.cos(a), -self.radii[0] * np.sin(a))
        yaw = heading + self.look + self.yaw_wobble * np.sin(2 * np.pi * self.yaw_wobble_hz * t)
        z = np.zeros_like(t)
        Rz = rotvec_to_matrix(np.stack([z, z, yaw], axis=-1))
        Ry = rotvec_to_matrix(np.stack([z, np.full_like(t, -self.tilt), z], axis=-1))
        return Rz @ Ry @ R_FORWARD


@dataclass(frozen=True)
class OneSpot(RoomWalk):
    """A hand-held video from one spot: the camera stays near ``spot`` (x, y, height; m),
    shaking by about 2 cm, and pans its view from ``yaw_from`` to ``yaw_to`` (rad, world
    yaw of the optical axis) and back in ``duration`` seconds, with the hand-held yaw wobble
    of :class:`RoomWalk` (``yaw_wobble`` rad at ``yaw_wobble_hz``), looking ``pitch`` rad up
    and down: the far walls' markers are seen from one direction only. Same interface as
    :class:`RoomWalk`."""

    duration: float = 5.0
    spot: tuple = (0.7, 0.7, 1.5)
    yaw_from: float = -0.2
    yaw_to: float = 1.8
    pitch: float = 0.15

    def position(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        shake = 0.02 * np.stack(
            [np.sin(2 * np.pi * 0.9 * t), np.sin(2 * np.pi * 1.3 * t + 1), np.sin(3.7 * t)],
            axis=-1,
        )
        return np.asarray(self.spot, dtype=float) + shake

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        u = 0.5 - 0.5 * np.cos(2 * np.pi * t / self.duration)  # there and back
        yaw = self.yaw_from + (self.yaw_to - self.yaw_from) * u
        yaw = yaw + self.yaw_wobble * np.sin(2 * np.pi * self.yaw_wobble_hz * t)  # the hand
        pitch = self.pitch * np.sin(2 * np.pi * 0.4 * t) - 0.05
        roll = 0.04 * np.sin(2 * np.pi * 0.7 * t + 0.5)
        z = np.zeros_like(t)
        Rz = rotvec_to_matrix(np.stack([z, z, yaw], axis=-1))
        Ry = rotvec_to_matrix(np.stack([z, -pitch, z], axis=-1))
        Rx = rotvec_to_matrix(np.stack([roll, z, z], axis=-1))
        return Rz @ Ry @ Rx @ R_FORWARD


def view_dependent_error(
    marker_id: int, direction: np.ndarray, sigma_px: float, seed: int = 0, scale_rad: float = 0.35
) -> np.ndarray:
    """(4, 2) pixels: a detector's error on the four corners of marker ``marker_id`` seen
    from ``direction`` (3,) (unit vector from the marker to the camera, in the marker's
    frame). It is the same for the same viewpoint and changes smoothly as the viewpoint
    turns (over about ``scale_rad``): a marker's image seen again from the same place gives
    the same corners, so frames taken from one spot do not average it away, where views from
    other directions do. Each corner's error is a sum of three random plane waves over the
    viewing direction (rms ``sigma_px`` per axis; fixed by ``seed`` and the id)."""
    rng = np.random.default_rng([int(seed), int(marker_id), 77])
    k = rng.normal(scale=1.0 / scale_rad, size=(4, 3, 3))  # corner, wave, direction
    phase = rng.uniform(0, 2 * np.pi, size=(4, 3))
    amp = rng.normal(size=(4, 3, 2))
    wave = np.cos(k @ np.asarray(direction, dtype=float) + phase)  # (4, 3)
    return sigma_px * np.sqrt(2.0 / 3.0) * np.einsum("cw,cwa->ca", wave, amp)


@dataclass(frozen=True)
class AnchorSweep:
    """The camera in front of a marker (``target``: its centre, ``normal``: its face normal,
    world frame), ``distance`` m away, swaying ``lateral`` m left and right (and 0.25 m up and
    down) once in ``duration`` seconds while looking at the marker's centre: how a user opens a
    mapping video, so that the anchor is seen from several directions (views at an angle fix
    its tilt, which sets the orientation of the whole map). Same interface as
    :class:`RoomWalk`."""

    target: tuple
    normal: tuple
    distance: float = 1.0
    lateral: float = 0.7
    duration: float = 2.0

    def position(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        a = 2 * np.pi * t / self.duration
        n = np.asarray(self.normal, dtype=float)
        up = np.array([0.0, 0.0, 1.0])
        side = np.cross(up, n)
        side /= np.linalg.norm(side)
        return (
            np.asarray(self.target, dtype=float)
            + n * self.distance
            + np.sin(a)[..., None] * side * self.lateral
            + (0.25 * np.sin(2 * a))[..., None] * up
        )

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        z = np.asarray(self.target, dtype=float) - self.position(t)
        z /= np.linalg.norm(z, axis=-1, keepdims=True)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x, axis=-1, keepdims=True)
        return np.stack([x, np.cross(z, x), z], axis=-1)

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.orientation(t), self.position(t)


def simulate_detections(
    room: MarkerRoom,
    camera: CameraModel,
    walk: RoomWalk,
    num_frames: int = 120,
    fps: float = 30.0,
    noise_px: float = 0.4,
    seed: int = 0,
    min_side_px: float = 14.0,
    max_view_angle_deg: float = 70.0,
    corner_bias_px: float = 0.0,
    view_error_px: float = 0.0,
    view_seed: int = 0,
    readout_free: bool = False,
) -> tuple[list[tuple[float, dict[int, np.ndarray]]], dict[str, np.ndarray]]:
    """Detections of the room's markers along the walk.

    A marker is detected when all four corners project inside the image, its face is turned
    towards the camera (angle between its normal and the direction to the camera below
    ``max_view_angle_deg``) and its shortest projected side is at least ``min_side_px``.
    ``corner_bias_px`` moves every detected corner that far towards the centre of its marker's
    projected square along the diagonal (the inward bias of a subpixel corner detector on
    blurred images), before the noise. ``view_error_px`` adds a detector error that depends on
    the viewpoint (:func:`view_dependent_error`, rms per axis; ``view_seed`` fixes it: use
    the same for several videos of one room) before the noise.

    ``readout_free``: the same video taken with a global shutter: every corner projected with
    the camera pose at the frame's reference line (the frame's stamp), through the same lens,
    and nothing else changed: the same stamps, the same markers detected (decided on the
    rolling-shutter image), the same noise drawn, the same inward bias (along the diagonals of
    the readout-free square) and detector error. What the detections would allow if the
    shutter cost nothing: map it with ``camera`` at zero line delay.

    Returns:
        ``(detections, truth)``: a list of ``(stamp, {id: (4, 2) pixels})`` with ``stamp`` the
        reference line's capture time (s), and a dict with ``orientation`` (K, 3, 3) camera ->
        world, ``position`` (K, 3), ``angular_velocity`` (K, 3) rad/s and ``linear_velocity``
        (K, 3) m/s in the camera frame, at the reference line of each frame.
    """
    rng = np.random.default_rng(seed)
    corners = room.corners()
    t_ref_off = float(camera.line_time(camera.reference_line))
    out = []
    Rs, ps, ws, vs = [], [], [], []
    for k in range(num_frames):
        t0 = k / fps
        t_ref = t0 + t_ref_off
        R, p = walk.pose(np.array([t_ref]))
        R, p = R[0], p[0]
        dets = {}
        for i in room.ids:
            c = corners[int(i)]
            centre = room.p[i]
            view = p - centre
            cosang = np.dot(room.R[i][:, 2], view) / np.linalg.norm(view)
            if cosang < np.cos(np.radians(max_view_angle_deg)):
                continue
            uv, ok = project_rs(camera, walk, t0, c)
            if not ok.all():
                continue
            sides = np.linalg.norm(uv - np.roll(uv, 1, axis=0), axis=1)
            if sides.min() < min_side_px:
                continue
            if readout_free:  # every line read at the reference line's time (may fall just
                # outside the image where the rolling-shutter one does not)
                Xc = (c - p) @ R
                uv = camera.distort(Xc[:, :2] / Xc[:, 2:])
            d = uv - uv.mean(axis=0)
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            uv = uv - corner_bias_px * d + rng.normal(scale=noise_px, size=uv.shape)
            if view_error_px:
                u = room.R[i].T @ view / np.linalg.norm(view)
                uv = uv + view_dependent_error(int(i), u, view_error_px, view_seed)
            dets[int(i)] = uv
        out.append((t_ref, dets))
        h = 1e-5
        Ra, Rb = walk.orientation(np.array([t_ref - h, t_ref + h]))
        Rs.append(R)
        ps.append(p)
        ws.append(matrix_to_rotvec(Ra.T @ Rb) / (2 * h))
        pa, pb = walk.position(np.array([t_ref - h, t_ref + h]))
        vs.append(R.T @ (pb - pa) / (2 * h))
    truth = dict(
        orientation=np.array(Rs),
        position=np.array(ps),
        angular_velocity=np.array(ws),
        linear_velocity=np.array(vs),
    )
    return out, truth
