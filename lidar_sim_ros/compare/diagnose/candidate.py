"""What a diagnosis weighs and what it concludes: the rule's numbers (``diagnosis``'s
module doc explains them), the names beyond the catalogue that a verdict may hold (the
reference pose, range errors of the sensor weighed against it, surfaces off their mesh),
one ``Candidate`` per effect tried, and the ``Decision``. Gains in nats per point.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidar_sim_ros.core.effects import Effect

UNMATCHED_NATS = 3.0        # gain credited per unmatched point a candidate explains
MIN_TOTAL_GAIN = 15.0       # nats of held-out log-likelihood ratio (odds e^15 : 1)
FAMILY_ALPHA = 0.01         # family-wise error rate of the candidate tests (one-sided)
MIN_PRACTICAL_GAIN = 0.005  # nats per point: 0.5 (0.1 sigma)^2 (module doc)
MIN_SHARE = 0.25            # least share of the feature structure a bias/noise effect explains
MAX_ALSO_TRIES = 2         # candidates decisively worse than the named one tried on top of it
# An effect that shares the named one's dilation at grazing incidence: a wide footprint
# lengthens (or, read at its nearest sub-ray, shortens) ranges where the beam meets the
# surface obliquely, as an incidence bias does, so fitted alone it takes the bias's part
# and the bias, ranked behind effects of other shapes, was never tried beside it.
SHARES_DILATION = {'beam_divergence': 'incidence_angle'}
MIN_UNMATCHED_EXPLAINED = 20   # unmatched points explained count only from this many ...
MIN_UNMATCHED_FRACTION = 0.002  # ... and this share of all points (grazing rays aside)
N_FOLDS = 2
# The reference pose's per-cloud correction as a member of a tie (``confounded_with``):
# not a sensor effect (``pose_error.py``), judged by its own held-out test.
POSE_ERROR = 'pose_error'
# Range errors of the sensor that move a whole cloud along the line of sight, as a
# reference pose that is off does: weighed against the per-cloud pose correction on the
# same footing when it passes (``Diagnosis.weigh_pose_rivals``); no default candidates.
POSE_RIVALS = ('range_drift', 'range_scale')
RANGE_DRIFT = POSE_RIVALS[0]     # a range offset of the sensor changing over the recording
# A range error of the sensor outside the catalogue that follows range, tied with a
# per-cloud pose where the data cannot tell the two (``run.pose_against_range_alone``):
# judged by its own test (``range_alone.PoseAgainstRange``), as pose_error is by its own.
RANGE_OF_RANGE = 'range_error_of_range'
# The target's surfaces off its mesh (as-built vs CAD): no sensor effect, and no default
# candidate; weighed against a named effect as the range errors are (``weigh_rivals``):
# a surface moved along its normal shifts ranges as 1 / cos(incidence), as a footprint
# effect does.
GEOMETRY_RIVALS = ('surface_offset',)


@dataclass
class Candidate:
    """One catalogue effect fitted to the residuals and what it would bring."""

    name: str
    score: float = 0.0                 # held-out gain, nats per measured point
    params: dict = field(default_factory=dict)
    at_bound: list = field(default_factory=list)   # params fitted at their search bound (``fit.at_bounds``)
    # What the model with this effect would show on the calibrated basis (each
    # material's offset and sigma scale profiled out, as a --fit run): comparable with
    # the summary's range_rmse_calibrated_m / nll_calibrated / robust sigma.
    range_rmse_after_m: float = float('nan')
    nll_after: float = float('nan')
    range_robust_sigma_after_m: float = float('nan')
    # A false-return effect, fitted as --fit leaves it: what it gains on the shots that
    # missed the target (the binomial count of false returns among them, the other
    # term of the likelihood it is fitted and held out on), nats per matched point;
    # 0 for an effect that adds no false returns (``Diagnosis.finalize``).
    missed_gain_after: float = 0.0
    # A ray-moving effect (a footprint): what the returns it puts back on the target
    # gain, UNMATCHED_NATS each for the ``unmatched_gain_points`` credited to it, nats
    # per matched point: the score's footing, on which the rays that return are the same
    # before and after; 0 for a false-return effect (``missed_gain_after``).
    unmatched_gain_after: float = 0.0
    unmatched_explained: float = 0.0
    matched_gain: float = 0.0          # held-out, nats per matched point
    z: float = 0.0                     # score in standard errors (``total_z``): the rule's z
    z_matched: float = 0.0             # matched_gain in block-robust standard errors
    unmatched_gain_points: float = 0.0
    n_params: int = 0
    significant: bool = False          # decisive: z and total gain (module doc)
    practical: bool = False            # matters: score >= MIN_PRACTICAL_GAIN
    share: float | None = None         # of the attribution's feature structure
    vetoed: str | None = None          # why it cannot be the missing effect despite its gain
    tile_vetoed: bool = False          # ``vetoed`` by the tile test (``tile_veto``)
    material_vetoed: bool = False      # ``vetoed`` by the cross-material test (``material_veto``)
    # A per-laser one: the tile test as last asked (``Diagnosis.tile_veto``: the worst
    # split, its loss in nats per analysed point and z, the effects beside, 'passes').
    tile_test: dict | None = None
    # Lasers' pointing: what each laser's own offsets gain over their common turn alone
    # (``own_part_veto``).
    own_part: dict | None = None
    # A surface standoff beside an incidence-shaped rival: its per-material part, the
    # common standoff's gain taken out (``standoff_part_veto``).
    standoff_part: dict | None = None
    beside: str | None = None          # passed the tile test on top of this one (``lasers_beside``)
    beside_gain: dict | None = None    # its gain on top of the named and 'also' (``lasers_beside_named``)
    together: dict | None = None       # refitted with the 'also' effect (``fit_together``)
    # A walk or incidence bias weighed with the other refitted together on each fold where
    # neither alone may be named (``Diagnosis.walk_beside_incidence``): its figures and
    # whether, as one of the pair, it passes the rule ('passes').
    jointly: dict | None = None
    far_points: float = 0.0            # outlier effects: far or unmatched points it explains
    effect: Effect | None = None
    variant: type | None = None
    yaml: str = ''
    error: str | None = None
    heldout_nll: np.ndarray | None = None   # per matched point, folds concatenated
    seconds: float = 0.0
    # A rival of the reference pose (POSE_RIVALS): the pose test on top of it and its
    # score on the pose-corrected model (``weigh_pose_rivals``).
    against_pose: dict | None = None
    # The named one: the pose test on top of it and what the decision holds beside it,
    # fitted together (``Diagnosis.pose_beside_named``).
    pose_beside: dict | None = None
    # A named (or tied) one: the pose test ``judge_pose`` weighed on top of it alone
    # (per cloud or constant, the larger held-out gain).
    pose_on_top: dict | None = None
    # An outlier effect: the false returns its fitted rate predicts against those
    # recorded, on the diagnosed points (``Diagnosis.false_return_budget``).
    false_returns: dict | None = None

    @property
    def admissible(self) -> bool:
        return (self.error is None and self.significant and self.practical
                and self.vetoed is None)

    def as_dict(self) -> dict:
        return {'name': self.name, 'score': _num(self.score), 'params': self.params,
                **({'at_bound': list(self.at_bound)} if self.at_bound else {}),
                'range_rmse_after_m': _num(self.range_rmse_after_m),
                'nll_after': _num(self.nll_after),
                **({'missed_shots_gain_after': _num(self.missed_gain_after)}
                   if self.missed_gain_after else {}),
                **({'unmatched_gain_after': _num(self.unmatched_gain_after)}
                   if self.unmatched_gain_after else {}),
                'range_robust_sigma_after_m': _num(self.range_robust_sigma_after_m),
                'unmatched_explained': _num(self.unmatched_explained),
                'heldout_gain_per_matched_point': _num(self.matched_gain), 'z': _num(self.z),
                'z_matched': _num(self.z_matched),
                'unmatched_points_credited': _num(self.unmatched_gain_points),
                'n_params': self.n_params, 'significant': self.significant,
                'seconds': round(self.seconds, 2),
                'practical': self.practical,
                **({'structure_share': _num(self.share)} if self.share is not None else {}),
                **({'vetoed': self.vetoed} if self.vetoed else {}),
                **({'passes_beside': self.beside} if self.beside else {}),
                **({'gain_beside': self.beside_gain} if self.beside_gain else {}),
                **({'tile_test': self.tile_test} if self.tile_test else {}),
                **({'own_offsets': self.own_part} if self.own_part else {}),
                **({'per_material_part': self.standoff_part} if self.standoff_part else {}),
                **({'fitted_together': self.together} if self.together else {}),
                **({'jointly': self.jointly} if self.jointly else {}),
                **({'against_pose': self.against_pose} if self.against_pose else {}),
                **({'pose_beside': self.pose_beside} if self.pose_beside else {}),
                **({'pose_on_top': self.pose_on_top} if self.pose_on_top else {}),
                **({'false_returns': self.false_returns} if self.false_returns else {}),
                **({'error': self.error} if self.error else {})}


def _num(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else round(float(x), 6)


@dataclass
class Decision:
    """What the diagnosis concludes: the missing effect (or None), the candidates that
    are confounded in this recording, and a candidate that also explains a separate
    part of the residual (two effects at once: expect it next). ``evidence``: the
    candidate whose held-out gain supports ``missing`` when that is not a candidate
    itself (``sunlight``, named on ``solar_background``'s gain and the sun test)."""

    missing: str | None
    confounded_with: list[str]
    also: str | None = None
    pair_z: dict = field(default_factory=dict)
    evidence: str | None = None
    # The reference pose is off (``pose_error.PoseError``, significant); with ``missing``
    # None, it explains what the candidates would have claimed.
    pose: object | None = None
    # Names the rule kept from the verdict (``settle``): name -> why.
    withheld: dict = field(default_factory=dict)
    # Beside the named effect, two explanations of one more part that the recording
    # cannot tell apart (``Diagnosis.range_offset_beside``: [pose_error, range_drift]),
    # and the pose test that found it (``pose_error.PoseError``, on top of the named).
    beside_tie: list[str] = field(default_factory=list)
    beside_pose: object | None = None
    # One part of a material against the reference pose (``region_offset.judge``:
    # ``region_offset.RegionOffset``); where the pose does not gain beyond it, the pose
    # is not reported (part of the target reads off the rest, or the two not told apart).
    region: object | None = None
    # Further effects that also explain a separate part, beside ``also`` (in the order
    # found); each passed the rule on top of the named effect as ``also`` did.
    also_more: list[str] = field(default_factory=list)
