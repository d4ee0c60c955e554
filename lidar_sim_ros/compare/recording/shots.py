"""How many shots the recording fired: the shots behind its unmatched points.

A false return needs a shot: a per-shot false-return probability predicts as many
returns off the target as there were shots that missed it
(``likelihood.unmatched_explained``). An unorganised cloud lists only the returns, so
the count comes from the configured scan pattern (shots per frame x clouds); an
organised cloud keeps a slot per shot (non-finite or zero points where nothing came
back), so its size counts them, whatever the configured pattern. When the count does
not exceed the points the recording holds (an unorganised cloud and the scan pattern of
another sensor), it is unknown and the likelihood falls back to its assumption.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.compare.recording.measurements import Measurements


def missed_per_unmatched(meas: Measurements, matched: np.ndarray, per_frame: int) -> float | None:
    """Shots without a matched point per unmatched point analysed (module doc), or None.

    ``matched``: bool per analysed point; ``per_frame``: shots of one frame of the
    configured scan pattern (``Simulator.shots``). The shots are scaled to the analysed share of
    the recording's points (a random subset may be analysed)."""
    matched = np.asarray(matched, bool)
    n_unmatched = int((~matched).sum())
    if n_unmatched == 0:
        return None
    dropped = meas.dropped
    # Occluded returns (``occlusion.py``, left out of ``meas``) came from shots too: the
    # analysed share of the shots is scaled down by them. Crosstalk ghosts
    # (``crosstalk.py``) are second returns of shots already counted, or returns of shots
    # that missed the target: left out of the points, their shots stay among the shots.
    # A shot's later returns (``multiple_returns.py``) are of shots already counted too.
    finite = len(meas) + dropped.get('subsampled', 0) + dropped.get('occluded', 0)
    empty = dropped.get('non_finite', 0) + dropped.get('at_origin', 0)
    shots = finite + empty if empty else per_frame * len(meas.cloud_stamps_s)
    if shots <= finite:
        return None
    missed = shots * len(meas) / max(finite, 1) - int(matched.sum())
    return float(missed / n_unmatched)
