"""Marker maps, stage (5): the output frame (one anchor at its pose, a best fit to surveyed
markers, or the best-observed marker), the markers' poses and covariances moved into it with
the frame's own uncertainty propagated, and that uncertainty."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..geometry import matrix_to_rotvec, rotvec_to_matrix
from .marker_covariance import corner_shape_std, covariance_in_gauge
from .marker_model import MappingOptions, OutputFrame, fit_rigid, marker_corners_local
from .marker_problem import MarkerProblem


def _pose_vector_map(poses: dict, ids: list, x: np.ndarray) -> dict:
    """Marker poses with the perturbation ``x`` (6 per id: rotation vector, world axes left;
    centre) applied."""
    out = dict(poses)
    for i, m in enumerate(ids):
        R, p = poses[m]
        out[m] = (rotvec_to_matrix(x[6 * i : 6 * i + 3]) @ R, p + x[6 * i + 3 : 6 * i + 6])
    return out


def _output_transform(poses: dict, options: MappingOptions, gauge: int, sides: dict) -> tuple:
    """Rigid transform ``(R, t)`` from the adjustment's frame to the output frame, and the RMS
    corner residual (m) of the surveyed anchors (0 for one anchor)."""
    if options.anchors:
        ids = sorted(options.anchors)
        src = np.concatenate(
            [marker_corners_local(sides[m]) @ poses[m][0].T + poses[m][1] for m in ids]
        )
        dst = np.concatenate([np.asarray(options.anchors[m], float).reshape(4, 3) for m in ids])
        R, t = fit_rigid(src, dst)
        res = np.linalg.norm(src @ R.T + t - dst, axis=1)
        return R, t, float(np.sqrt(np.mean(res**2)))
    anchor = gauge if options.anchor is None else int(options.anchor)
    Rt, pt = options.anchor_pose if options.anchor_pose is not None else (np.eye(3), np.zeros(3))
    Ra, pa = poses[anchor]
    R = np.asarray(Rt, float) @ Ra.T
    return R, np.asarray(pt, float) - R @ pa, 0.0


def _propagate(poses: dict, ids: list, cov: np.ndarray, options, gauge, sides) -> tuple:
    """Marker poses and covariances in the output frame, and the frame's covariance.

    The adjustment holds the gauge marker fixed; the output frame is a function of the
    estimated markers (an anchor's pose, or a best fit to surveyed markers), so its own
    uncertainty enters every marker's: with ``y(x)`` the markers' poses in the output frame
    as a function of all adjusted markers' poses ``x`` (6 per marker), the covariance is
    ``A cov A^T`` with ``A = dy/dx`` (central differences). The frame's own uncertainty is
    that of the output frame against the rigid best fit of all markers' centres (the map as a
    whole), by the same propagation."""
    cent_ids = sorted(poses)
    all_out = sorted(poses)
    h = 1e-6

    def outputs(x: np.ndarray) -> np.ndarray:
        P = _pose_vector_map(poses, ids, x)
        R, t, _ = _output_transform(P, options, gauge, sides)
        y = []
        for m in all_out:
            Rm, pm = P[m]
            y.append(matrix_to_rotvec(R @ Rm @ R0_out[m].T))
            y.append(R @ pm + t)
        # the output frame against the best fit of all centres
        C = np.array([P[m][1] for m in cent_ids])
        Rb, tb = fit_rigid(C, np.array([poses[m][1] for m in cent_ids]))
        # frame -> adjustment frame is (R^T, -R^T t); map it by the best fit
        Rf = Rb @ R.T
        y.append(matrix_to_rotvec(Rf @ R0_frame.T))
        y.append(tb - Rb @ R.T @ t)
        return np.concatenate(y)

    R_, _, _ = _output_transform(poses, options, gauge, sides)
    R0_frame = R_.T
    R0_out = {m: R_ @ poses[m][0] for m in all_out}
    y0 = outputs(np.zeros(6 * len(ids)))
    A = np.empty((y0.size, 6 * len(ids)))
    for j in range(6 * len(ids)):
        dx = np.zeros(6 * len(ids))
        dx[j] = h
        A[:, j] = (outputs(dx) - outputs(-dx)) / (2 * h)
    S = A @ cov @ A.T
    out_cov = {m: S[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i, m in enumerate(all_out)}
    G = np.kron(np.eye(2), R_)  # (the frame's uncertainty on the output axes)
    frame_cov = G @ S[-6:, -6:] @ G.T
    return out_cov, frame_cov


def _best_observed(poses: dict, ids: list, cov: np.ndarray) -> int:
    """The marker whose pose the map fixes best: the smallest uncertainty of its pose
    against the map as a whole (the markers' poses moved by the rigid best fit of all centres
    onto the estimate, covariance by central differences as :func:`_propagate`), scored as
    the position variance the rotation's uncertainty causes at the map's median distance
    from it plus its own position variance (largest axes)."""
    all_ids = sorted(poses)
    cent = np.array([poses[m][1] for m in all_ids])
    R0 = {m: poses[m][0] for m in all_ids}

    def outputs(x: np.ndarray) -> np.ndarray:
        P = _pose_vector_map(poses, ids, x)
        C = np.array([P[m][1] for m in all_ids])
        Rb, tb = fit_rigid(C, cent)
        y = []
        for m in all_ids:
            y.append(matrix_to_rotvec(Rb @ P[m][0] @ R0[m].T))
            y.append(Rb @ P[m][1] + tb)
        return np.concatenate(y)

    h = 1e-6
    n = 6 * len(ids)
    A = np.empty((6 * len(all_ids), n))
    for j in range(n):
        dx = np.zeros(n)
        dx[j] = h
        A[:, j] = (outputs(dx) - outputs(-dx)) / (2 * h)
    S = A @ cov @ A.T
    best, score = all_ids[0], np.inf
    for i, m in enumerate(all_ids):
        r = np.median(np.linalg.norm(cent - poses[m][1], axis=1))
        blk = S[6 * i : 6 * i + 6, 6 * i : 6 * i + 6]
        sc = np.linalg.eigvalsh(blk[:3, :3])[-1] * r**2 + np.linalg.eigvalsh(blk[3:, 3:])[-1]
        if sc < score:
            best, score = m, sc
    return best


def frame_and_covariance(
    prob: MarkerProblem,
    sol: Any,
    poses: dict,
    options: MappingOptions,
    gauge: int,
    sides: dict,
    inconsistent: dict,
) -> dict:
    """Stages (4)-(5) of :func:`~rs_localizer.mapping.marker_map.map_markers`: the
    covariance of the markers in the gauge
    (:func:`~rs_localizer.mapping.marker_covariance.covariance_in_gauge`), the output frame
    (the best-observed marker chosen when no anchor is given; surveyed anchors checked
    against their residual) and the markers' poses and covariances in it. ``sol``: SciPy's
    ``least_squares`` result of ``prob``; ``poses``: id -> ``(R (3, 3), p (3,))`` of the
    markers in the adjustment's frame; ``sides``: id -> side (m); ``inconsistent``: ids left
    out of the map. Returns a dict of ``poses`` / ``cov`` (id -> output pose, (6, 6)),
    ``frame`` (:class:`OutputFrame`), ``transform`` ``(R, t)`` (adjustment frame -> output
    frame), ``gauge_poses`` (``poses``) and ``shape_std`` (id -> (4,),
    :func:`~rs_localizer.mapping.marker_covariance.corner_shape_std`). Raises ValueError for
    surveyed anchors that disagree."""
    ids, cov, rho = covariance_in_gauge(prob, sol, poses, options, gauge)
    kind = "surveyed" if options.anchors else "anchor" if options.anchor is not None else None
    if kind is None:
        kind = "best-observed"
        options = replace(options, anchor=_best_observed(poses, ids, cov))
    out_cov, frame_cov = _propagate(poses, ids, cov, options, gauge, sides)
    Ro, to, residual = _output_transform(poses, options, gauge, sides)
    if options.anchors:
        # what the map states for the surveyed markers' positions (rms per axis)
        stated = float(
            np.sqrt(np.mean([np.trace(out_cov[m][3:, 3:]) / 3 for m in options.anchors]))
        )
        bound = max(options.max_anchor_residual, 3 * stated)
        if residual > bound:
            raise ValueError(
                f"the surveyed anchors {sorted(options.anchors)} disagree with the video: RMS "
                f"corner residual {residual * 1000:.0f} mm after the best fit, above "
                f"{bound * 1000:.0f} mm (3x the {stated * 1000:.0f} mm the map states for them, "
                f"at least {options.max_anchor_residual * 1000:.0f} mm): a wrong pose or id, a "
                "moved marker, or a wrong marker size"
            )
    out_poses, covs = {}, {}
    for m in poses:
        if m in inconsistent:
            continue
        R, p = poses[m]
        out_poses[m] = (Ro @ R, Ro @ p + to)
        c = 0.5 * (out_cov[m] + out_cov[m].T)
        if m == options.anchor and kind == "anchor":
            c = np.zeros((6, 6))  # (the anchor's pose in its own frame is exact)
        covs[m] = c
    frame_std = np.sqrt(np.clip(np.diag(frame_cov), 0.0, None))
    frame = OutputFrame(
        kind,
        sorted(options.anchors) if options.anchors else [int(options.anchor)],
        float(np.degrees(frame_std[:3].max())),
        float(1e3 * frame_std[3:].max()),
        frame_cov,
        1e3 * residual,
        rho,
    )
    shape_std = corner_shape_std(poses, ids, cov, sides, out_poses)
    return dict(
        poses=out_poses,
        cov=covs,
        frame=frame,
        transform=(Ro, to),
        gauge_poses=poses,
        shape_std=shape_std,
    )
