"""How far a TagSLAM recording's reference poses are from what their own corners say, and what
the rig pose's stated covariance leaves out: ``python -m benchmarks.reference_fit --folder
PATH/test_N``.

Two references of one recording (:mod:`benchmarks.tagslam_data`,
:mod:`benchmarks.joint_reference`): TagSLAM's published rig poses on its final tag map and
extrinsics, and the joint solution's poses on its own map and mountings. On each reference's
map and mountings (taken as exact), every rig frame with tags in two or more cameras and a
reference pose is posed by the rig estimator
(:func:`~rs_localizer.estimation.rig.estimate_rig_pose`, :data:`RIG_OPTIONS`), then:

1. **The reference's own fit** (:func:`delta_chi2`): the corners' squared error in the
   distorted image at the reference's pose minus at the estimator's, over the corners' noise
   variance ``sigma^2`` (the estimator's squared error over ``2 N - 6``). A pose at the corners'
   best fit has about 0; a pose the corners reject has more than the 99.73 % quantile of a
   chi-square of 6 degrees of freedom (20.1). How many rig poses are within 3 sigma of the
   reference (rotation and position NEES, 3 degrees of freedom each, below the 99.73 %
   quantile) in the covariance the estimator states.
2. **The two references against each other** in that covariance: rig frames whose two
   reference poses are within 3 sigma of each other. Where they are not, no covariance of
   ours can be within 3 sigma of both.
3. **The tags' common shift**: the 4 corners of one tag in one image share part of their
   error (the tag's image shifted as a whole: a lens model, the detector, the map a little off
   where the tag is seen). Printed: at the joint solution, the correlation of two corners'
   errors of one tag, the shift's share of a corner's error variance, and the correlation of
   one tag's shift in one camera between consecutive rig frames (under 0.2 s apart: a slowly
   varying error, not noise); the rig poses within 3 sigma of each reference in the
   covariance the estimator states with the corners grouped by tag (``View.groups``: the
   shift's variance and the corners' own estimated from the frame's residuals,
   :func:`~rs_localizer.estimation.noise_model.shared_shift_covariance`) and in the one it
   states for independent corners (the views without groups).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import replace
from itertools import pairwise

import numpy as np
from scipy.stats import chi2

from benchmarks.joint_reference import recording, recording_parser, with_reference
from benchmarks.tagslam_data import RealRig
from rs_localizer.estimation.rig import RIG_OPTIONS, estimate_rig_pose
from rs_localizer.frames import Mounting

__all__ = ["corner_errors", "delta_chi2", "main", "measure"]

#: the 99.73 % quantiles of a chi-square of 3 and of 6 degrees of freedom
K3, K6 = chi2.ppf(0.9973, 3), chi2.ppf(0.9973, 6)


def corner_errors(
    rig: RealRig, views: dict, R: np.ndarray, C: np.ndarray, mounts: dict | None = None
) -> np.ndarray:
    """(N, 2) px: every corner of ``views`` (a rig frame's, camera -> ``(uv, X)``) projected at
    the rig pose ``x_rig = R X + C`` through ``mounts`` (camera -> ``(R, c)``, default
    ``rig``'s) and ``rig``'s cameras, minus its detection (the distorted image), in ``views``'
    order."""
    mounts = rig.mounts if mounts is None else mounts
    out = []
    for n, (uv, X) in views.items():
        Rm, cm = mounts[n]
        out.append(rig.cameras[n].project((X @ R.T + C) @ Rm.T + cm) - uv)
    return np.concatenate(out)


def delta_chi2(e_ref: np.ndarray, e_best: np.ndarray, n_free: int = 6) -> float:
    """The corners' squared error at a reference pose (``e_ref`` (N, 2) px) minus at the
    best fit (``e_best``), over the noise variance per image axis the best fit's residuals
    give (``sum e_best^2 / (2 N - n_free)``): chi-square of ``n_free`` degrees of freedom when
    the reference is the truth and the errors independent and Gaussian."""
    s_best = float((e_best**2).sum())
    s2 = s_best / max(2 * len(e_best) - n_free, 1)
    return (float((e_ref**2).sum()) - s_best) / s2


def _tag_shift_persistence(rig: RealRig) -> tuple[float, float, float]:
    """At ``rig``'s reference poses: the mean correlation of two corners' errors (x) of one
    tag in one image, the tags' shift's share of a corner's error variance, and the
    correlation of one tag's shift (its 4 corners' mean error, x and y pooled) in one camera
    between rig frames under 0.2 s apart."""
    E, seq = [], defaultdict(list)
    for s, views in rig.frames:
        if s not in rig.reference:
            continue
        e = corner_errors(rig, views, *rig.reference[s]).reshape(-1, 4, 2)
        E.append(e)
        k = 0
        for n, (uv, _) in views.items():
            for t, m in zip(rig.tag_ids[s][n], e[k : k + len(uv) // 4].mean(axis=1), strict=True):
                seq[(n, int(t))].append((s, m))
            k += len(uv) // 4
    E = np.concatenate(E)
    c = np.corrcoef(E[:, :, 0].T)
    corner_corr = float(c[np.triu_indices(4, 1)].mean())
    v = E.reshape(-1, 2).var(axis=0).sum()
    share = float((E.mean(axis=1).var(axis=0).sum() - v / 4) / (0.75 * v))
    a, b = [], []
    for track in seq.values():
        for (s0, m0), (s1, m1) in pairwise(track):
            if s1 - s0 < 0.2:
                a.append(m0)
                b.append(m1)
    a, b = np.array(a).ravel(), np.array(b).ravel()
    return corner_corr, share, float(np.corrcoef(a, b)[0, 1]) if len(a) > 2 else float("nan")


def measure(
    rig: RealRig, references: dict, estimates: dict | None = None, shift_share: float = 0.0
) -> dict:
    """On ``rig``'s map and mountings (exact; or ``estimates``: camera -> ``MountingEstimate``,
    calibrated mountings with their covariance and time offset std, as
    :func:`~benchmarks.real_rig_mountings.calibrated_rig_run` poses the rig), every rig frame with
    tags in two or more cameras and a pose in every reference of ``references`` (label ->
    stamp -> ``(R, C)``; the first: ``rig``'s own), posed twice: each corner's error its own
    (the views without groups) and the corners grouped by tag (:meth:`RealRig.views`: the
    covariance with the tags' shared shift; ``shift_share``: the options'
    ``correlated_noise.shift_share``, the shift's share of a corner's error variance in rig
    frames too few tags to tell it). Returns ``{"frames", "delta_chi2": (F,) of the
    first reference's pose (through the same mountings as the rig's), "within": label -> (F,)
    within 3 sigma in the independent corners' covariance, "within_groups": label -> (F,) in
    the covariance with the tags' shift, "between", "between_groups": (F,) the first two
    references' poses within 3 sigma of each other in either covariance}``."""
    from benchmarks.real_rig_mountings import _tracked_twist, within_3_sigma

    first, *_ = references
    shared = replace(RIG_OPTIONS.correlated_noise, shift_share=shift_share)
    options = replace(RIG_OPTIONS, correlated_noise=shared)
    out = {"delta_chi2": [], "within": defaultdict(list), "within_groups": defaultdict(list),
           "between": [], "between_groups": []}  # fmt: skip
    mountings, mounts = dict(rig.mountings), dict(rig.mounts)
    for n, e in (estimates or {}).items():
        s_t = e.time_offset_std if e.time_offset and np.isfinite(e.time_offset_std) else 0
        mountings[n] = Mounting(e.mount.R, e.mount.c, e.mount.covariance, s_t)
        mounts[n] = (e.mount.R, e.mount.c)
    last: list = []
    for stamp, views in rig.frames:
        if len(views) < 2 or any(stamp not in r for r in references.values()):
            continue
        grouped = rig.views(stamp, views, mountings)
        twist = _tracked_twist(last, stamp) if estimates else None
        e = estimate_rig_pose(grouped, options, twist=twist)
        plain = estimate_rig_pose([replace(v, groups=None) for v in grouped], RIG_OPTIONS,
                                  twist=twist)  # fmt: skip
        if not (e.success and plain.success) or e.covariance is None or plain.covariance is None:
            continue
        last = [*last[-1:], (stamp, e.model)]
        R, C = e.model.R, e.model.C
        cov, cov_g = np.asarray(plain.covariance)[:6, :6], np.asarray(e.covariance)[:6, :6]
        best = corner_errors(rig, views, R, C, mounts)
        ref_err = corner_errors(rig, views, *references[first][stamp], mounts)
        out["delta_chi2"].append(delta_chi2(ref_err, best))
        for label, ref in references.items():
            out["within"][label].append(within_3_sigma(cov, R, C, ref[stamp]))
            out["within_groups"][label].append(within_3_sigma(cov_g, R, C, ref[stamp]))
        a, b = list(references.values())[:2]
        Ra, Ca = a[stamp]
        out["between"].append(within_3_sigma(cov, Ra, Ca, b[stamp]))
        out["between_groups"].append(within_3_sigma(cov_g, Ra, Ca, b[stamp]))
    out["frames"] = len(out["delta_chi2"])
    return {k: (np.asarray(v) if isinstance(v, list) else {n: np.asarray(x) for n, x in v.items()})
            if k != "frames" else v for k, v in out.items()}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks.reference_fit --folder PATH/test_N [--calibrated]
    [--shift-share S] [--cache DIR]``: the module's three measurements on both references of
    the recording; ``--calibrated``: the rig posed with ``calibrate-rig``'s mountings and their
    covariance (the first of 20 and 8 inliers that calibrates every camera, on each
    reference's map, as ``benchmarks.joint_reference`` runs it) instead of the reference's
    mountings as exact; ``--shift-share``: the options' ``correlated_noise.shift_share`` for
    the rig frames with too few tags to tell the shift (default 0: none there)."""
    from benchmarks.real_rig_mountings import calibrate_every_camera

    ap = recording_parser(main.__doc__)
    ap.add_argument("--calibrated", action="store_true", help="calibrate-rig's mountings")
    ap.add_argument(
        "--shift-share", type=float, default=0.0,
        help="correlated_noise.shift_share: the tags' shift's share of a corner's error "
        "variance in rig frames with too few tags to tell it (default 0)",
    )  # fmt: skip
    a = ap.parse_args(argv)
    if (loaded := recording(a)) is None:
        return
    rig, sol = loaded
    joint = with_reference(rig, sol)
    corr, share, persist = _tag_shift_persistence(joint)
    print(
        f"{rig.name}: corner errors at the joint solution: two corners of one tag correlated "
        f"{corr:.2f} (x); the tags' common shift {100 * share:.0f} % of a corner's error "
        f"variance; one tag's shift in consecutive rig frames correlated {persist:.2f}"
    )
    for label, r, refs in (
        ("TagSLAM's", rig, {"TagSLAM's": rig.reference, "the joint solution's": joint.reference}),
        ("the joint solution's", joint,
         {"the joint solution's": joint.reference, "TagSLAM's": rig.reference}),
    ):  # fmt: skip
        est = calibrate_every_camera(r)[0] if a.calibrated else None
        m = measure(r, refs, est, a.shift_share)
        n, d = m["frames"], m["delta_chi2"]
        how = "calibrate-rig's mountings" if est else "mountings (exact)"
        fit = (
            f"its poses' delta chi2 over the rig estimator's: median {np.median(d):.1f}, beyond "
            f"{K6:.1f} (99.73 %, 6 dof) in {100 * np.mean(d > K6):.1f} %; "
            if est is None
            else ""
        )
        print(f"on {label} map and {how}, {n} rig frames{': ' + fit[:-2] if fit else ''}")
        print(
            "  the two references within 3 sigma of each other: "
            f"{100 * m['between_groups'].mean():.1f} % (corners grouped by tag), "
            f"{100 * m['between'].mean():.1f} % (independent corners)"
        )
        for ref in refs:
            print(
                f"  rig poses within 3 sigma of {ref} poses: "
                f"{100 * m['within_groups'][ref].mean():.1f} % (corners grouped by tag), "
                f"{100 * m['within'][ref].mean():.1f} % (independent corners)"
            )


if __name__ == "__main__":
    main()
