"""Reference-pose errors: is the target's recorded pose off, rigidly, per cloud?

In a lab the target's pose comes from a tracking system or an extrinsic calibration
(the paper's Fig. 1: a target on a crane). Their errors move whole clouds rigidly, and
read as a sensor effect (an incidence or footprint effect) they would be the wrong
diagnosis. This module tests for them on the matched points.

A small rigid motion of the target, translation ``d`` (m) and rotation ``w`` (rad, about
the cloud's centroid ``g``), moves the surface point ``p = e u`` (expected range ``e``
along the unit ray ``u``) of a plane with normal ``n`` to a range
``e + n.(d + w x (p - g)) / (n.u)``: a range residual linear in the six parameters,
``a_d = n / (n.u)`` and ``a_w = ((p - g) x n) / (n.u)``. Per cloud these are fitted by
weighted least squares to the residual (per-material offset and sigma scale profiled,
points beyond OUTLIER_SIGMAS and grazing rays left out), and judged by the rule of
every candidate (``diagnosis``): the held-out gain (fitted on one half of each cloud's
points, scored on the other, both ways) in Gaussian nats per matched point, its z
over neighbourhood blocks, decisive at the family's z and at least MIN_PRACTICAL_GAIN.

A correct pose gains nothing (6 parameters per cloud against thousands of points).
The simulator never applies a pose error: it is a reference error, not a sensor effect.

The linear range change holds on smooth surfaces only: near a silhouette or a depth
step a moved target changes which surface a ray meets (or whether it meets one). So a
fitted correction is applied to the pose itself (``CorrectedPoses``: each cloud's rigid
motion composed with the recorded pose, ``PoseCorrection``) and the model is raycast
again; the fit is repeated on the re-matched residual and composed (Gauss-Newton,
``iterate``), until the step is small.

A per-cloud correction is six parameters, but a pose error need not have both parts: a
tracking system's position may jitter while its attitude holds (or the reverse). Each
part is claimed only if it passes the rule on its own, nested: the six-parameter
correction's held-out gain over the translation alone (the rotation's part) and over
the rotation alone (the translation's), on the same halves as the pose test
(``shown_parts``). Where only one part shows, the verdict, the summary's sizes and
``--effect pose_error --fit``'s report claim that part alone (``PoseError.parts``), the
other given as a bound (the six-parameter fit's part plus two standard errors, per
cloud), not as a size. Whether the pose is off stays the six-parameter test's, and the
correction applied stays the six-parameter fit (the best estimate; the part not shown
is within its bound): applied alone, a part not shown on the test's footing (grazing
rays left out) lost a tie with a clock offset on the rays it leaves out.

A reference pose that drifts within a cloud (a tracking system's lag: a rotation
growing over each scan) is a correction linear in time within the cloud: six more
parameters per cloud, the rate, ``a tau`` with tau = (t - t_c) / h_c the point's time
from the cloud's mean time over its half-span (``rate_columns``). Where the points
carry their own times (``rate=True``), the rate is kept only if it passes the same
rule on top of the rigid correction (held-out, nested: ``rate_supported``); then the
test, the correction and the re-cast use the rigid part and its rate
(``PoseCorrection.rate_*``).

A reference pose that drifts the same way in every cloud (a tracking pose sampled at
each cloud's start and held over the scan while the target moves) is one rigid
correction for the recording and one rate (``fit_reference_pose`` with
``constant=True``, ``rate=True``): the rate's columns are scaled by the time since the
cloud's stamp, on one time base for the recording, read at the pose's samples
(``ScanClock``); the rate is tested on the part of that time the direction does not fix
(``beyond_direction``) and kept if it passes the rule on top of the rigid correction
held out, and the drifting correction against none (``constant_rate_supported``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, TypeVar

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.pose import Poses

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.diagnose.features import block_mean_z
from lidar_sim_ros.compare.diagnose import face_transfer, range_alone
from lidar_sim_ros.compare.diagnose.scan_clock import ScanClock, beyond_direction

OUTLIER_SIGMAS = 5.0      # residuals beyond this many sigma are not fitted (edges, outliers)
MIN_COS = 0.2             # |n.u| below this: grazing rays, range too sensitive to the pose
MIN_CLOUD_POINTS = 60     # a cloud needs this many usable points for its six parameters
RIDGE = 1e-2              # relative ridge of the correction applied: damps motions the data barely see (about a cylinder's long axis)
CONSTANT_RIDGE = 1e-6     # the same for one correction for all the clouds, fitted on every
                          # cloud's points: the test's (1e-4 held a 1 deg mount tilt at
                          # 1.5 deg and 12.4 cm for 1.0 and 14.05)
TEST_RIDGE = 1e-6         # relative ridge of the held-out test (the rule's footing, as before the re-cast)
HALVES_SEED = 61          # the held-out test's random halves: default_rng([seed, HALVES_SEED])


@dataclass(frozen=True)
class PoseError:
    """Per-cloud rigid corrections of the reference pose and their held-out gain."""

    clouds: np.ndarray            # (C,) cloud indices
    t_s: np.ndarray               # (C,) mean point time of each cloud (s, recording clock)
    translation_m: np.ndarray     # (C, 3) lidar frame: the target is really here + this
    rotation_deg: np.ndarray      # (C, 3) rotation vector (deg), lidar frame, about the centroid
    gain: float                   # held-out nats per matched point
    z: float
    significant: bool             # z >= z_crit and gain >= the practical margin
    correction_m: np.ndarray      # (N,) range correction per matched point (fit on all)
    centroid_m: np.ndarray | None = None   # (C, 3) lidar frame: each cloud's rotation centre
    passes: int = 0               # re-casts with the corrected pose (0: linear correction only)
    last_step: tuple[float, float] = (0.0, 0.0)   # the last pass's largest step (m, deg)
    # Within-cloud drift (``rate_columns``): tested where the points carry their own times.
    rate_tested: bool = False
    rate_supported: bool = False  # the rate passed the rule on top of the rigid correction
    rate_gain: float = 0.0        # its held-out gain over the rigid one, nats per matched point
    rate_z: float = 0.0
    # The rate decisive (z above the bound) but short of the margin: said, not claimed.
    rate_decisive: bool = False
    rate_translation_mps: np.ndarray | None = None   # (C, 3) m/s, lidar frame
    rate_rotation_deg_s: np.ndarray | None = None    # (C, 3) deg/s, rotation vector rate
    t_centre_s: np.ndarray | None = None             # (C,) tau = 0 (s)
    half_span_s: np.ndarray | None = None            # (C,) tau = +-1 (s)
    # One rigid correction for all the clouds (``fit_reference_pose(constant=True)``):
    # an extrinsic calibration or tracking-frame error, the same in every cloud.
    constant: bool = False
    # The constant correction was fitted jointly with the material offsets and took
    # their common offset (``explains_common_offset``): a translation along the line of
    # sight, which every material's range follows as a range offset of the sensor's would.
    joint: bool = False
    # Reported on the raycast footing though its own test fails
    # (``diagnosis.Diagnosis.weigh_line_of_sight``): the candidates it explains and the
    # closest of its fitted margins over them (nats/point, each parameter charged a nat).
    raycast: dict | None = None
    # The constant correction was fitted with the materials at their configured ranges
    # and took the materials' differing offsets (``explains_material_offsets``): a
    # target whose faces are each one material, moved across the line of sight.
    through_materials: bool = False
    # One correction for the recording with a rate (``constant_rate_supported``): tau on
    # this time base within each cloud's scan; t_centre_s and half_span_s its centre and
    # half-span (one row, s after the stamp).
    scan: ScanClock | None = None
    # Whether ``gain`` and ``z`` are the drifting correction's: False where the rate was
    # supported on every matched point (the correction reported) but not on the test's
    # sample, whose gain is then the rigid correction's.
    rate_in_test: bool = True
    # One rate for the recording that passed its own test but not beyond a range offset of
    # the sensor growing over each scan (``range_over_scan``): the two cannot be told
    # apart (its figures; None where not asked or told apart).
    scan_tie: dict | None = None
    # Per cloud: one range offset per cloud (a sensor's range offset changing between
    # clouds, ``per_cloud_offset_columns``), its held-out gain and z, and the rigid
    # correction's gain over it (nested, on the same halves). A correction that gains
    # nothing beyond it moves the clouds only as a range offset of the sensor would.
    offset_gain: float = 0.0
    offset_z: float = 0.0
    beyond_offset_gain: float = 0.0
    beyond_offset_z: float = 0.0
    # Its test passed, but the correction it converges to, applied exactly, would gain
    # less than the practical margin (``applied_gain``): not reported (its figures).
    too_small: dict | None = None
    # Its test passed on top of an effect --fit left at its search bound: the residual it
    # takes may be the rest of that effect (``run.pose_beyond_a_bound``): not reported
    # (which effects, and its test's figures).
    left_by_bound: dict | None = None
    # Its test passed beside a named range term that stands in for a bias of range alone
    # (``run.pose_beside_a_stand_in``): what the stand-in leaves is the rest of that bias,
    # which a per-cloud pose takes too: not reported (the stand-in, its test's figures).
    left_by_stand_in: dict | None = None
    # A function of range alone on the same halves, and the pose on top of it
    # (``range_alone.PoseAgainstRange``): a range error of the sensor that follows range
    # moves the clouds of an approach as a per-cloud pose does.
    against_range: 'range_alone.PoseAgainstRange | None' = None
    # Its test passed, but not beyond a function of range alone
    # (``run.pose_against_range_alone``): not reported (the outcome, its test's figures).
    left_to_range: dict | None = None
    # Its test passed alone, but fails on top of lasers' pointing offsets that gain more
    # and were set aside for their shape (``run.pose_left_to_pointing``): not reported
    # (the offsets' name, the pose on top of them, its test's figures).
    left_to_pointing: dict | None = None
    # Which parts of the per-cloud correction the data show (``shown_parts``): 'both',
    # 'translation' (no rotation shown: the correction is a translation per cloud),
    # 'attitude' (a rotation per cloud only) or 'either' (the whole passes, neither part
    # beyond the other: which cannot be told); and its figures (None: not tested).
    parts: str = 'both'
    parts_test: dict | None = None
    # One correction for the recording whose test passed on random halves, asked then
    # across the surfaces' orientations
    # (``face_transfer.across_orientations``: fitted on the surfaces facing some ways,
    # held out on the others); where some group loses by the rule the correction is no
    # rigid motion every surface agrees on, and its test is marked failed (the figures).
    across_faces: dict | None = None
    # The same for a supported rate per cloud, on top of the rigid part (its bounds over
    # the scan).
    rate_parts: str = 'both'
    rate_parts_test: dict | None = None
    # What the target's outline says of the correction (``silhouette``, asked where a
    # pose is about to be reported: ``run.pose_on_silhouette``), and, where the edges
    # contradict it or do not support it, the same figures with its test's: not reported.
    silhouette: dict | None = None
    left_to_edges: dict | None = None

    @property
    def size_cm(self) -> float:
        """RMS over clouds of the translation's length (cm); 0 where the data do not show
        it (``parts`` 'attitude': the correction applied keeps it, within its bound)."""
        if self.parts == 'attitude':
            return 0.0
        if self.parts == 'translation' and 'translation_alone_cm' in (self.parts_test or {}):
            return float(self.parts_test['translation_alone_cm'])
        return float(100 * np.sqrt(np.mean(np.sum(self.translation_m ** 2, axis=1))))

    @property
    def size_deg(self) -> float:
        """RMS over clouds of the rotation angle (deg); 0 where the data do not show it
        (``parts`` 'translation')."""
        if self.parts == 'translation':
            return 0.0
        if self.parts == 'attitude' and 'rotation_alone_deg' in (self.parts_test or {}):
            return float(self.parts_test['rotation_alone_deg'])
        return float(np.sqrt(np.mean(np.sum(self.rotation_deg ** 2, axis=1))))

    @property
    def line_of_sight_share(self) -> float | None:
        """Share (0..1) of the per-cloud translations' mean square along each cloud's
        line of sight (the direction of its rotation centre); None without centres or a
        translation. Near 1 the correction moves the clouds toward or away from the
        sensor only, as a range offset of the sensor changing from cloud to cloud does."""
        if self.centroid_m is None or not len(self.translation_m):
            return None
        c = np.asarray(self.centroid_m, float).reshape(-1, 3)
        t = np.asarray(self.translation_m, float).reshape(-1, 3)
        norm = np.linalg.norm(c, axis=1, keepdims=True)
        total = float(np.sum(t ** 2))
        if total <= 0 or len(c) != len(t) or not np.all(norm > 0):
            return None
        along = np.einsum('ij,ij->i', t, c / norm)
        return float(np.sum(along ** 2) / total)

    @property
    def n_params(self) -> int:
        """Parameters of the correction: six for all the clouds (``constant``), else six
        per cloud; twelve with a supported rate."""
        if self.constant:
            return 12 if self.rate_supported else 6
        return 6 * len(self.clouds) * (2 if self.rate_supported else 1)

    @property
    def span_s(self) -> float:
        return float(np.ptp(self.t_s)) if len(self.t_s) else 0.0

    @property
    def drift_cm(self) -> float:
        """RMS over clouds of the translation of the rotation centre over one cloud's
        span due to the rate (cm); 0 without a supported rate."""
        if (not self.rate_supported or self.rate_translation_mps is None
                or self.rate_parts == 'attitude'):
            return 0.0
        span = 2 * self.half_span_s[:, None]
        return float(100 * np.sqrt(np.mean(np.sum((self.rate_translation_mps * span) ** 2, 1))))

    @property
    def drift_deg(self) -> float:
        """RMS over clouds of the rotation over one cloud's span due to the rate (deg)."""
        if (not self.rate_supported or self.rate_rotation_deg_s is None
                or self.rate_parts == 'translation'):
            return 0.0
        span = 2 * self.half_span_s[:, None]
        return float(np.sqrt(np.mean(np.sum((self.rate_rotation_deg_s * span) ** 2, 1))))

    def as_dict(self) -> dict:
        share = self.line_of_sight_share
        return {'gain_per_matched_point': round(self.gain, 6), 'z': round(self.z, 3),
                'significant': self.significant, 'translation_rms_cm': round(self.size_cm, 3),
                'line_of_sight_share': None if share is None else round(float(share), 4),
                'rotation_rms_deg': round(self.size_deg, 4), 'span_s': round(self.span_s, 3),
                'clouds': [{'cloud': int(c), 't_s': round(float(t), 4),
                            'translation_m': [round(float(x), 5) for x in d],
                            'rotation_deg': [round(float(x), 5) for x in w]}
                           for c, t, d, w in zip(self.clouds, self.t_s, self.translation_m,
                                                 self.rotation_deg)],
                'constant': self.constant,
                **({} if self.constant else {'per_cloud_range_offset': {
                    'gain_per_matched_point': round(self.offset_gain, 6),
                    'z': round(self.offset_z, 3),
                    'pose_gain_beyond': round(self.beyond_offset_gain, 6),
                    'pose_z_beyond': round(self.beyond_offset_z, 3)}}),
                **({'joint_with_material_offsets': True} if self.joint else {}),
                **({'through_material_offsets': True} if self.through_materials else {}),
                **({'raycast': self.raycast} if self.raycast else {}),
                **({'too_small': self.too_small} if self.too_small else {}),
                **({'left_by_bound': self.left_by_bound} if self.left_by_bound else {}),
                **({'left_by_stand_in': self.left_by_stand_in}
                   if self.left_by_stand_in else {}),
                **({'against_range_alone': self.against_range.as_dict()}
                   if self.against_range is not None else {}),
                **({'left_to_range': self.left_to_range} if self.left_to_range else {}),
                **({'left_to_pointing': self.left_to_pointing}
                   if self.left_to_pointing else {}),
                **({'across_faces': self.across_faces} if self.across_faces else {}),
                **({'silhouette': self.silhouette} if self.silhouette else {}),
                **({'left_to_edges': self.left_to_edges} if self.left_to_edges else {}),
                **({'parts': {'reported': self.parts, **self.parts_test,
                              'applied': 'the six-parameter fit (per cloud above)'}}
                   if self.parts_test else {}),
                'recast_passes': self.passes,
                'last_step_m_deg': [round(float(x), 6) for x in self.last_step],
                'rate': self.rate_dict()}

    def rate_dict(self) -> dict | None:
        """The within-cloud drift: its test and, if supported, the rates per cloud."""
        if not self.rate_tested:
            return None
        out = {'supported': self.rate_supported, 'gain_over_rigid': round(self.rate_gain, 6),
               'z': round(self.rate_z, 3), 'decisive_short_of_margin': self.rate_decisive}
        if self.scan_tie is not None:
            out['tied_with_range_over_scan'] = self.scan_tie
        if self.rate_supported and self.rate_translation_mps is not None and self.constant:
            v = np.asarray(self.rate_translation_mps, float)[0]
            w = np.asarray(self.rate_rotation_deg_s, float)[0]
            out.update({'same_in_every_cloud': True,
                        **({'scan_time_base': self.scan.as_dict()} if self.scan else {}),
                        'drift_per_cloud_rms_cm': round(self.drift_cm, 3),
                        'drift_per_cloud_rms_deg': round(self.drift_deg, 4),
                        'drift_per_0_1_s_cm': round(10 * float(np.linalg.norm(v)), 3),
                        'drift_per_0_1_s_deg': round(0.1 * float(np.linalg.norm(w)), 4),
                        'translation_mps': [round(float(x), 5) for x in v],
                        'rotation_deg_s': [round(float(x), 4) for x in w]})
        elif self.rate_supported and self.rate_translation_mps is not None:
            if self.rate_parts_test:
                out['parts'] = {'reported': self.rate_parts, **self.rate_parts_test}
            out.update({'drift_per_cloud_rms_cm': round(self.drift_cm, 3),
                        'drift_per_cloud_rms_deg': round(self.drift_deg, 4),
                        'clouds': [{'cloud': int(c),
                                    'translation_mps': [round(float(x), 5) for x in v],
                                    'rotation_deg_s': [round(float(x), 4) for x in w]}
                                   for c, v, w in zip(self.clouds, self.rate_translation_mps,
                                                      self.rate_rotation_deg_s)]})
        return out

    def drift_words(self) -> str:
        """The drift of one rate for the recording: over the scan and per 0.1 s."""
        scan = 2 * float(self.half_span_s[0])
        per = 0.1 / scan if scan > 0 else 0.0
        return (f'by about {self.drift_cm:.1f} cm and {self.drift_deg:.2f} deg over its '
                f'{scan:.3f} s scan ({per * self.drift_cm:.1f} cm and '
                f'{per * self.drift_deg:.2f} deg per 0.1 s)')

    def words(self) -> str:
        if self.constant:
            c = (np.asarray(self.centroid_m, float).reshape(-1, 3)
                 if self.centroid_m is not None else np.zeros((0, 3)))
            # A rotation moves every point by its lever arm: the size is the seen points'
            # centroid's (a mount tilted 1 deg about the sensor moves a target 8 m away
            # by 14 cm there, its body origin 10 m away by 17 cm).
            where = (f' at the centroid of the points seen, {np.linalg.norm(c[0]):.1f} m from '
                     'the sensor, the rotation about it' if len(c) and np.all(np.isfinite(c[0]))
                     and np.linalg.norm(c[0]) > 0 else '')
            if self.rate_supported:
                return (f'the reference pose is off by about {self.size_cm:.1f} cm and '
                        f'{self.size_deg:.2f} deg on average over the scan{where}, and it '
                        f'drifts within each cloud {self.drift_words()}, the same in every '
                        'cloud (one correction for the whole recording and one rate over '
                        'the scan, from the point times: a tracking pose sampled once a '
                        'cloud and held while the target moves; held-out gain over '
                        f'the rigid correction {self.rate_gain:.4f} nats/point, '
                        f'z = {self.rate_z:.1f})')
            return (f'the reference pose is off by about {self.size_cm:.1f} cm and '
                    f'{self.size_deg:.2f} deg{where}, the same in every cloud (one rigid '
                    'correction for the whole recording: an extrinsic calibration or '
                    f'tracking-frame error){self.rate_short_words()}')
        text = (f'the reference pose is off by about {self.part_words()}, varying over '
                f'{self.span_s:.1f} s')
        text += self.rate_short_words()
        if self.rate_supported:
            text += (f', and it drifts within each cloud by about {self.rate_part_words()} '
                     'over the scan (a per-cloud rate, from the point times: held-out gain '
                     f'over a rigid correction {self.rate_gain:.4f} nats/point, '
                     f'z = {self.rate_z:.1f})')
        return text

    def rate_short_words(self) -> str:
        """A drift within each cloud that the point times show decisively but short of
        the margin that matters (``rate_decisive``): said, not claimed (the nineteenth
        holdout's lagdrift: a pose turning 0 -> 0.57 deg over each scan, said as its mean,
        the rate 0.0046 nats/point at z 9.6)."""
        if not self.rate_decisive:
            return ''
        return (f'; it may also drift within each cloud: a rate over the scan, from the '
                f'point times, gains {self.rate_gain:.4f} nats/point held out over the rigid '
                f'correction (z = {self.rate_z:.1f}), decisive but short of the margin that '
                'would matter, so not claimed (--effect pose_error --fit corrects the pose '
                'without it)')

    def rate_part_words(self) -> str:
        """A per-cloud rate's drift over the scan, its parts as the data show them."""
        return part_words(self.rate_parts, self.rate_parts_test, self.drift_cm,
                          self.drift_deg, ' within the cloud')

    def part_words(self) -> str:
        """The per-cloud correction's size, its parts as the data show them."""
        return part_words(self.parts, self.parts_test, self.size_cm, self.size_deg)


def part_words(parts: str, test: dict | None, size_cm: float, size_deg: float,
               within: str = '') -> str:
    """A correction's size (cm, deg), each part said only where the data show it
    (``shown_parts``: ``parts`` and its figures ``test``), the other as its bound (the
    part a six-parameter fit takes plus two standard errors); ``within``: ' within the
    cloud' for a rate."""
    test = test or {}
    if parts == 'translation':
        noun, other = 'rotation', test.get('rotation', {})
        said = (f'{size_cm:.1f} cm in translation alone (no rotation{within} shows: below '
                f'about {test.get("rotation_bound_deg", 0.0):.2f} deg')
    elif parts == 'attitude':
        noun, other = 'translation', test.get('translation', {})
        said = (f'{size_deg:.2f} deg in attitude alone, about the centroid of the points '
                f'seen (no translation of it{within} shows: below about '
                f'{test.get("translation_bound_cm", 0.0):.1f} cm')
    elif parts == 'either' and 'translation_alone_cm' in test:
        return (f'{test["translation_alone_cm"]:.1f} cm as a translation alone, or '
                f'{test["rotation_alone_deg"]:.2f} deg as a rotation alone about the centroid '
                f'of the points seen{within} (neither passes the rule beyond the other, so '
                'which of them cannot be told)')
    elif parts == 'either':
        return (f'{size_cm:.1f} cm and {size_deg:.2f} deg (a translation or a rotation'
                f'{within}: neither passes the rule beyond the other, so which of them '
                'cannot be told)')
    else:
        return f'{size_cm:.1f} cm and {size_deg:.2f} deg'
    return (f'{said}; a {noun} beside it gains {other.get("gain_beyond", 0.0):.4f} '
            f'nats/point held out, z = {other.get("z", 0.0):.1f}, short of the rule)')


PART_COLUMNS = {'both': slice(0, 6), 'either': slice(0, 6), 'translation': slice(0, 3),
                'attitude': slice(3, 6)}


def only_part(a: np.ndarray, parts: str) -> np.ndarray:
    """(N, 6) ``a`` (``design``) with the columns of the part not kept zeroed: a fit on it
    leaves that part at zero (``fit_clouds``' ridge holds an empty column there)."""
    if parts in ('both', 'either'):
        return a
    out = np.zeros_like(a)
    out[:, PART_COLUMNS[parts]] = a[:, PART_COLUMNS[parts]]
    return out


def part_bounds(a: np.ndarray, x: np.ndarray, sigma_m: np.ndarray, cloud: np.ndarray,
                use: np.ndarray, clouds: np.ndarray, at: int = 0) -> tuple[float, float]:
    """Upper bounds (RMS over clouds) of the translation (cm) and rotation (deg) per cloud
    the data could hide: the fit's part (``x``, (C, n) m and rad, the six columns from
    ``at`` of ``a``'s) plus two standard errors of it, from its normal equations
    (weights 1 / sigma^2)."""
    tr, rot = [], []
    for k, c in enumerate(clouds):
        sel = use & (cloud == c)
        if sel.sum() < MIN_CLOUD_POINTS * a.shape[1] // 6:
            continue
        aw = a[sel] / sigma_m[sel][:, None]
        d = np.clip(np.diag(np.linalg.pinv(aw.T @ aw)), 0.0, None)[at:at + 6]
        tr.append((np.linalg.norm(x[k, at:at + 3]) + 2 * np.sqrt(np.sum(d[:3]))) ** 2)
        rot.append((np.linalg.norm(x[k, at + 3:at + 6]) + 2 * np.sqrt(np.sum(d[3:6]))) ** 2)
    if not tr:
        return 0.0, 0.0
    return (float(100 * np.sqrt(np.mean(tr))), float(np.degrees(np.sqrt(np.mean(rot)))))


def shown_parts(a: np.ndarray, r: np.ndarray, s: np.ndarray, cloud: np.ndarray,
                use: np.ndarray, clouds: np.ndarray, prior: np.ndarray | None,
                half: np.ndarray, judged: Callable[[np.ndarray], tuple[float, float]],
                z_crit: float, min_gain: float, fixed: np.ndarray | None = None,
                part_z: float | None = None) -> tuple[str, dict | None]:
    """Which parts of a per-cloud correction ``a`` (N, 6: translation, rotation) the data
    show, on the pose test's held-out halves (``half``) and footing (``judged``: nats per
    matched point and z of a per-point gain): the six columns' gain over their
    translation alone (the rotation's part) and over their rotation alone (the
    translation's), each judged by the rule. 'both', 'translation', 'attitude', or
    'either' (neither beyond the other); and the figures, with each part's bound
    (``part_bounds``). ``fixed`` (N, 6): columns fitted beside every variant (the rigid
    correction, where ``a`` is its rate; ``prior`` then has twelve). Without ``fixed``,
    where the whole correction does not pass the rule there is nothing to split: 'both'
    and None. ``part_z``: the z each part needs (default and at least ``z_crit``)."""
    row = np.searchsorted(clouds, cloud)

    def columns(part: str) -> np.ndarray:
        return only_part(a, part) if fixed is None else np.hstack([fixed, only_part(a, part)])
    gains = {k: np.zeros(len(r)) for k in ('both', 'translation', 'attitude')}
    for k in (0, 1):
        test, train = use & (half != k), use & (half == k)
        for part, g in gains.items():
            cols = columns(part)
            x = fit_clouds(cols, r, s, cloud, train, clouds, prior, TEST_RIDGE)
            corr = np.einsum('ij,ij->i', cols, x[row])
            g[test] = heldout_gain(r[test], corr[test], s[test])
    whole = judged(gains['both'])
    if fixed is None and not (whole[1] >= z_crit and whole[0] >= min_gain):
        return 'both', None        # nothing to split: the whole does not pass
    rot = judged(gains['both'] - gains['translation'])
    tr = judged(gains['both'] - gains['attitude'])
    z_part = max(z_crit, part_z if part_z is not None else z_crit)
    shows_rot = rot[1] >= z_part and rot[0] >= min_gain
    shows_tr = tr[1] >= z_part and tr[0] >= min_gain
    parts = ('both' if shows_rot and shows_tr else 'translation' if shows_tr
             else 'attitude' if shows_rot else 'either')
    cols = columns('both')
    x = fit_clouds(cols, r, s, cloud, use, clouds, prior, TEST_RIDGE)
    bound_cm, bound_deg = part_bounds(cols, x, s, cloud, use, clouds,
                                      0 if fixed is None else fixed.shape[1])
    figures = {'rotation': {'gain_beyond': round(rot[0], 6), 'z': round(rot[1], 3),
                            'shown': bool(shows_rot)},
               'translation': {'gain_beyond': round(tr[0], 6), 'z': round(tr[1], 3),
                               'shown': bool(shows_tr)},
               'rotation_bound_deg': round(bound_deg, 4),
               'translation_bound_cm': round(bound_cm, 3),
               'whole': {'gain': round(whole[0], 6), 'z': round(whole[1], 3)}}
    if fixed is None:
        figures.update(part_alone_sizes(a, r, s, cloud, use, clouds, prior))
    return parts, figures


def part_alone_sizes(a: np.ndarray, r: np.ndarray, s: np.ndarray, cloud: np.ndarray,
                     use: np.ndarray, clouds: np.ndarray, prior: np.ndarray | None
                     ) -> dict[str, float]:
    """RMS over clouds of the per-cloud correction fitted as a translation alone (cm) and
    as a rotation alone about the centroid of the points seen (deg), with the applied
    correction's ridge (RIDGE). Where one part is shown alone, or neither beyond the other,
    these are its sizes: fitted beside each other the two share a motion the data see
    either way (a shift of a cylinder across its axis is a turn about the points' centroid
    too), and the ridge splits it at will (the eighteenth holdout's jitter of 5.5 cm RMS
    was said as 2.7 cm 'in translation alone')."""
    t = fit_clouds(only_part(a, 'translation'), r, s, cloud, use, clouds, prior, RIDGE)
    w = fit_clouds(only_part(a, 'attitude'), r, s, cloud, use, clouds, prior, RIDGE)
    return {'translation_alone_cm': round(float(100 * np.sqrt(np.mean(np.sum(
                t[:, :3] ** 2, axis=1)))), 3),
            'rotation_alone_deg': round(float(np.degrees(np.sqrt(np.mean(np.sum(
                w[:, 3:6] ** 2, axis=1))))), 4)}


def design(direction: np.ndarray, normal: np.ndarray, expected_m: np.ndarray,
           cloud: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 6) range change per unit translation (m) and rotation (rad) of the target,
    rotation about each cloud's centroid of points; and the usable rays (not grazing)."""
    u = np.asarray(direction, float)
    n = np.asarray(normal, float)
    p = u * np.asarray(expected_m, float)[:, None]
    nu = np.einsum('ij,ij->i', n, u)
    use = np.isfinite(nu) & (np.abs(nu) >= MIN_COS) & np.all(np.isfinite(p), axis=1)
    g = np.zeros_like(p)
    for c in np.unique(cloud):
        sel = (cloud == c) & use
        if sel.any():
            g[cloud == c] = p[sel].mean(axis=0)
    safe = np.where(use, nu, 1.0)[:, None]
    a = np.hstack([n / safe, np.cross(p - g, n) / safe])
    return np.where(use[:, None], a, 0.0), use


def range_over_scan(tau: np.ndarray, residual_m: np.ndarray, sigma_m: np.ndarray,
                    group: np.ndarray | None, train: np.ndarray) -> np.ndarray:
    """(N,) a range offset of the sensor growing linearly over the scan, the same in
    every cloud (m per unit ``tau``, fitted on the ``train`` points with one offset per
    material), at every point: what one rate of the pose for the recording is along the
    line of sight, which the sensor's range changing over each scan does alike."""
    t = np.asarray(tau, float)
    g = np.zeros(len(t), int) if group is None else np.asarray(group, int)
    labels, col = np.unique(g, return_inverse=True)
    w = np.where(train, 1.0 / np.asarray(sigma_m, float), 0.0)
    a = np.zeros((len(t), 1 + len(labels)))
    a[:, 0] = t
    a[np.arange(len(t)), 1 + col] = 1.0
    x = np.linalg.lstsq(a * w[:, None], residual_m * w, rcond=None)[0]
    return a @ x


def fit_clouds(a: np.ndarray, residual_m: np.ndarray, sigma_m: np.ndarray,
               cloud: np.ndarray, use: np.ndarray, clouds: np.ndarray,
               prior: np.ndarray | None = None, ridge: float = RIDGE,
               group: np.ndarray | None = None) -> np.ndarray:
    """(C, 6) weighted least-squares correction per cloud (zeros where too few points).
    The ridge pulls the total correction, ``prior`` (C, 6: already applied) plus the
    step returned, toward zero: a Gauss-Newton pass damps the same motions as the first.

    ``group`` (N,) ints, each point's material: the corrections are fitted jointly with
    one range offset per material shared by all the clouds (the likelihood's nuisance,
    ``likelihood.material_nuisance``), so a motion is fitted from what the offsets
    cannot take. Subtracting each material's offset first and fitting the rest would
    shrink every motion that moves a material's ranges by a common amount: a
    translation along the line of sight (every material alike) or along a target's
    axis seen on its end faces (one material each)."""
    n_par = a.shape[1]
    out = np.zeros((len(clouds), n_par))
    x0 = np.zeros((len(clouds), n_par)) if prior is None else np.asarray(prior, float)
    systems = []
    for k, c in enumerate(clouds):
        sel = use & (cloud == c)
        if sel.sum() < MIN_CLOUD_POINTS * n_par // 6:
            continue
        w = 1.0 / sigma_m[sel]
        aw = a[sel] * w[:, None]
        ata = aw.T @ aw
        # Per block of six (rigid, rate): the rate's columns are scaled by tau.
        lam = np.concatenate([np.full(6, ridge * np.trace(ata[j:j + 6, j:j + 6]) / 6)
                              for j in range(0, n_par, 6)])
        ata += np.diag(lam)
        rhs = aw.T @ (residual_m[sel] * w) - lam * x0[k]
        systems.append((k, sel, w, aw, ata, rhs))
    if group is None or not systems:
        for k, _, _, _, ata, rhs in systems:
            out[k] = range_alone.solve_or_lstsq(ata, rhs)
        return out
    # Joint: eliminate each cloud's motion (Schur complement) and solve for the
    # offsets of the materials with enough points; the others keep theirs.
    g = np.asarray(group)
    mats = [m for m in np.unique(g[use]) if np.sum(use & (g == m)) >= lk.MIN_MATERIAL_POINTS]
    col = np.full(int(g.max()) + 1, -1)          # each material's column, -1: none
    col[mats] = np.arange(len(mats))
    n_m = len(mats)
    lhs, rhs_m = np.zeros((n_m, n_m)), np.zeros(n_m)
    coupling = []
    for k, sel, w, aw, ata, rhs in systems:
        j = col[g[sel]]
        keep = j >= 0
        b = np.zeros((n_par, n_m))
        np.add.at(b.T, j[keep], aw[keep] * w[keep, None])
        d = np.bincount(j[keep], weights=w[keep] ** 2, minlength=n_m)
        e = np.bincount(j[keep], weights=residual_m[sel][keep] * w[keep] ** 2, minlength=n_m)
        inv_b = range_alone.solve_or_lstsq(ata, b)
        inv_r = range_alone.solve_or_lstsq(ata, rhs)
        lhs += np.diag(d) - b.T @ inv_b
        rhs_m += e - b.T @ inv_r
        coupling.append((k, inv_b, inv_r))
    try:
        offset = np.linalg.solve(lhs + 1e-12 * np.trace(lhs) * np.eye(n_m), rhs_m)
    except np.linalg.LinAlgError:
        offset = np.zeros(n_m)
    for k, inv_b, inv_r in coupling:
        out[k] = inv_r - inv_b @ offset
    return out


def fit_clouds_with(a: np.ndarray, shared: 'range_alone.RangeDesign',
                    residual_m: np.ndarray, sigma_m: np.ndarray, cloud: np.ndarray,
                    use: np.ndarray, clouds: np.ndarray, ridge: float = TEST_RIDGE
                    ) -> np.ndarray:
    """(N,) the range correction (m) of a per-cloud correction (columns ``a``) fitted
    by weighted least squares on the ``use`` points jointly with columns ``shared`` by
    every cloud (a function of range alone and the materials' intercepts,
    ``range_alone.range_fit``), at every point: each cloud's motion eliminated (Schur
    complement), the shared coefficients solved, then each cloud's. Light relative
    ridges on both blocks."""
    n_par, n_sh = a.shape[1], shared.size
    w_all = 1.0 / np.asarray(sigma_m, float)
    lhs, rhs_s = np.zeros((n_sh, n_sh)), np.zeros(n_sh)
    per = []
    for c in clouds:
        at = np.flatnonzero(use & (cloud == c))
        w, y = w_all[at], residual_m[at]
        bb, br = shared.gram(at, w), shared.cross(at, w, y)
        if len(at) < MIN_CLOUD_POINTS * n_par // 6:
            lhs += bb
            rhs_s += br
            continue
        aw = a[at] * w[:, None]
        ata = aw.T @ aw
        ata += np.diag(np.full(n_par, ridge * np.trace(ata) / n_par))
        ab, ar = shared.cross(at, w, a[at]).T, aw.T @ (y * w)
        inv_ab = range_alone.solve_or_lstsq(ata, ab)
        inv_ar = range_alone.solve_or_lstsq(ata, ar)
        lhs += bb - ab.T @ inv_ab
        rhs_s += br - ab.T @ inv_ar
        per.append((c, inv_ab, inv_ar))
    beta = range_alone.solve_ridged(lhs, rhs_s, range_alone.RANGE_RIDGE)
    out = shared.predict(beta)
    for c, inv_ab, inv_ar in per:
        sel = cloud == c
        out[sel] += a[sel] @ (inv_ar - inv_ab @ beta)
    return out


def time_scale(t_s: np.ndarray, cloud: np.ndarray,
               clouds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N,) tau = (t - t_c) / h_c of each point, and per cloud t_c (its points' mean
    time, s) and h_c (their largest distance from it, s; tau = 0 where h_c is 0)."""
    t = np.asarray(t_s, float)
    t_c = np.array([float(np.mean(t[cloud == c])) for c in clouds])
    h_c = np.array([float(np.max(np.abs(t[cloud == c] - m))) for c, m in zip(clouds, t_c)])
    k = np.searchsorted(clouds, cloud)
    with np.errstate(invalid='ignore', divide='ignore'):
        tau = np.where(h_c[k] > 1e-9, (t - t_c[k]) / h_c[k], 0.0)
    return tau, t_c, h_c


def rate_columns(a: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(N, 12): the rigid columns and the same scaled by tau, the correction's change
    over the cloud (a pose drifting linearly in time within it)."""
    return np.hstack([a, a * np.asarray(tau, float)[:, None]])


@dataclass(frozen=True)
class PoseCorrection:
    """A rigid correction per cloud of the recorded target pose, lidar frame:
    ``p' = R[c] p + t[c]`` for every point p of the target during cloud c. Clouds are
    told apart by time: each cloud's span of point times ``[t0_s, t1_s]``, split half-way
    between neighbours (``CorrectedPoses``)."""

    clouds: np.ndarray            # (K,) cloud indices, in time order
    t0_s: np.ndarray              # (K,) first point time of each cloud (s)
    t1_s: np.ndarray              # (K,) last point time (s)
    rotation: Rotation            # (K,) R[c]
    translation_m: np.ndarray     # (K, 3) t[c] (m)
    centroid_m: np.ndarray = field(default=None)   # (K, 3) reference point for reports
    # Within-cloud drift on top (``rate_columns``): at time t of cloud c, a further
    # rotation tau rate_rotvec_rad[c] about centroid_m[c] and translation tau rate_m[c],
    # tau = (t - t_centre_s[c]) / half_span_s[c]; None: none.
    rate_m: np.ndarray | None = None
    rate_rotvec_rad: np.ndarray | None = None
    t_centre_s: np.ndarray | None = None
    half_span_s: np.ndarray | None = None
    # One correction for the recording (one row) with a rate: tau on the recording's
    # time base within each cloud's scan (``ScanClock``), not the row's span.
    scan: ScanClock | None = None

    @classmethod
    def identity(cls, cloud: np.ndarray, t_s: np.ndarray) -> 'PoseCorrection':
        """No correction, for the clouds of the points ``cloud``/``t_s``."""
        clouds = np.unique(cloud)
        t0 = np.array([t_s[cloud == c].min() for c in clouds])
        t1 = np.array([t_s[cloud == c].max() for c in clouds])
        order = np.argsort(t0)
        k = len(clouds)
        return cls(clouds[order], t0[order], t1[order], Rotation.identity(k),
                   np.zeros((k, 3)), np.full((k, 3), np.nan))

    def compose(self, step: PoseError) -> tuple['PoseCorrection', tuple[float, float]]:
        """This correction followed by ``step``'s (a fit on the re-cast model: translation
        d and rotation w about its cloud's centroid g, ``p' = R_w (p - g) + g + d``); and
        the step's largest translation (m) and rotation (deg)."""
        pos = np.searchsorted(self.clouds, step.clouds)
        ok = (pos < len(self.clouds))
        ok[ok] = self.clouds[pos[ok]] == step.clouds[ok]
        rotvec = np.zeros((len(self.clouds), 3))
        move = np.zeros((len(self.clouds), 3))
        g = np.array(self.centroid_m, float, copy=True)
        rotvec[pos[ok]] = np.radians(step.rotation_deg[ok])
        rw = Rotation.from_rotvec(rotvec)
        if step.centroid_m is not None:
            g_step = np.zeros((len(self.clouds), 3))
            g_step[pos[ok]] = step.centroid_m[ok]
            move[pos[ok]] = step.translation_m[ok]
            move += g_step - rw.apply(g_step)
            first = ~np.isfinite(g[:, 0])
            g[first] = g_step[first]
        out = replace(self, rotation=rw * self.rotation,
                      translation_m=rw.apply(self.translation_m) + move, centroid_m=g)
        size = (float(np.max(np.linalg.norm(step.translation_m, axis=1), initial=0.0)),
                float(np.max(np.linalg.norm(step.rotation_deg, axis=1), initial=0.0)))
        if step.rate_supported and step.rate_translation_mps is not None:
            out = out._with_rate(step, pos, ok, g)
        return out, size

    def _with_rate(self, step: PoseError, pos: np.ndarray, ok: np.ndarray,
                   g: np.ndarray) -> 'PoseCorrection':
        """This correction with ``step``'s rate added (first order: rates are small),
        re-expressed about this correction's centroid (w x (g - g_step) more translation)."""
        k = len(self.clouds)
        rate_m = np.zeros((k, 3)) if self.rate_m is None else np.array(self.rate_m, float)
        rate_w = (np.zeros((k, 3)) if self.rate_rotvec_rad is None
                  else np.array(self.rate_rotvec_rad, float))
        t_c = np.zeros(k) if self.t_centre_s is None else np.array(self.t_centre_s, float)
        h_c = np.ones(k) if self.half_span_s is None else np.array(self.half_span_s, float)
        rows = pos[ok]
        h_step = step.half_span_s[ok]
        w = np.radians(step.rate_rotation_deg_s[ok]) * h_step[:, None]     # per unit tau
        d = step.rate_translation_mps[ok] * h_step[:, None]
        g_step = step.centroid_m[ok] if step.centroid_m is not None else g[rows]
        rate_w[rows] += w
        rate_m[rows] += d + np.cross(w, g[rows] - g_step)
        t_c[rows], h_c[rows] = step.t_centre_s[ok], h_step
        return replace(self, rate_m=rate_m, rate_rotvec_rad=rate_w, t_centre_s=t_c,
                       half_span_s=h_c, scan=step.scan if step.scan is not None else self.scan)

    def drift_at(self, k: np.ndarray, t_s: np.ndarray) -> tuple[Rotation, np.ndarray] | None:
        """The within-cloud part at times ``t_s`` of clouds (rows) ``k``: a rotation about
        each cloud's centroid and a translation, as (rotation, translation m); None
        without a rate."""
        if self.rate_m is None:
            return None
        h = self.half_span_s[k]
        tau = (self.scan.tau(t_s) if self.scan is not None else
               np.where(h > 1e-9, (np.asarray(t_s, float) - self.t_centre_s[k]) / np.where(
                   h > 1e-9, h, 1.0), 0.0))
        rot = Rotation.from_rotvec(self.rate_rotvec_rad[k] * tau[:, None])
        g = np.nan_to_num(np.asarray(self.centroid_m, float))[k]
        return rot, g - rot.apply(g) + self.rate_m[k] * tau[:, None]

    def at_time(self, t_s: np.ndarray) -> np.ndarray:
        """(N,) row of each time's cloud: the cloud whose span holds it, else the nearer
        neighbour (split half-way between one cloud's last and the next one's first time)."""
        edges = 0.5 * (self.t1_s[:-1] + self.t0_s[1:])
        return np.searchsorted(edges, np.asarray(t_s, float), side='right')

    def apply(self, position_m: np.ndarray, t_s: np.ndarray,
              rotation: Rotation | None = None) -> tuple[np.ndarray, Rotation | None]:
        """Points (or target positions) ``position_m`` ((N, 3) m, lidar frame) at times
        ``t_s`` moved by the correction of their cloud and its drift within the cloud;
        ``rotation`` (N target attitudes, or None) turned with them."""
        t = np.atleast_1d(np.asarray(t_s, float))
        k = self.at_time(t)
        rot = self.rotation[k]
        position = rot.apply(position_m) + self.translation_m[k]
        if rotation is not None:
            rotation = rot * rotation
        drift = self.drift_at(k, np.broadcast_to(t, (len(k),)))
        if drift is not None:
            r_d, t_d = drift
            position = r_d.apply(position) + t_d
            if rotation is not None:
                rotation = r_d * rotation
        return position, rotation

    def moved(self) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) motion of each cloud's reference point (m) and (K, 3) rotation vector
        (deg): the correction as the report states it (the target is really here + this)."""
        g = np.nan_to_num(np.asarray(self.centroid_m, float))
        return (self.rotation.apply(g) + self.translation_m - g,
                np.degrees(self.rotation.as_rotvec()))

    def params(self, clouds: np.ndarray, rate: bool = False) -> np.ndarray:
        """(len(clouds), 6) this correction as a fit's parameters (``moved``: translation
        of the reference point, m; rotation vector, rad); zeros for clouds it lacks.
        ``rate``: (len(clouds), 12), the within-cloud drift per unit tau after them."""
        out = np.zeros((len(clouds), 12 if rate else 6))
        moved, rotvec = self.moved()
        pos = np.clip(np.searchsorted(self.clouds, clouds), 0, max(len(self.clouds) - 1, 0))
        have = (self.clouds[pos] == clouds) if len(self.clouds) else np.zeros(len(clouds), bool)
        out[have, :6] = np.hstack([moved, np.radians(rotvec)])[pos[have]]
        if rate and self.rate_m is not None:
            out[have, 6:] = np.hstack([self.rate_m, self.rate_rotvec_rad])[pos[have]]
        return out


class CorrectedPoses:
    """A pose source (``core.pose.PoseSource``): ``base`` with ``correction`` applied,
    so that the model can be raycast with the corrected reference pose."""

    def __init__(self, base, correction: PoseCorrection):
        self.base, self.correction = base, correction

    def __getattr__(self, name):          # coverage, sample times: the base track's
        if name in ('base', 'correction'):   # not set yet (copy, unpickling)
            raise AttributeError(name)
        return getattr(self.base, name)

    def at(self, t_s: np.ndarray) -> Poses:
        poses = self.base.at(t_s)
        n = len(np.atleast_1d(np.asarray(t_s, float)))
        position = np.broadcast_to(poses.position_m.reshape(-1, 3), (n, 3)).copy()
        position, rotation = self.correction.apply(position, t_s, poses.rotation)
        return Poses(rotation, position)


S = TypeVar('S')
RECAST_PASSES = 3            # re-casts at most (Gauss-Newton passes after the first fit)
CONSTANT_RECAST_PASSES = 15  # the same for one correction for the recording (one raycast a pass)
RECAST_STEP_M = 5e-4         # a step below this and RECAST_STEP_DEG: converged
RECAST_STEP_DEG = 0.01


def iterate(first: PoseError, start: PoseCorrection, rematch: Callable[[PoseCorrection], S],
            refit: Callable[[S, PoseCorrection], PoseError], passes_max: int = RECAST_PASSES
            ) -> tuple[S, PoseCorrection, PoseError]:
    """Gauss-Newton on the re-cast model: apply ``first`` (a fit on the model with the
    recorded pose) to the pose, ``rematch`` (raycast again), ``refit`` on the re-matched
    residual, compose, until the step is below RECAST_STEP_M and RECAST_STEP_DEG or
    after ``passes_max`` re-casts (RECAST_PASSES; one correction for the recording,
    CONSTANT_RECAST_PASSES: a sensor mount tilted 1 deg moved the target 14 cm, seen
    mostly where it ends, and the passes took a fraction of it each, 8 cm after three).
    Returns the last re-match, the composed correction and ``first`` with the composed
    sizes (its test, gain and z, are the first fit's).
    ``refit(state, corr)`` fits the step on the model re-cast with ``corr`` applied."""
    corr, step = start.compose(first)
    passes = 0
    while True:
        state = rematch(corr)
        passes += 1
        if passes >= passes_max or (step[0] < RECAST_STEP_M and step[1] < RECAST_STEP_DEG):
            break
        corr, step = corr.compose(refit(state, corr))
    moved, rotvec = corr.moved()
    rows = np.searchsorted(corr.clouds, first.clouds)
    report = replace(first, translation_m=moved[rows], rotation_deg=rotvec[rows],
                     correction_m=np.zeros_like(first.correction_m), passes=passes,
                     last_step=step)
    if corr.rate_m is not None and first.rate_supported:
        h = corr.half_span_s[rows][:, None]
        with np.errstate(invalid='ignore', divide='ignore'):
            report = replace(report,
                             rate_translation_mps=np.where(h > 0, corr.rate_m[rows] / h, 0.0),
                             rate_rotation_deg_s=np.where(
                                 h > 0, np.degrees(corr.rate_rotvec_rad[rows]) / h, 0.0))
    return state, corr, report


def footing(data: lk.FitData, model) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                               np.ndarray]:
    """The pose test's footing on ``data`` under ``model`` (``likelihood.model_on_rays``):
    the range residual (m) with each material's offset taken out, its sigma (m) with the
    material's scale, the placed finite points, and the offsets taken out (per point)."""
    r = np.asarray(data.measured_range_m, float) - model.expected_range_m
    sigma = np.maximum(model.sigma_m, lk.MIN_SIGMA_M)
    ok = model.placed & np.isfinite(r) & np.isfinite(sigma)
    group = np.asarray(data.baseline.ctx.material, int)
    offset, scale = lk.material_nuisance(r, sigma, group, ok)
    return np.where(ok, r - offset, 0.0), np.where(ok, sigma * scale, 1.0), ok, offset


def heldout_gain(residual_m: np.ndarray, correction_m: np.ndarray,
                 sigma_m: np.ndarray) -> np.ndarray:
    """Nats per point the correction gains on held-out points: the Gaussian log density of
    the corrected residual minus the uncorrected one's, (r^2 - (r - c)^2) / (2 s^2)."""
    r = np.asarray(residual_m, float)
    return (r ** 2 - (r - correction_m) ** 2) / (2 * np.asarray(sigma_m, float) ** 2)


def fit_reference_pose(data: lk.FitData, cloud: np.ndarray, t_s: np.ndarray,
                       blocks: np.ndarray, z_crit: float, min_gain: float, seed: int = 0,
                       effects: list | None = None,
                       applied: 'PoseCorrection | None' = None,
                       rate: bool = False, constant: bool = False,
                       scan: ScanClock | None = None,
                       parts_z_crit: float | None = None, step_only: bool = False,
                       orientations: bool = True) -> PoseError:
    """Fit and judge per-cloud rigid pose corrections on ``data``'s matched points
    (``cloud``, ``t_s``, ``blocks``: per matched point) under the model with
    ``effects`` on top of its own (module doc). ``rate``: the points carry their own
    times, so a drift within each cloud is tested too (nested, on top of the rigid
    correction) and kept if it passes the rule. ``constant``: one rigid correction for
    all the clouds (six parameters, rotation about the centroid of all the points; no
    rate): an extrinsic error of the reference pose, the same in every cloud, which six
    parameters per cloud test with far less power. With ``rate`` too, one rate for the
    recording on top of it, tau on ``scan`` (``ScanClock``; None: each cloud's first
    point time is its stamp): the same drift within every cloud's scan. ``parts_z_crit``:
    the z each part of a per-cloud correction needs on its own (``shown_parts``; default
    ``z_crit``): ``--effect pose_error --fit``'s test is one test, but the parts it claims
    are the diagnosis's, asked at the diagnosis's bound. ``step_only``: a step of
    ``iterate`` (its test is the first fit's): without a rate, the correction alone is
    fitted, the same as the full fit's, and its test is not asked (gain 0, z 0, not
    significant); the held-out halves only where they choose the correction's footing
    (through the materials or not). With a rate the test decides the correction: the
    full fit. ``orientations``: one rigid correction for the recording that passes is
    asked across the surfaces' orientations too (``faces_agree``), and not significant
    where it does not hold there (False: ``--effect pose_error --fit``, which corrects
    the pose the user names)."""
    tau_scan = None
    if constant:
        scan = (scan if scan is not None else ScanClock.of(cloud, t_s)) if rate else None
        tau_scan = scan.tau(pose_time_s(t_s, [*data.base_effects, *(effects or [])])) \
            if scan is not None else None
        rate = tau_scan is not None
        cloud = np.zeros(len(np.asarray(cloud)), dtype=np.asarray(cloud).dtype)
    model = lk.model_on_rays(data, list(effects or []))
    ctx = model.ctx
    clouds = np.unique(cloud)
    if ctx.normal is None or ctx.direction is None or len(clouds) == 0:
        return PoseError(clouds, np.zeros(len(clouds)), np.zeros((len(clouds), 3)),
                         np.zeros((len(clouds), 3)), 0.0, 0.0, False,
                         np.zeros(len(data.measured_range_m)))
    r, s, ok, offset = footing(data, model)
    group = np.asarray(data.baseline.ctx.material, int)
    a, usable = design(ctx.direction, ctx.normal, np.where(ok, model.expected_range_m, 0.0),
                       cloud)
    use = ok & usable & (np.abs(r) <= OUTLIER_SIGMAS * s)
    tau, t_c, h_c = time_scale(t_s, cloud, clouds)
    if tau_scan is not None:
        tau, t_c, h_c = tau_scan, np.array([scan.centre_s]), np.array([scan.half_s])
    rate = bool(rate and np.any(h_c > 1e-9))
    a12 = rate_columns(a, tau) if rate else None
    # One rate for the recording is tested on the part of tau that the direction does
    # not fix (``beyond_direction``); estimated on tau whole.
    tau_beyond = beyond_direction(tau, ctx.direction, use) if rate and constant else None
    a12t = rate_columns(a, tau_beyond) if rate and constant else a12
    prior = None if applied is None else applied.params(clouds)
    prior12 = None if applied is None else applied.params(clouds, rate=True)
    # Jointly with the material offsets for one correction for the recording only: a
    # common offset of the materials is the same in every cloud, and per cloud the
    # joint fit would move each cloud along the line of sight on the pattern alone.
    ridge = CONSTANT_RIDGE if constant else RIDGE
    row = np.searchsorted(clouds, cloud)
    joint = fit_clouds(a, r, s, cloud, use, clouds, prior, ridge, group) if constant else None
    if joint is None or not explains_common_offset(np.einsum('ij,ij->i', a, joint[row]), r,
                                                   group, use, offset):
        group, joint = None, None
    # Else, for one correction for the recording: fitted with the materials at their
    # configured ranges (``explains_material_offsets``), where the materials' offsets
    # differ and the motion takes them; kept below if held out it loses no margin
    # that matters to the correction fitted on top of free offsets.
    materials = np.asarray(data.baseline.ctx.material, int)
    through = None
    if constant and joint is None:
        x_t = fit_clouds(a, r + offset, s, cloud, use, clouds, prior, ridge)
        if explains_material_offsets(np.einsum('ij,ij->i', a, x_t[row]), r + offset,
                                     materials, use, offset):
            through = x_t
    # The test (held-out halves) keeps the light ridge it was validated with: a damped
    # fit generalises better, so the stronger ridge would make the test more eager,
    # e.g. on top of a fitted time offset; the correction applied is the damped one.
    half = np.random.default_rng([seed, HALVES_SEED]).integers(0, 2, len(r))

    def per_point_of(g: np.ndarray) -> float:
        return float(np.sum(g[use]) / max(len(r), 1))

    def judged(g: np.ndarray) -> tuple[float, float]:
        z = block_mean_z(g[use], blocks[use])[1] if use.sum() > 1 else 0.0
        return per_point_of(g), z

    def halves_gain(through_materials: bool) -> np.ndarray:
        """Held-out gain per point of the rigid correction fitted on the other half: on
        free offsets (``group``: with the common one where ``joint``) or through the
        materials' configured ranges."""
        g = np.zeros(len(r))
        for k in (0, 1):
            test, train = use & (half != k), use & (half == k)
            if through_materials:
                x = fit_clouds(a, r + offset, s, cloud, train, clouds, prior, TEST_RIDGE)
                corr = with_offsets(np.einsum('ij,ij->i', a, x[row]), r, materials, train)
            else:
                x = fit_clouds(a, r, s, cloud, train, clouds, prior, TEST_RIDGE, group)
                corr = with_offsets(np.einsum('ij,ij->i', a, x[row]), r, group, train)
            g[test] = heldout_gain(r[test], corr[test], s[test])
        return g
    if step_only and not rate:
        if through is not None and not (per_point_of(halves_gain(True))
                                        > per_point_of(halves_gain(False)) - min_gain):
            through = None
        x = joint if joint is not None else through if through is not None else fit_clouds(
            a, r, s, cloud, use, clouds, prior, ridge)
        return _correction_only(x, a, ctx, model, ok, use, cloud, clouds, row, t_s,
                                constant, joint is not None, through is not None)
    # Per cloud: the parts the data show (``shown_parts``), asked where the whole passes
    # (not on a refit on the re-cast model, ``applied``: the first fit's claim stands).
    parts, parts_test = 'both', None
    if not constant and applied is None:
        parts, parts_test = shown_parts(a, r, s, cloud, use, clouds, prior, half, judged,
                                        z_crit, min_gain, part_z=parts_z_crit)
    gain12, gain1 = np.zeros(len(r)), np.zeros(len(r))
    gain_t, gain12_t = np.zeros(len(r)), np.zeros(len(r))
    gain_scan = np.zeros(len(r))      # a range offset over the scan instead (constant, rate)
    # A function of range alone instead (``range_alone.range_fit``), and the correction
    # on top of it (nested: the pose beyond range alone), rigid and with the rate.
    gain_rng, gain_wr, gain12_wr = np.zeros(len(r)), np.zeros(len(r)), np.zeros(len(r))
    knots = []
    gain = halves_gain(False)
    if through is not None:
        # Fitted through the offsets, then each material's offset profiled on what it
        # leaves, as the likelihood does: the same footing as ``gain``.
        gain_t = halves_gain(True)
    for k in (0, 1):
        test, train = use & (half != k), use & (half == k)
        if not constant:
            off = per_cloud_offset(r, s, row, train, len(clouds))
            gain1[test] = heldout_gain(r[test], off[test], s[test])
        range_cols = range_alone.range_fit(np.where(ok, model.expected_range_m, 0.0), r, s,
                                           use, train, len(clouds), seed, materials)
        knots.append(range_cols.n_knots)
        rng_corr = with_offsets(range_alone.fit_range_function(range_cols, r, s, train), r,
                                group, train)
        gain_rng[test] = heldout_gain(r[test], rng_corr[test], s[test])
        both = with_offsets(fit_clouds_with(a, range_cols, r, s, cloud, train, clouds), r,
                           group, train)
        gain_wr[test] = heldout_gain(r[test], both[test], s[test])
        if rate:
            both = with_offsets(fit_clouds_with(a12t, range_cols, r, s, cloud, train, clouds),
                               r, group, train)
            gain12_wr[test] = heldout_gain(r[test], both[test], s[test])
        if rate and constant:
            over_scan = range_over_scan(tau_beyond, r, s, group, train)
            gain_scan[test] = heldout_gain(r[test], over_scan[test], s[test])
        if rate:
            x12 = fit_clouds(a12t, r, s, cloud, train, clouds, prior12, TEST_RIDGE, group)
            corr12 = with_offsets(np.einsum('ij,ij->i', a12t, x12[row]), r, group, train)
            gain12[test] = heldout_gain(r[test], corr12[test], s[test])
            if through is not None:
                # The drifting correction on the footing of ``gain_t``.
                x12 = fit_clouds(a12t, r + offset, s, cloud, train, clouds, prior12,
                                 TEST_RIDGE)
                corr12 = with_offsets(np.einsum('ij,ij->i', a12t, x12[row]), r, materials,
                                      train)
                gain12_t[test] = heldout_gain(r[test], corr12[test], s[test])
    per_point, z = judged(gain)
    if through is not None:
        per_point_t, z_t = judged(gain_t)
        if per_point_t > per_point - min_gain:
            per_point, z = per_point_t, z_t
            gain, gain12 = gain_t, gain12_t
        else:
            through = None
    rate_gain, rate_z = judged(gain12 - gain) if rate else (0.0, 0.0)
    offset_gain, offset_z = judged(gain1) if not constant else (0.0, 0.0)
    beyond_gain, beyond_z = judged(gain - gain1) if not constant else (0.0, 0.0)
    # A refinement of a pose error that is there: the rigid correction passes first.
    # Within one cloud a point's time follows its place in the scan (a raster's rows),
    # so on its own the rate is six more spatial patterns per cloud, which a sensor's
    # own pattern (a bias periodic in azimuth) would pass for.
    rigid_passes = z >= z_crit and per_point >= min_gain
    scan_tie = None
    if constant:
        supported = bool(rate and constant_rate_supported(
            (rate_gain, rate_z), judged(gain12), z_crit, min_gain))
        if supported:
            # Along the line of sight one rate of the pose is a range offset of the sensor
            # growing over each scan: claimed only if it gains beyond that, by the rule.
            beyond = judged(gain12 - gain_scan)
            if not (beyond[1] >= z_crit and beyond[0] >= min_gain):
                supported = False
                scan_tie = {'rate_gain': round(judged(gain12)[0], 6),
                            'range_over_scan_gain': round(judged(gain_scan)[0], 6),
                            'rate_beyond_range_over_scan': round(beyond[0], 6),
                            'z': round(beyond[1], 2)}
    else:
        supported = bool(rate and rigid_passes and rate_z >= z_crit
                         and rate_gain >= min_gain)
    # A supported rate per cloud claims its parts as the rigid correction does: each on
    # its own, nested on top of the rigid part (``shown_parts`` with it fixed).
    rate_parts, rate_parts_test = 'both', None
    if supported and not constant and applied is None:
        rate_parts, rate_parts_test = shown_parts(
            a * tau[:, None], r, s, cloud, use, clouds, prior12, half, judged, z_crit,
            min_gain, fixed=a, part_z=parts_z_crit)
        # Its bounds per unit tau: over the scan (tau from -1 to 1), twice that.
        rate_parts_test.update(
            rotation_bound_deg=round(2 * rate_parts_test['rotation_bound_deg'], 4),
            translation_bound_cm=round(2 * rate_parts_test['translation_bound_cm'], 3))
    if supported:
        # The drifting correction against none: the test of what is reported.
        per_point, z = judged(gain12)
    # The correction as reported against range alone, and on top of it, on the same
    # points (``range_alone.PoseAgainstRange``).
    against_range = range_alone.PoseAgainstRange(
        max(knots), *judged(gain_rng),
        *judged((gain12_wr if supported else gain_wr) - gain_rng),
        judged((gain12 if supported else gain) - gain_rng)[0])
    # A rigid correction that passes: does it hold across the surfaces' orientations?
    across = None
    if orientations and constant and not supported and z >= z_crit and per_point >= min_gain:
        # On the test's footing: free offsets, or the materials at their configured
        # ranges where the motion took their offsets (``through``).
        across = faces_agree(a, r, s, cloud, use, clouds, prior, ctx.normal, materials, row,
                             blocks, z_crit, min_gain,
                             None if through is None else r + offset)
    cols = a12 if supported else a
    if constant and supported:
        # One correction for the recording and its rate, on the rigid one's footing.
        x = fit_clouds(a12, r + offset if through is not None else r, s, cloud, use,
                       clouds, prior12, ridge, group)
    else:
        # One correction for the recording without a rate: the joint fit is the correction.
        x = joint if joint is not None else through if through is not None else fit_clouds(
            cols, r, s, cloud, use, clouds, prior12 if supported else prior, ridge)
    correction = np.einsum('ij,ij->i', cols, x[row])
    # A correction per cloud that passes: does its held-out gain hold on the surfaces
    # facing every way? The rigid one first (a rate refines a pose error that is there),
    # then, where the rate is supported, the drifting one. Reported (``across_faces``);
    # the claim is withheld where it is made (the caller's), its test here left as it is.
    if orientations and not constant and z >= z_crit and per_point >= min_gain:
        across = per_cloud_faces(gain, use, ctx.normal, x[row, :3], blocks, z_crit,
                                 min_gain, len(r))
        if supported and all(g.transfers for g in across):
            across = per_cloud_faces(gain12, use, ctx.normal, x[row, :3], blocks, z_crit,
                                     min_gain, len(r))
    t_mean = np.array([float(np.mean(t_s[cloud == c])) for c in clouds])
    p = ctx.direction * np.where(ok, model.expected_range_m, 0.0)[:, None]
    centroid = np.array([p[use & (cloud == c)].mean(axis=0) if np.any(use & (cloud == c))
                         else np.zeros(3) for c in clouds])
    with np.errstate(invalid='ignore', divide='ignore'):
        per_s = np.where(h_c[:, None] > 1e-9, 1.0 / h_c[:, None], 0.0)
    return PoseError(clouds, t_mean, x[:, :3], np.degrees(x[:, 3:6]), per_point, z,
                     bool(z >= z_crit and per_point >= min_gain
                          and (across is None or not constant
                               or all(g.transfers for g in across))),
                     correction, centroid,
                     rate_tested=rate, rate_supported=supported, rate_gain=rate_gain,
                     rate_z=rate_z,
                     rate_decisive=bool(rate and not supported and rate_z >= z_crit
                                        and rate_gain > 0),
                     rate_translation_mps=x[:, 6:9] * per_s if supported else None,
                     rate_rotation_deg_s=np.degrees(x[:, 9:12]) * per_s if supported else None,
                     t_centre_s=t_c, half_span_s=h_c, constant=constant,
                     joint=joint is not None, through_materials=through is not None,
                     scan=scan if constant and rate else None, scan_tie=scan_tie,
                     offset_gain=offset_gain, offset_z=offset_z,
                     beyond_offset_gain=beyond_gain, beyond_offset_z=beyond_z,
                     against_range=against_range,
                     parts=parts, parts_test=parts_test, rate_parts=rate_parts,
                     rate_parts_test=rate_parts_test,
                     across_faces=None if across is None else {
                         'transfers': all(g.transfers for g in across),
                         **dict(zip(('clusters', 'halves'), (g.as_dict() for g in across)))})


def faces_agree(a: np.ndarray, r: np.ndarray, s: np.ndarray, cloud: np.ndarray,
                use: np.ndarray, clouds: np.ndarray, prior: np.ndarray | None,
                normal: np.ndarray, materials: np.ndarray, row: np.ndarray,
                blocks: np.ndarray, z_crit: float, min_gain: float,
                through: np.ndarray | None = None
                ) -> tuple['face_transfer.AcrossOrientations', ...]:
    """The rigid correction (columns ``a``, per cloud as ``cloud`` says) fitted on the
    usable points of every orientation group of the surface normals (``normal``, sensor
    frame) but one, jointly with the materials' offsets (or, ``through``: the residual
    with the materials at their configured ranges, the motion fitted to it alone, as the
    test's footing where the motion took the offsets) and damped (RIDGE: a motion the
    other groups do not see is left near zero), the materials' offsets then profiled on
    every usable point (a face that is one material keeps its own offset: a material's
    bias off the configuration is the model's nuisance, not the pose's), and scored held
    out on that group (``face_transfer``; residual ``r`` and sigma
    ``s`` in m, as the pose test's footing). Two groupings: clusters of the normals, and
    the halves facing along and against each cloud's fitted translation. Asked of one
    correction for the recording only (``fit_reference_pose``): per cloud, the few points
    a cloud has on the surfaces facing some ways leave the motions those surfaces do not
    see to their noise (a true jitter over 20 and 80 clouds of three planes lost on a
    held-out plane at z -4 and, on the halves, -9); a per-cloud correction is asked by
    ``per_cloud_faces``."""
    def fit(train: np.ndarray) -> np.ndarray:
        if through is not None:
            return fit_clouds(a, through, s, cloud, train, clouds, prior, RIDGE)
        return fit_clouds(a, r, s, cloud, train, clouds, prior, RIDGE, materials)

    def fit_on(train: np.ndarray) -> np.ndarray:
        return with_offsets(np.einsum('ij,ij->i', a, fit(train)[row]), r, materials, use)
    whole = fit(use)
    return tuple(face_transfer.across_orientations(fit_on, r, s, groups, normal, blocks,
                                                   z_crit, min_gain, len(r))
                 for groups in (face_transfer.orientation_groups(normal, use),
                                face_transfer.halves_along(normal, use, whole[row, :3])))


def per_cloud_faces(gain: np.ndarray, use: np.ndarray, normal: np.ndarray,
                    translation_m: np.ndarray, blocks: np.ndarray, z_crit: float,
                    min_gain: float, n_points: int
                    ) -> tuple['face_transfer.AcrossOrientations', ...]:
    """A per-cloud correction's held-out gain on random halves (``gain``, nats per
    point, 0 where not ``use``) summed within each orientation group of the surface
    normals (``normal``, sensor frame): the clusters of the normals, and the halves
    facing along and against each point's cloud's fitted translation (``translation_m``,
    (N, 3) m) (``face_transfer.by_group``). Fitted per cloud on the surfaces facing some
    ways and held out on the others (``faces_agree``), a true jitter over 3-60 clouds lost
    on a held-out cluster at z -4.5 to -6.9 (the motion a group does not see is its
    noise there); fitted on every group at once it gains on each (z >= -0.6 on our pose
    items), while a face-dependent bias taken per cloud loses where it is not (-0.02
    nats per point, z -5 to -11, on the sunlit drum)."""
    return tuple(face_transfer.by_group(gain, groups, normal, blocks, z_crit, min_gain,
                                        n_points)
                 for groups in (face_transfer.orientation_groups(normal, use),
                                face_transfer.halves_along(normal, use, translation_m)))


def _correction_only(x: np.ndarray, a: np.ndarray, ctx, model, ok: np.ndarray,
                     use: np.ndarray, cloud: np.ndarray, clouds: np.ndarray,
                     row: np.ndarray, t_s: np.ndarray, constant: bool, joint: bool,
                     through: bool) -> PoseError:
    """``fit_reference_pose``'s correction ``x`` (per cloud: 3 translations m, 3 turns
    rad) as a step of ``iterate``: its sizes, range change and centroid as the full
    fit reports them, no test (gain 0, z 0, not significant)."""
    correction = np.einsum('ij,ij->i', a, x[row])
    t_mean = np.array([float(np.mean(t_s[cloud == c])) for c in clouds])
    p = ctx.direction * np.where(ok, model.expected_range_m, 0.0)[:, None]
    centroid = np.array([p[use & (cloud == c)].mean(axis=0) if np.any(use & (cloud == c))
                         else np.zeros(3) for c in clouds])
    return PoseError(clouds, t_mean, x[:, :3], np.degrees(x[:, 3:6]), 0.0, 0.0, False,
                     correction, centroid, constant=constant, joint=joint,
                     through_materials=through)


def applied_gain(pose: PoseError, data: lk.FitData, cloud: np.ndarray) -> float:
    """Nats per matched point of ``data`` (``cloud`` per matched point) that ``pose``'s
    correction (its translation and rotation per cloud, as reported: after the re-casts)
    would gain if it were exactly right: sum over the test's points of (c / s)^2 / 2 per
    matched point, c the range change it makes (``design``) and s the point's sigma on
    the test's footing. The rule's practical margin, MIN_PRACTICAL_GAIN, is what a 0.1
    sigma shift gains: a correction below it does not matter whatever its test's gain,
    which then came from elsewhere (rays whose surface a linear fit moves: on a correct
    pose with a beam-divergence effect the linear fit took 1.5 cm at 0.024 nats/point,
    and raycast again it came to 0.08 cm, worth 0.0002)."""
    model = lk.model_on_rays(data, [])
    ctx = model.ctx
    if ctx.normal is None or ctx.direction is None or not len(pose.clouds):
        return 0.0
    r, s, ok, _ = footing(data, model)
    cl = np.zeros(len(r), int) if pose.constant else np.asarray(cloud)
    a, usable = design(ctx.direction, ctx.normal, np.where(ok, model.expected_range_m, 0.0),
                       cl)
    use = ok & usable & (np.abs(r) <= OUTLIER_SIGMAS * s)
    x = np.hstack([np.asarray(pose.translation_m, float),
                   np.radians(np.asarray(pose.rotation_deg, float))])
    pos = np.clip(np.searchsorted(pose.clouds, cl), 0, len(pose.clouds) - 1)
    have = use & (np.asarray(pose.clouds)[pos] == cl)
    c = np.einsum('ij,ij->i', a, x[pos])
    return float(np.sum((c[have] / s[have]) ** 2) / 2 / max(len(r), 1))


def constant_rate_supported(rate: tuple[float, float], drifting: tuple[float, float],
                            z_crit: float, min_gain: float) -> bool:
    """Whether one rate for the recording (``fit_reference_pose(constant=True,
    rate=True)``) stands: its held-out gain over the rigid correction (``rate``: nats
    per matched point, z) and the drifting correction's against none (``drifting``)
    both pass the rule. Unlike a rate per cloud, the rigid part need not pass alone:
    twelve parameters for the recording, held out on every cloud's points, cannot fit
    a pattern per cloud, and a drift of the pose along the line of sight has a mean
    (a sample-and-hold pose is off by half its drift on average) that every material's
    offset takes, so that the rigid test sees little of it alone."""
    return bool(rate[1] >= z_crit and rate[0] >= min_gain
                and drifting[1] >= z_crit and drifting[0] >= min_gain)


def pose_time_s(t_s: np.ndarray, effects: list) -> np.ndarray:
    """(N,) the times (s) the model reads the reference pose at for points at ``t_s``:
    through each effect's ``pose_time_s`` (a clock offset), as the pipeline does."""
    t = np.asarray(t_s, float)
    for e in effects:
        t = np.asarray(e.pose_time_s(t), float)
    return t


def per_cloud_offset(residual_m: np.ndarray, sigma_m: np.ndarray, row: np.ndarray,
                     train: np.ndarray, n_clouds: int) -> np.ndarray:
    """(N,) one range offset per cloud (m), the weighted mean of the ``train`` points'
    residual of each cloud (``row``: each point's cloud row), at every point: a range
    offset of the sensor that changes between clouds and not within one, the same on
    every ray whatever its surface or direction."""
    w = np.where(train, 1.0 / np.asarray(sigma_m, float) ** 2, 0.0)
    num = np.bincount(row, weights=w * residual_m, minlength=n_clouds)
    den = np.bincount(row, weights=w, minlength=n_clouds)
    with np.errstate(invalid='ignore', divide='ignore'):
        per = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return per[row]


COMMON_OFFSET_MIN_M = 0.005     # a common offset of the materials below this: no joint fit
COMMON_OFFSET_SHARE = 0.5       # the joint fit must explain at least this share of it
COMMON_OFFSET_MATERIALS = 3     # materials' offsets that differ: at least this many materials


def common_offset_m(offset_m: np.ndarray, group: np.ndarray, use: np.ndarray) -> float:
    """The materials' common range offset (m): the median over the materials with
    enough usable points of each one's offset (``offset_m`` per point)."""
    values = [float(np.median(offset_m[use & (group == g)])) for g in np.unique(group[use])
              if np.sum(use & (group == g)) >= lk.MIN_MATERIAL_POINTS]
    return float(np.median(values)) if values else 0.0


def explains_common_offset(correction_m: np.ndarray, residual_m: np.ndarray,
                           group: np.ndarray, use: np.ndarray, offset_m: np.ndarray) -> bool:
    """Whether ``correction_m`` (m per point), fitted jointly with the material offsets
    (``fit_clouds`` with ``group``) on ``residual_m`` (m, the offsets ``offset_m`` per
    point subtracted), may stand: the materials show a common offset (``offset_m``, the
    per-material offsets of the residual before it, per point; their median at least
    COMMON_OFFSET_MIN_M) and the joint fit explains at least COMMON_OFFSET_SHARE of it.
    A pose off along the line of sight moves every material alike, and the joint fit
    takes that common offset into the translation; but the translation's only other
    trace, its n.d / n.u pattern, grows at grazing rays as a footprint's first returns
    at the edges do: on a correct pose with a beam-divergence effect the joint fit moved
    the target 16 cm along the line of sight and left every material 16 cm off, and,
    where the effect's own bias had put every material 11 cm short, it moved the target
    1 cm and left the offsets as they were (the pose then reported beside the effect).
    Otherwise the offsets are subtracted first and the correction fitted on the rest."""
    left = residual_m - correction_m
    after, _ = lk.material_nuisance(left, np.ones(len(left)), group, use)
    before = common_offset_m(offset_m, group, use)
    left_over = common_offset_m(offset_m + after, group, use)
    return bool(abs(before) >= COMMON_OFFSET_MIN_M
                and abs(left_over) <= (1 - COMMON_OFFSET_SHARE) * abs(before))


def explains_material_offsets(correction_m: np.ndarray, residual_m: np.ndarray,
                              group: np.ndarray, use: np.ndarray,
                              offset_m: np.ndarray) -> bool:
    """Whether ``correction_m`` (m per point), one rigid correction fitted to
    ``residual_m`` with every material at its configured range (its offset ``offset_m``
    per point not subtracted), takes the materials' offsets: at least
    COMMON_OFFSET_MATERIALS materials with enough points, whose offsets differ (their
    spread about their mean at least COMMON_OFFSET_MIN_M: a common offset alone is a
    range offset of the sensor as much as the pose, ``explains_common_offset``), and
    at least COMMON_OFFSET_SHARE of their RMS explained. On a target whose faces are
    each one material (a box satellite: MLI on one side, a bulkhead on another), a
    motion across the line of sight lengthens one face's ranges and shortens the
    opposite face's, which free per-material offsets take whole: fitted on top of
    them, a (3, 2, -3) cm error came out as 0.5 cm."""
    members = [m for m in np.unique(group[use])
               if np.sum(use & (group == m)) >= lk.MIN_MATERIAL_POINTS]
    if len(members) < COMMON_OFFSET_MATERIALS:
        return False
    before = np.array([float(np.median(offset_m[use & (group == m)])) for m in members])
    left = residual_m - correction_m
    after = np.array([float(np.median(left[use & (group == m)])) for m in members])
    rms_before = float(np.sqrt(np.mean(before ** 2)))
    return bool(float(np.std(before)) >= COMMON_OFFSET_MIN_M
                and float(np.sqrt(np.mean(after ** 2)))
                <= (1 - COMMON_OFFSET_SHARE) * rms_before)


def with_offsets(correction_m: np.ndarray, residual_m: np.ndarray,
                 group: np.ndarray | None, train: np.ndarray) -> np.ndarray:
    """A fitted range correction (m, per point) plus its materials' offsets: each
    material's median of the corrected residual over the ``train`` points, as the
    likelihood profiles it (``likelihood.material_nuisance``) on the residual left by
    the correction (the motion fitted jointly with the offsets, ``fit_clouds``)."""
    if group is None:
        return correction_m
    left = residual_m - correction_m
    offset, _ = lk.material_nuisance(left, np.ones(len(left)), group, train)
    return correction_m + offset


def corrected(data: lk.FitData, correction_m: np.ndarray) -> lk.FitData:
    """``data`` with the pose correction's range change (m, per matched point) in the
    baseline's range bias: the model as the corrected reference pose would predict it."""
    corr = np.asarray(correction_m, float)

    def shift(pred):
        return replace(pred, bias_m=np.asarray(pred.bias_m) + corr)
    cast = data.cast
    return replace(data, baseline=shift(data.baseline),
                   cast=lk.PredictionCache(lambda effects: shift(cast(effects))))
