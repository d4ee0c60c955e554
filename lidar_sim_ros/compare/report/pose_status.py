"""Whether the verdict reports the reference pose, which test decided it and why.

summary.json's ``reference_pose`` holds one pose test: the pose the decision reports,
or, where none is reported, the per-cloud test on top of the named effect alone. That
test may pass while the verdict says nothing of the pose: the pose was then tested
again beside the named effect and what the decision holds beside it
(``Diagnosis.pose_beside_named``), or weighed against the named effect on the corrected
pose (``Diagnosis.judge_pose``), and the decision stood. ``pose_status`` says so in the
JSON beside the figures (``reported``, ``reported_as``, ``reported_because``,
``decided_by``), read from what the
decision and the candidates recorded; it decides nothing.
"""
from __future__ import annotations

from lidar_sim_ros.compare.diagnose.candidate import MIN_PRACTICAL_GAIN, POSE_ERROR, RANGE_OF_RANGE
from lidar_sim_ros.compare.report.verdict import LINE_OF_SIGHT_SHARE


def pose_status(pose: dict | None, decision, cands: list, on_top: list[str]) -> dict:
    """``reported`` (bool: the verdict says the pose is off, alone, beside a named effect
    or in a tie), ``reported_as`` ('off', 'off_or_sensor_range': off, per cloud along the
    line of sight, which the verdict says a sensor's range offset does alike; 'beside',
    'tie', 'beside_tie' or None),
    ``reported_because`` (one sentence) and ``decided_by`` (the deciding test's figures:
    gain per matched point, z, significant, per cloud or constant, on top of what).
    ``pose``: summary.json's ``reference_pose`` (``PoseError.as_dict``); ``on_top``: the
    effects its test had in the model."""
    if pose is None:
        return _out(False, None, 'the pose was not tested', None)
    shown = _figures(pose, on_top)
    named = [n for n in (decision.missing, *decision.confounded_with) if n and n != POSE_ERROR]
    if decision.pose is not None:
        if POSE_ERROR in decision.confounded_with and RANGE_OF_RANGE in named:
            return _out(True, 'tie', 'it explains the residual as well as a function of range '
                        'alone (a range error of the sensor that follows range) with as many '
                        'parameters, held out on the same points: a tie (confounded_with), '
                        'none named', shown)
        if POSE_ERROR in decision.confounded_with:
            return _out(True, 'tie', f'it explains the residual as well as {_join(named)}: a '
                        'tie (confounded_with), none named', shown)
        if (pose.get('raycast') or {}).get('line_of_sight'):
            return _out(True, 'off', 'moved along the line of sight and every ray raycast '
                        'again, scored as the candidates are, it passes the rule and the '
                        'named candidates gain nothing on the moved target (line_of_sight)',
                        {**shown, 'raycast': pose['raycast']})
        if pose.get('raycast'):
            return _out(True, 'off', 'its own held-out test does not pass, but raycast again '
                        'with it the model fits better than with the named candidates as '
                        '--fit leaves them (raycast)', {**shown, 'raycast': pose['raycast']})
        if named:
            lead = next((c for c in cands if c.name == named[0]), None)
            pb = getattr(lead, 'pose_beside', None) or {}
            also = (f', and on top of {_join([lead.name, *pb["with"]])} fitted together '
                    f'({_f(pb.get("gain"))} nats/point, z = {_f(pb.get("z"), 1)})'
                    if pb.get('significant') else '')
            where = f'on top of {_join(on_top)}' if on_top else 'on its own'
            return _out(True, 'beside', f'its test passes {where}{also}: reported beside '
                        f'{_join(named)}', shown)
        share = pose.get('line_of_sight_share')
        if share is not None and share >= LINE_OF_SIGHT_SHARE and not pose.get('constant'):
            return _out(True, 'off_or_sensor_range', 'its test passes and no sensor effect is '
                        f'named beside it; {100 * share:.0f} % of its correction moves the '
                        'clouds along the line of sight, as a range offset of the sensor '
                        'changing from cloud to cloud would: the verdict says the two cannot '
                        'be told apart', shown)
        return _out(True, 'off', 'its test passes and no sensor effect is named beside it',
                    shown)
    if decision.beside_tie and decision.beside_pose is not None:
        other = [n for n in decision.beside_tie if n != POSE_ERROR]
        what = ('a range offset of the sensor changing between clouds' if other == [
            'range_drift'] else _join(other))
        return _out(True, 'beside_tie', f'beside the named effect, the pose and {what} '
                    'explain one more part alike (also_confounded_with): neither is named',
                    shown)
    small = pose.get('too_small')
    if small:
        return _out(False, None, f'its test passes ({_f(small["test_gain_per_matched_point"])} '
                    f'nats/point, z = {_f(small["test_z"], 1)}), but the correction it comes to '
                    f'({small["translation_rms_cm"]:.2f} cm and {small["rotation_rms_deg"]:.3f} '
                    'deg RMS), applied exactly, would gain '
                    f'{_f(small["applied_gain_per_matched_point"])} nats/point, below the '
                    f'{MIN_PRACTICAL_GAIN:g} that matters: the test\'s gain is not the pose\'s',
                    shown)
    to_range = pose.get('left_to_range')
    if to_range:
        how = ('explains the residual at least as well' if to_range['outcome'] == 'range'
               else 'explains it nearly as well, the pose short of the rule beyond it')
        return _out(False, None, f'{_test_passes(to_range)}, but a function of range '
                    f'alone {how} '
                    f'({_f(to_range["gain_per_matched_point"])} nats/point; the pose on top '
                    f'of it {_f(to_range["pose_gain_beyond"])} more, z = '
                    f'{_f(to_range["pose_z_beyond"], 1)}): a range error of the sensor that '
                    'follows range moves the clouds alike, so the pose is not claimed', shown)
    to_lasers = pose.get('left_to_pointing')
    if to_lasers:
        return _out(False, None, f'{_test_passes(to_lasers, " alone")}, but on top of '
                    f'{to_lasers["named"]} '
                    f'(fitted with the beams\' common turn; {_f(to_lasers["score"])} '
                    f'nats/point) it gains {_f(to_lasers["pose_gain_on_top"])} (z = '
                    f'{_f(to_lasers["pose_z_on_top"], 1)}), which does not pass the rule, '
                    f'while on the corrected pose they still gain '
                    f'{_f(to_lasers["score_on_pose"])} (z = {_f(to_lasers["z_on_pose"], 1)}): '
                    'a few beams off their direction read as a turned target, so the pose is '
                    'not claimed', shown)
    left = pose.get('left_by_bound') or pose.get('left_by_stand_in')
    if left:
        what = (f'on top of {_join(list(left["effects"]))}, which --fit left at its search '
                'bound: what the fit left may be the rest of that effect'
                if 'effects' in left else
                f'beside {left["named"]}, which stands in for a bias of range alone: what the '
                'stand-in leaves may be the rest of that bias')
        return _out(False, None, f'{_test_passes(left)} {what}, so the pose is not claimed',
                    shown)
    faces = pose.get('across_faces')
    if faces and not faces.get('transfers'):
        return _out(False, None, f'its {"constant" if pose.get("constant") else "per-cloud"} '
                    'test passes on random halves '
                    f'({_f(pose.get("gain_per_matched_point"))} nats/point, z = '
                    f'{_f(pose.get("z"), 1)}), but '
                    + ('fitted on the surfaces facing some ways it loses on those facing '
                       'others' if pose.get('constant') else
                       'held out it loses on the surfaces facing some ways')
                    + ' (across_faces): no rigid motion every '
                    'surface agrees on, so the pose is not claimed', shown)
    edges = pose.get('left_to_edges')
    if edges:
        return _out(False, None, f'{_test_passes(edges)}, but the target\'s outline '
                    f'contradicts it: on the {edges["edge_rays"]} returns whose outcome the '
                    f'correction changes at the silhouette and depth steps it gains '
                    f'{_f(edges["gain_per_edge_ray"])} nats per ray, z = {_f(edges["z"], 1)} '
                    '(silhouette): a range error fixed to the body or its faces moves no '
                    'edge, so the pose is not claimed', shown)
    if not pose.get('significant'):
        where = f' on top of {_join(on_top)}' if on_top else ''
        gain = pose.get('gain_per_matched_point')
        small = (f' (its held-out gain, {_f(gain)} nats/point, is below the '
                 f'{MIN_PRACTICAL_GAIN:g} that matters, whatever its z)'
                 if gain is not None and gain < MIN_PRACTICAL_GAIN and (pose.get('z') or 0) > 0
                 else '')
        return _out(False, None, f'its held-out test does not pass{where}{small}', shown)
    by_name = {c.name: c for c in cands}
    if decision.evidence in by_name:      # sunlight, named on solar_background's gain
        by_name[decision.missing] = by_name[decision.evidence]
    first = next((by_name[n] for n in named if n in by_name), None)
    if first is None:
        return _out(False, None, 'its test passes on top of an effect the verdict does not '
                    f'name ({_join(on_top) if on_top else "none"}), and nothing was weighed '
                    'against it', shown)
    ap = first.against_pose or {}
    after = ''
    if ap.get('passes_on_pose'):
        after = (f'; with the pose corrected, {first.name} still passes the rule '
                 f'({_f(ap.get("score_on_pose"))} nats/point, z = {_f(ap.get("z_on_pose"), 1)})'
                 ': it stands')
    elif ap.get('heldout_margin') is not None:
        after = (f'; weighed against the pose (its margin over the pose '
                 f'{_f(ap.get("heldout_margin"))} nats/point held out, '
                 f'{_f(ap.get("fitted_margin"))} as --fit leaves them), {first.name} stands')
    beside = first.pose_beside
    if beside and not beside.get('significant'):
        return _out(False, None, f'its {shown["test"]} test passes on top of {_join(on_top)} '
                    'alone, but not '
                    f'on top of {_join([first.name, *beside["with"]])} fitted together (as '
                    '--fit fits them): it gains nothing beyond the effects the verdict names'
                    + after, _test(beside, [first.name, *beside['with']]))
    alone = getattr(first, 'pose_on_top', None)
    if alone and not alone.get('significant'):
        return _out(False, None, f'its {_kind(alone)} test, the one the decision weighed (the '
                    f'larger held-out gain), does not pass on top of {first.name}' + after,
                    _test(alone, [first.name]))
    if ap.get('pose_significant_on_top') is False and ap.get('passes_on_pose'):
        return _out(False, None, f'{first.name}, a range error of the sensor, passes the rule '
                    'on the corrected pose and the pose test does not pass on top of it',
                    {**shown, 'gain_per_matched_point': ap.get('pose_gain_on_top'),
                     'z': ap.get('pose_z_on_top'), 'significant': False})
    return _out(False, None, f'weighed against {first.name} (judge_pose), {first.name} stands'
                + after, shown)


def _test_passes(left: dict, alone: str = '') -> str:
    """'its test passes (gain nats/point, z = z)' of a pose left to another test (its
    ``test_gain_per_matched_point`` and ``test_z``)."""
    return (f'its test passes{alone} ({_f(left["test_gain_per_matched_point"])} nats/point, '
            f'z = {_f(left["test_z"], 1)})')


def _out(reported: bool, kind: str | None, reason: str, decided_by: dict | None) -> dict:
    return {'reported': reported, 'reported_as': kind, 'reported_because': reason,
            'decided_by': decided_by}


def _figures(pose: dict, on_top: list[str]) -> dict:
    return {'test': 'constant' if pose.get('constant') else 'per cloud',
            'on_top_of': list(on_top),
            'gain_per_matched_point': pose.get('gain_per_matched_point'),
            'z': pose.get('z'), 'significant': bool(pose.get('significant'))}


def _test(t: dict, on_top: list[str]) -> dict:
    """A test recorded on a candidate (``pose_beside``, ``pose_on_top``)."""
    return {'test': _kind(t), 'on_top_of': on_top,
            'gain_per_matched_point': t.get('gain'), 'z': t.get('z'),
            'significant': bool(t.get('significant'))}


def _kind(t: dict) -> str:
    return 'constant' if t.get('pose_constant') else 'per cloud'


def _f(x, digits: int = 4) -> str:
    return 'n/a' if x is None else f'{x:.{digits}f}'


def _join(names: list[str]) -> str:
    names = list(names)
    if not names:
        return 'nothing'
    return names[0] if len(names) == 1 else ', '.join(names[:-1]) + ' and ' + names[-1]
