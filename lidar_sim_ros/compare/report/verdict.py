"""The verdict in plain words, and the lines ``lidar-sim compare`` prints.

The verdict says only what the diagnosis showed (``diagnosis.Decision``): where the
residual depends (given the other features, or on a confounded group of them), which
effect is missing and what adding it brings, or that two candidates are confounded in
this recording and which recording would separate them, or that no catalogue effect
explains what is left (with the pointer to writing one). Physics words for an effect
appear only when that effect is named.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from lidar_sim_ros.compare.diagnose import (beside, diagnosis, mixed_edges, pose_error,
                                            power_incidence, range_outside, spin_clock)
from lidar_sim_ros.compare.diagnose.plan import MOTION_RIVALS
from lidar_sim_ros.compare.model.materials import common_offset_m

EFFECT_WORDS = {
    'range_walk': 'range walk (intensity-dependent timing bias)',
    'incidence_angle': 'footprint elongation at oblique incidence',
    'snr_noise': 'range noise growing as the signal falls',
    'solar_background': 'false returns from background light (outliers at random ranges)',
    'beam_divergence': 'returns from the beam edge beyond the silhouette and mixed ranges at '
                       'depth steps',
    'time_offset': 'a clock offset between the pose and LiDAR stamps',
    'multipath': 'ghosts behind specular surfaces (MLI): the mirror image of another surface '
                 'at |SA| + |AB|',
    'range_drift': 'a range offset of the sensor drifting over the recording (thermal): the '
                   'same on every ray of a cloud, changing from cloud to cloud',
    'range_scale': 'a range scale error of the sensor (its clock, or light through air): a '
                   'range error growing with the range',
    'laser_pointing': 'each laser\'s beam off its configured direction (a pointing error per '
                      'laser): the sensor reports a point along the configured direction at '
                      'the range measured along the true beam, a range error of r tan(incidence) '
                      'times the offset along the surface\'s slope. The fix: calibrate each '
                      'laser\'s pointing, with a recording of a flat target at a known pose '
                      '(tilted, so that its range changes across every laser\'s tile)',
    'surface_offset': 'the target\'s surfaces lying off its mesh (as-built vs CAD: the '
                      'mesh scaled off the real target, or blankets standing proud of the '
                      'structure it shows), not a sensor effect: check the mesh against the '
                      'target',
}
# Catalogue effects of the target, not the sensor: a verdict weighing them against the pose
# does not call them the sensor's.
NOT_THE_SENSOR = ('surface_offset',)
# What varies each catalogue effect independently of the others: the recording that
# separates two confounded candidates varies what drives one at fixed values of what
# drives the other.
DRIVEN_BY = {
    'range_walk': ('received power', 'another distance (power falls as 1/r^2 at the same '
                   'incidence) or surfaces of other reflectance'),
    'snr_noise': ('received power', 'another distance (weaker returns at the same incidence)'),
    'incidence_angle': ('incidence angle', 'another attitude of the target (other incidence '
                        'angles at the same distance)'),
    'beam_divergence': ('distance to silhouettes and depth steps', 'another distance (the '
                        'footprint grows with range) or a target with other edges in view'),
    'time_offset': ('the target\'s motion', 'another tumble rate or a static target (the '
                    'offset acts through the motion only)'),
    'solar_background': ('returns at random ranges', 'the target away from the sun or with '
                         'the sun off (false returns change, the target does not)'),
    'multipath': ('mirror paths off specular surfaces', 'another attitude of the target '
                  '(the mirror rays of its specular surfaces meet other surfaces or none)'),
    'laser_pointing': ('laser, through the slope of the surface its tile falls on',
                       'a flat target at a known pose, tilted (every laser sees the same '
                       'known slope), or another attitude of the target (other slopes under '
                       'each tile at the same incidence)'),
    'surface_offset': ('place of each surface on the body and 1 / cos(incidence)',
                       'another distance (a footprint grows with range, a surface offset '
                       'does not), or with the target measured on a surveyed fixture'),
}


def verdict(summary: dict, attribution, cands: list, decision) -> str:
    """One plain-language paragraph (module doc)."""
    feats = attribution.features if attribution is not None else []
    by_name = {f.name: f for f in feats}
    parts = [scan_pattern_words(summary)] if scan_pattern_off(summary) else []
    if attribution is not None and attribution.driver:
        f = by_name[attribution.driver]
        parts.append(f'The range residual depends most on {f.name}, given the other '
                     f'features: {f.trend}.')
    elif attribution is not None and attribution.confounded:
        names = attribution.confounded
        # "Cannot be told" is said of candidates only when none is named (a tie in
        # confounded_with); of features it says what the features alone show.
        parts.append(f'The range residual depends on {_join(names)} together; in this '
                     'recording they stand in for each other (each explains the residual '
                     'alone, none given the others), so the features alone do not show '
                     'which of them drives it.')
    elif attribution is not None and attribution.significant:
        parts.append(f'The range residual depends on the features jointly '
                     f'({attribution.structure_gain:.4f} nats/point held out), no single one '
                     'dominating.')
    missing = decision.missing
    beyond_bound = (summary.get('reference_pose') or {}).get('left_by_bound')
    beside_stand_in = (summary.get('reference_pose') or {}).get('left_by_stand_in')
    to_range = (summary.get('reference_pose') or {}).get('left_to_range')
    faces = across_faces_left(summary, decision)
    edges = (summary.get('reference_pose') or {}).get('left_to_edges')
    if missing == 'sunlight':
        parts.append(_sunlight_named(summary, next(c for c in cands
                                                   if c.name == decision.evidence)))
    elif missing:
        c = next(c for c in cands if c.name == missing)
        params = _params_words(c.params)
        gain, caveat = _gain_words(summary, c)
        words = EFFECT_WORDS.get(missing, missing)
        if missing == 'laser_pointing' and isinstance(c.params.get('rms_offset_deg'), float):
            words = words.replace('configured direction (',
                                  f'configured direction by about '
                                  f'{c.params["rms_offset_deg"]:.2g} deg RMS (', 1)
        if missing == 'time_offset' and summary.get('point_times') in ('stamp', 'scan pattern'):
            how = ('these clouds carry no per-point time' if summary['point_times'] == 'stamp'
                   else 'these clouds carry no per-point time field (their times come from '
                   'the scan pattern, read as stamped at the scan start)')
            words = ('a time offset between the poses and the points: a clock offset, or, '
                     f'as {how}, the place of the cloud stamp in the scan (start, middle or '
                     'end), which gives the same data')
            st = summary.get('stamp_place')
            if st:
                words += stamp_place_words(st)
        alone = summary.get('range_alone') or {}
        stand_in = (alone.get('named') == missing
                    and alone.get('stands_in_for_a_range_bias_outside_the_catalogue'))
        if stand_in:
            parts.append(range_alone_words(alone))
        parts.append(
            (f'As a stand-in, with per-material offsets and sigmas refit (as --fit does), '
             if stand_in else
             f'This is {words}. With per-material offsets and sigmas refit (as --fit does), ')
            + f'adding {missing} with {params} {gain} (held-out gain {c.score:.4f} nats/point, '
            f'z = {c.z:.1f}).{caveat} '
            + (f'--effect {missing} --fit adds it as a stand-in; an effect of your own that '
               'follows range (docs/effects.md, "Write your own effect") would fit it better.'
               if stand_in else f'Run again with --effect {missing} --fit to add it.')
            + (walk_scale_words(summary.get('intensity_gain'), c.params)
               if missing == 'range_walk' else ''))
        if decision.also:
            parts.append(f'{decision.also} also explains a separate part of the residual'
                         f'{_on_top_words(cands, decision.also, missing)}: '
                         f'expect it in the next run.{_together_words(c)}')
        pair = power_incidence.pair_words(decision.pair_z)
        if pair:
            parts.append(pair)
        own = power_incidence.figures_in(decision.pair_z) or {}
        if own.get('also') == 'not_shown':
            parts.append(power_incidence.also_not_shown_words(own, missing))
        for more in decision.also_more:
            parts.append(f'{more} also explains a separate part of the residual'
                         f'{_on_top_words(cands, more, missing)}: add it after '
                         f'{decision.also}.')
        parts.extend(stands_in_words(decision))
        parts.extend(range_split_words(decision))
        lasers = laser_intensity_words(summary.get('laser_intensity'))
        if lasers:
            parts.append(lasers)
        if (c.against_pose or {}).get('constant_pose_footing', {}).get('dt_beside_pose_s') \
                is not None:
            parts.append(clock_beside_pose_words(c))
        elif c.against_pose:
            parts.append(_against_pose_words(c))
            parts.extend(constant_pose_beside_words(c))
    elif diagnosis.POSE_ERROR in decision.confounded_with:
        parts.append(pose_tie_words(decision, summary, cands))
        if decision.also:
            parts.append(f'{decision.also} explains a separate part of the residual, '
                         'with the pose corrected too: expect it in the next run.')
    elif decision.confounded_with:
        names = decision.confounded_with
        scores = ', '.join(f'{n} {next(c.score for c in cands if c.name == n):.4f}'
                           for n in names)
        advice = _separation(names, summary)
        own = power_incidence.figures_in(decision.pair_z) or {}
        if summary.get('separation_plan'):
            advice += ' ' + plan_words(summary['separation_plan'],
                                       by_form_only=own.get('outcome') == 'tie')
        alike = ('explain the data equally well within their uncertainty' if
                 own.get('outcome') != 'tie' else
                 'each explain the data, the one by its form better than the other, but '
                 'neither by a part of its own')
        parts.append(
            f'{_join(names)} {alike} (held-out '
            f'gains {scores} nats/point): they are confounded in this recording, so none is '
            f'named. {advice} If you know which it is, add it with --effect NAME --fit.')
        pair = power_incidence.pair_words(decision.pair_z)
        if pair:
            parts.append(pair)
        if own.get('outcome') == 'tie':
            # ``Diagnosis.power_or_incidence``: neither has a part of its own.
            words = power_incidence.tie_words(own)
            parts.append(words[0].upper() + words[1:] + '.')
    elif decision.pose is not None:
        parts.append(pose_words(decision.pose, cands))
        spin = (summary.get('reference_pose') or {}).get('clock_equivalent')
        if spin and spin.get('shown'):
            parts.append(spin_clock.words(spin))
        below = clock_below_margin_words(cands)
        if below:
            parts.append(below)
    elif not beyond_bound and not to_range and not faces and not edges:
        parts.append(_nothing_named(summary, attribution, cands))
    if faces:
        parts.append(across_faces_words(summary['reference_pose']))
    if edges:
        parts.append(silhouette_words(summary['reference_pose']))
    if beyond_bound:
        parts.append(bound_remainder_words(beyond_bound))
    if beside_stand_in:
        parts.append(stand_in_remainder_words(beside_stand_in))
    if to_range:
        parts.append(range_of_range_words(to_range))
    if decision.pose is not None and (missing or decision.confounded_with) and \
            diagnosis.POSE_ERROR not in decision.confounded_with:
        kind = _correction(decision.pose)
        parts.append(f'Besides, {decision.pose.words()} (held-out gain of '
                     f'{kind[0].lower()}{kind[1:]} {decision.pose.gain:.4f} nats/point, '
                     f'z = {decision.pose.z:.1f}): check the tracking system or the extrinsic '
                     'calibration.')
    region = getattr(decision, 'region', None)
    if region is not None and decision.pose is None and region.outcome != 'pose':
        parts.append(region_words(region))
    if getattr(decision, 'beside_tie', None) and decision.beside_pose is not None:
        named = [n for n in (missing, decision.also) if n]
        parts.append(range_offset_beside_words(decision.beside_pose, named)
                     if diagnosis.RANGE_DRIFT in decision.beside_tie else
                     pose_beside_tie_words(decision.beside_pose, named, [
                         c for c in cands if c.name in decision.beside_tie]))
    vetoed = [c for c in cands if c.vetoed and c.significant and c.practical
              and c.name != missing and c.name not in decision.confounded_with]
    mechanism = mechanism_words(decision, cands)
    if vetoed and (missing or decision.confounded_with) and not (
            mechanism and vetoed[0].name in mechanism):
        parts.append(set_aside_words(vetoed[0]))
    parts.extend(mechanism.values())
    mats = summary['materials']
    bad = [n for n, m in mats.items() if m['bias_mismatch'] or m['sigma_mismatch']]
    if bad:
        def row(n: str) -> str:
            m = mats[n]
            return (f'{n} (bias {100 * (m["measured_bias_m"] - m["model_bias_m"]):+.1f} cm, '
                    f'sigma x {m["measured_sigma_m"] / max(m["model_sigma_m"], 1e-9):.2f})')
        rows = ', '.join(row(n) for n in bad)
        named = [n for n in (missing, decision.also) if n]
        if decision.pose is not None:
            note = (' They are measured on the recorded pose, which moves them with the '
                    'pose error reported above: correct the pose first (--effect '
                    'pose_error --fit measures them on the corrected pose).')
        elif named:
            note = (f' They are measured without {_join(named)}, which can move every '
                    f'range too (a walk\'s mean over the target\'s intensities, say): '
                    f'--effect {named[0]} --fit measures them with it.')
        else:
            note = ''
        parts.append(f'Per-material range bias/sigma differ from the configuration for {rows}: '
                     f'see materials.yaml (--fit refits them).{note}')
        # Every material off alike is a sensor offset or the pose only when no named
        # effect could carry it.
        common = common_offset_words(mats) if decision.pose is None and not named else ''
        if common:
            parts.append(common)
    occluded = (summary.get('occlusion') or {}).get('interpretation')
    if occluded:
        parts.append(f'{occluded}.')
    ghosts = (summary.get('crosstalk') or {}).get('interpretation')
    if ghosts:
        parts.append(f'{ghosts}.')
    later = (summary.get('multiple_returns') or {}).get('interpretation')
    if later:
        parts.append(f'{later}.')
    un = summary['unmatched']
    if un['points']:
        parts.append(f'{un["points"]} points ({100 * un["fraction"]:.2f} %) miss the target '
                     f'model: {un.get("interpretation", "")}.')
    spread = summary.get('point_time_spread_s')
    if spread:
        parts.append(f'The clouds carry no per-point time: the model widens each point\'s '
                     f'spread by the target\'s motion over the unknown point times (fitted '
                     f'spread {1e3 * spread:.0f} ms), which is not a physical effect.')
    if summary.get('sunlight'):
        parts.append(sunlight_words(summary['sunlight'], hint=missing != 'sunlight'))
    tie = ((summary.get('reference_pose') or {}).get('rate') or {}).get('tied_with_range_over_scan')
    if tie:
        parts.append(scan_tie_words(tie))
    if summary.get('scan_pattern_rate_error') is not None:
        parts.append(scan_rate_words(summary['scan_pattern_rate_error']))
    return ' '.join(parts)


def scan_rate_words(eps: float) -> str:
    """The verdict's sentence on a scan pattern running (1 + eps) fast (``scan_rate``): the
    same figure at other instants, so its times come from the curve; nothing is named."""
    return (f'The scan pattern runs {100 * abs(eps):.2f} % {"fast" if eps > 0 else "slow"} '
            f'against the configuration (its frequencies x {1 + eps:.5f}): it traces the '
            'configured figure at other instants, so the point times were taken from its '
            'curve; lidar-sim calibrate scan writes the rate.')


def scan_tie_words(tie: dict) -> str:
    """One rate of the reference pose for the recording that did not gain beyond a range
    offset of the sensor growing over each scan (``pose_error.range_over_scan``)."""
    return (f'The residual also changes over each scan the same way in every cloud: one '
            f'rate of the reference pose over the scan gains {tie["rate_gain"]:.4f} '
            f'nats/point held out, a range offset of the sensor growing over the scan '
            f'{tie["range_over_scan_gain"]:.4f}, and the rate beyond it '
            f'{tie["rate_beyond_range_over_scan"]:.4f} (z = {tie["z"]:.1f}): a pose drifting '
            'along the line of sight within each scan (a tracking pose sampled once a cloud '
            'and held) and the sensor\'s range changing over the scan cannot be told apart '
            'here, and neither is named; a target seen across a wide angle, or a static '
            'target on a surveyed pose, separates them.')


# Clouds without point times of which fewer than this share of the directions match the
# configured scan pattern: the verdict says first that the pattern is not the sensor's.
SCAN_PATTERN_OFF_BELOW = 0.5
# A named effect's value fitted with the pose corrected is quoted beside the one on the
# recorded pose when they differ by more than this share of the larger.
VALUE_SHIFT = 0.2
# A per-cloud pose correction this much along the line of sight (share of its mean
# square) moves the clouds as a range offset of the sensor would: said, not decided.
LINE_OF_SIGHT_SHARE = 0.75


# A catalogue effect that is a physical mechanism of another: a beam footprint at oblique
# incidence is what makes a range bias growing with the incidence angle. Where the
# mechanism ranked above the effect named (or tied) for it, or passed the rule, and is
# not named, the verdict says what it scored and why not (``mechanism_words``).
MECHANISM_OF = {'incidence_angle': ('beam_divergence',)}


def laser_intensity_words(tie: dict | None) -> str:
    """laser_bias named (or 'also') beside a range walk read from the measured intensity,
    its offsets following k times each laser's mean log intensity ratio (summary.json's
    ``laser_intensity``, ``laser_gains.intensity_tie``): a tie of causes, said."""
    if not tie or not tie.get('ties'):
        return ''
    return (f'laser_bias\'s offsets follow k times each laser\'s mean log ratio of measured '
            f'to model intensity (k = {tie["k_m"]:.4g} m, the walk\'s; correlation '
            f'{tie["correlation"]:.2f} over {tie["lasers"]} lasers, and k times the ratio '
            f'gives {100 * tie["explained_share"]:.0f} % of their spread with nothing fitted): '
            'they may be a per-channel intensity calibration read through the range walk '
            '(the walk, read from intensity, moves a laser\'s ranges by k ln of its intensity '
            'gain) rather than range offsets of the lasers; this recording cannot tell the two '
            'causes apart (calibrating each laser\'s intensity would).')


def mechanism_words(decision, cands: list) -> dict[str, str]:
    """One sentence per candidate that is the mechanism (MECHANISM_OF) of a named,
    tied or 'also' effect but not named itself, where it passed the rule or its held-out
    gain is at least that effect's (a reader of the ranking would ask why not): what it
    scored and which part of the rule it fails, from the fit's own figures. Name ->
    sentence."""
    by_name = {c.name: c for c in cands}
    said = [n for n in (decision.missing, decision.also, *decision.confounded_with) if n]
    out = {}
    for name in said:
        shown = by_name.get(name)
        for mech in MECHANISM_OF.get(name, ()):
            c = by_name.get(mech)
            if (c is None or mech in said or mech in out or c.error is not None
                    or shown is None or not c.practical
                    or not (c.significant or c.score >= shown.score)):
                continue
            why = _not_named_why(c, decision, name)
            if why:
                out[mech] = (f'{mech}, a mechanism of {name}, is not named: {why}.')
    return out


def _not_named_why(c, decision, of: str) -> str:
    """Which part of the rule a candidate fails, in the fit's figures ('' if none is
    known: then it is not said)."""
    params = _params_words(c.params)
    fitted = (f'fitted with {params}, it gains {c.score:.4f} nats/point held out '
              f'(z = {c.z:.1f})')
    if c.vetoed:
        return f'{fitted}, but {c.vetoed}'
    withheld = (decision.withheld or {}).get(c.name)
    if withheld:
        return f'{fitted}, but {withheld}'
    if not c.significant and c.matched_gain <= -diagnosis.MIN_PRACTICAL_GAIN:
        share = 100 * c.unmatched_explained
        rests = (f'all of it on the points that miss the target model, {share:.0f} % of '
                 'which it explains'
                 if c.unmatched_explained > 0 else 'none of it on the matched points')
        return (f'{fitted}, {rests}; on the matched ranges it loses '
                f'{-c.matched_gain:.4f} nats/point (z = {c.z_matched:.1f}), so it does not '
                f'pass the rule: the range residual {of} explains is not shown to be its')
    if not c.significant:
        return f'{fitted}, which does not pass the rule (not decisive)'
    against = (decision.pair_z or {}).get(c.name)
    if isinstance(against, dict) and 'margin' in against:
        # Passing the rule, neither tied nor named: the one it was weighed against (the
        # named one, or the first of the tie) is decisively better (``decide``).
        best = decision.missing or (decision.confounded_with or [of])[0]
        return (f'{fitted}, but {against["margin"]:.4f} nats/point less than {best} on the '
                f'same points (z = {against.get("z", float("nan")):.1f})')
    return ''


def stands_in_words(decision) -> list[str]:
    """Why a candidate ranked above the named one is not named: beside it, it only stood
    in for a third (``Diagnosis.stands_in_beside``; ``against_named[NAME]``)."""
    out = []
    for name, w in (decision.pair_z or {}).items():
        if not isinstance(w, dict) or 'stands_in_for' not in w:
            continue
        third, beside = w['stands_in_for'], w['beside']
        figs = w.get('gain_z_on_top_of_both') or {}
        mine, theirs = figs.get(name), figs.get(third)
        nums = ''
        if mine and theirs and None not in (*mine, *theirs):
            nums = (f' ({round(mine[0], 4) + 0.0:.4f} nats/point on top of {beside} and {third} '
                    f'fitted together, while {third} gains {theirs[0]:.4f}, z = {theirs[1]:.1f}, '
                    f'on top of {beside} and {name})')
        out.append(f'{name} explains about as much alone, but beside {beside} it only '
                   f'stands in for {third}{nums}, so it is not named.')
    return out


def range_split_words(decision) -> list[str]:
    """Why a standoff or a footprint level with the other on held-out points is not
    named: fitted on the nearer half of the ranges and scored on the farther (and back)
    it did worse (``Diagnosis.range_decides``; ``against_named[NAME]``)."""
    out = []
    for name, w in (decision.pair_z or {}).items():
        if not isinstance(w, dict) or 'range_split_by' not in w:
            continue
        out.append(f'{name} explains about as much on held-out points, but fitted on the '
                   f'nearer half of the ranges and scored on the farther (and back) it does '
                   f'{w["range_split_margin"]:.4f} nats/point worse than {w["range_split_by"]} '
                   f'(z = {w["range_split_z"]:.1f}): a footprint grows with range, a surface '
                   'standing proud does not, so it is not named.')
    return out


def common_offset_words(mats: dict) -> str:
    """The verdict's sentence when every material's range is off by about the same
    amount and no pose error is reported: a range offset of the sensor and a target
    recorded nearer or farther along the line of sight move every material alike, and
    on a narrow target the one cannot be told from the other; '' otherwise."""
    common = common_offset_m([m['measured_bias_m'] - m['model_bias_m'] for m in mats.values()
                              if m.get('measured_bias_m') is not None
                              and m.get('model_bias_m') is not None])
    if common is None:
        return ''
    return (f'Every material\'s range is {"long" if common > 0 else "short"} by about '
            f'{100 * abs(common):.1f} cm alike: a range offset of the sensor, or the '
            'reference pose along the line of sight (the target recorded '
            f'{"nearer" if common > 0 else "farther"} than it was), which this recording cannot '
            'tell apart; a target on a surveyed pose, or one seen across a wide angle, '
            'separates them.')


def scan_pattern_off(summary: dict) -> bool:
    """Clouds without point times whose directions mostly miss the configured pattern."""
    share = summary.get('scan_pattern_match')
    return (summary.get('point_times') == 'stamp' and share is not None
            and share < SCAN_PATTERN_OFF_BELOW)


def scan_pattern_words(summary: dict) -> str:
    """The verdict's first sentence when the scan pattern is off (``scan_pattern_off``):
    without point times, a pattern that is not the sensor's leaves every point's time
    unknown, so a timing claim rests on the cloud stamps only."""
    return (f'The scan pattern is off: the clouds carry no per-point time and only '
            f'{100 * summary["scan_pattern_match"]:.0f} % of the measured directions match a '
            'shot of the configured scan pattern, so the configuration is not this sensor\'s '
            'pattern (its frequencies, phases or extent differ) and each point\'s time within '
            'the scan is unknown. Fix the pattern first: lidar-sim calibrate scan (from a '
            'recording with per-point times) writes the sensor\'s pattern; any timing claim '
            'below rests on the cloud stamps alone.')


def stamp_place_words(st: dict) -> str:
    """A fitted time offset that a stamp convention gives with the clocks in step
    (``summary.json`` ``stamp_place``): every place of the stamp with the clock offset it
    needs, none named (``compare/diagnose/stamp_place.py``)."""
    share = abs(st['dt_s'] / st['period_s'])
    part = 'half the' if abs(share - 0.5) < 1e-6 else 'one'

    def reading(r: dict) -> str:
        c = 1e3 * r['clock_offset_s']
        if abs(c) < 0.5:
            return f'at the {r["place"]} with the clocks in step'
        return (f'at the {r["place"]} with the poses stamped {abs(c):.0f} ms '
                f'{"late" if c > 0 else "early"}')
    parts = [reading(r) for r in st.get('readings') or []]
    said = ', or '.join([', '.join(parts[:-1]), parts[-1]] if len(parts) > 1 else parts)
    return (f' (the {1e3 * st["fitted_dt_s"]:+.1f} ms fitted, {part} '
            f'{1e3 * st["period_s"]:.0f} ms frame, is what a stamp of the scan gives {said}; '
            'without per-point times the place of the stamp and a clock offset give the same '
            'data, so which one it is cannot be told here, and a recording with the driver\'s '
            'per-point time field, or the driver\'s documented stamp place, separates them; '
            'the model needs the offset all the same)')


def pose_words(pose, cands: list = ()) -> str:
    """The verdict when a reference-pose error explains the residual (``pose_error``).
    ``cands``: candidates that still pass the rule on the corrected pose but were not
    the effect weighed against it (``Diagnosis.judge_pose``) are said, not named."""
    still = [c for c in cands if (c.against_pose or {}).get('passes_on_pose')]
    tail = ('with it no catalogue effect passes the rule.' if not still else
            'with it the effect the residual pointed to adds nothing held out; '
            + ', '.join(f'{c.name} still gains {c.against_pose["score_on_pose"]:.4f} '
                        f'nats/point on the corrected pose (z = {c.against_pose["z_on_pose"]:.1f})'
                        for c in still)
            + ', not named: it ranked below the effect the pose explains, and a pose error '
            'left in part by the correction grows with the incidence angle as a sensor '
            'effect can.')
    share = getattr(pose, 'line_of_sight_share', None)
    if (share is not None and share >= LINE_OF_SIGHT_SHARE
            and not getattr(pose, 'constant', False)):
        what = (f': {100 * share:.0f} % of the correction moves the clouds along the line '
                'of sight, as a range offset of the sensor that changes from cloud to cloud '
                'would (a frame-sync or counter error): the reference pose, or the sensor\'s '
                'range, cannot be told apart here; check the tracking system first, then '
                'range a static target on a surveyed pose')
    else:
        what = (': not a sensor effect; check the tracking system or the extrinsic '
                'calibration')
        if share is not None and share >= LINE_OF_SIGHT_SHARE:
            what += (f'. {100 * share:.0f} % of it is along the line of sight, so every '
                     'material\'s range offset moves with it; a range offset of the sensor '
                     'would move them alike, but not the ranges across the target as the '
                     'moved pose does (n.d / n.u: the correction is fitted on top of the '
                     'per-material offsets)')
    said = f'{pose.words()[0].upper()}{pose.words()[1:]}{what}'
    raycast = getattr(pose, 'raycast', None)
    if raycast and raycast.get('line_of_sight'):
        # Weighed on the candidates' footing (``Diagnosis.weigh_on_ray_footing``).
        los = raycast['line_of_sight']
        return (f'{said}. Its own held-out test is linear and leaves the rays near the limbs '
                f'out ({pose.gain:.4f} nats/point, z = {pose.z:.1f}); moved '
                f'{los["shift_cm"]:+.1f} cm along the line of sight and every ray raycast '
                'again, each point scored as the candidates are (each material\'s offset '
                f'refit, {los["put_back"]} returns put back on the target), it gains '
                f'{los["gain_per_point"]:.4f} nats/point (z = {los["z"]:.1f}), and on the '
                f'moved target {_join(raycast["explains"])} '
                f'{"gain" if len(raycast["explains"]) > 1 else "gains"} nothing: '
                f'{"they" if len(raycast["explains"]) > 1 else "it"} took the '
                'perspective of a target recorded nearer or farther, at its limbs. No sensor '
                'effect is named.')
    if raycast:
        # Reported on the raycast footing (``Diagnosis.weigh_line_of_sight``,
        # ``line_of_sight_alone``): its own test did not pass.
        said += ('. Its own held-out test is linear and leaves grazing rays out, and there it '
                 'gains no more than a range offset of the sensor would '
                 f'({pose.gain:.4f} nats/point, z = {pose.z:.1f}); but raycast again with it, ')
    if raycast and not raycast['explains']:
        return (f'{said}the model fits {raycast["fitted_margin_charged"]:.4f} nats/point '
                'better than without it as --fit leaves them, its six parameters charged, '
                'where the per-material offsets (a range offset of the sensor) are refit in '
                'both: a target recorded nearer or farther changes the ranges near its limbs '
                'and across its depth steps too. No catalogue effect passes the rule.')
    if raycast:
        return (f'{said}{_join(raycast["explains"])} gain nothing, and it fits '
                f'{raycast["fitted_margin_charged"]:.4f} nats/point better than '
                f'{"each" if len(raycast["explains"]) > 1 else "it"} as --fit leaves them, '
                'its six parameters charged: a target recorded nearer or farther changes the '
                'ranges near its limbs as 1 / cos(incidence), which they took. No sensor '
                'effect is named.')
    return (f'{said}. {_correction(pose)} gains {pose.gain:.4f} nats/point held out '
            f'(z = {pose.z:.1f}), and {tail}')


def _correction(pose) -> str:
    """The pose correction as tested: one for all the clouds, or one per cloud."""
    if (getattr(pose, 'constant', False) and getattr(pose, 'rate_supported', False)
            and getattr(pose, 'rate_in_test', True)):
        return ('One correction of the target pose for the whole recording and its rate '
                'over the scan')
    return ('One rigid correction of the target pose for the whole recording'
            if getattr(pose, 'constant', False) else
            'A rigid correction of the target pose per cloud')


def _corrected_how(constant: bool) -> str:
    """How the pose was corrected, as in "with the pose corrected ..."."""
    return 'for the whole recording' if constant else 'per cloud'


def _against_pose_words(c) -> str:
    """Why a range error of the sensor was named rather than the reference pose
    (``Diagnosis.weigh_pose_rivals``: ``c.against_pose``)."""
    ap = c.against_pose
    how = _corrected_how(bool(ap.get('pose_constant')))
    if ap.get('passes_on_pose'):
        return (f'A reference pose off along the line of sight moves clouds too, but with '
                f'the pose corrected {how} {c.name} still gains {ap["score_on_pose"]:.4f} '
                f'nats/point held out (z = {ap["z_on_pose"]:.1f}): '
                + ('it is the target\'s surfaces, not the pose.' if c.name in NOT_THE_SENSOR
                   else 'it is the sensor.')
                + _value_on_pose(c))
    return (f'A reference pose off along the line of sight moves clouds too, and on held-out '
            f'points the two leave each other nothing; but with the pose corrected {how} '
            f'and the model raycast again (rays at silhouettes and depth steps then meet the '
            f'surfaces the moved target puts there) the fit is {ap.get("fitted_margin") or 0:.4f} '
            f'nats/point worse than with {c.name}, as --fit leaves them: the rays at the edges '
            'did not move, the ranges did.')


def set_aside_words(c) -> str:
    """Why the first candidate set aside for its shape is not named; for lasers whose
    offsets hold across the tiles only with the named effect and its 'also' in the model
    (``Diagnosis.lasers_beside_named``), that they come next."""
    if c.beside and c.beside_gain:
        named = c.beside.split(' and ')
        flags = ' '.join(f'--effect {n}' for n in named)
        return (f'{c.name} is the next effect: alone it is set aside ({c.vetoed}), but with '
                f'{c.beside} fitted together in the model its offsets hold across the tiles '
                f'and it still gains {c.beside_gain["gain"]:.4f} nats/point held out '
                f'(z = {c.beside_gain["z"]:.1f}): expect it once they are fitted '
                f'(run again with {flags} --fit).')
    return f'{c.name} would raise the likelihood but is not the missing effect: {c.vetoed}.'


def constant_pose_beside_words(c) -> list[str]:
    """Beside a range term named with a constant pose along the line of sight
    (``Diagnosis.range_term_beside_constant_pose``: its ``against_pose``): the constant
    correction, what the candidates the decision had named gain on the corrected pose
    (``displaced``), the per-cloud correction on top, and the veto it passed there.
    Empty for every other naming."""
    ap = c.against_pose or {}
    if 'per_cloud_gain_on_top' not in ap:
        return []
    displaced = ap.get('displaced') or {}
    gains = ', '.join(f'{n} gains {g:.4f} nats/point (z = {z:.1f})' for n, (g, z)
                      in displaced.items() if g is not None and z is not None)
    out = [f'Fitted on top of {c.name}, one correction of the reference pose for the whole '
           f'recording moves the target {ap.get("pose_translation_cm") or 0:.1f} cm and '
           'takes the materials\' common offset (a motion along the line of sight); with it '
           'applied and the model raycast again, '
           + (f'{gains}, not decisive: on the recorded pose it took what that constant '
              'pose leaves at the limbs (a range change growing toward grazing '
              'incidence); and ' if gains else '')
           + 'a correction per cloud on top of '
           f'{c.name} gains {ap.get("per_cloud_gain_on_top") or 0:.4f} nats/point '
           f'(z = {ap.get("per_cloud_z_on_top") or 0:.1f}).']
    if ap.get('veto_on_recorded_pose'):
        out.append('On the recorded pose it was set aside (' + ap['veto_on_recorded_pose']
                   + '); with the pose corrected it holds across the materials.')
    return out


def clock_below_margin_words(cands: list) -> str:
    """Beside one rigid correction reported alone: a clock offset whose part on top of
    it, fitted together on the corrected pose, is decisive but below the margin that
    matters (``Diagnosis.clock_beside_constant_pose``); '' otherwise."""
    c = next((c for c in cands if c.name == 'time_offset'), None)
    on = ((c.against_pose or {}).get('constant_pose_footing') or {}) if c is not None else {}
    if (on.get('nested') or {}).get('fixed_spin'):
        return ''        # a constant spin: the clock is the pose's rotation (spin_clock)
    own = (on.get('nested') or {}).get('clock_over_pose')
    if own is not None:
        # The nested raycast test decides (``clock_nested``): its figures are the ones said.
        if not own.get('decisive') or own.get('passes'):
            return ''
        z, gain, where = own['z'], own['gain_per_point'], 'every ray raycast again'
    elif not on.get('clock_decisive_over_pose') or on.get('clock_passes_over_pose'):
        return ''
    else:
        z, gain, where = on['clock_over_pose_z'], on['clock_over_pose_gain'], 'the corrected pose'
    return (f'A clock offset between the pose and LiDAR stamps would move the target much as '
            f'this correction does; fitted together with it on {where}, a clock '
            f'offset keeps a part of its own, decisive (z = {z:.1f}) but '
            f'below the margin that matters ({gain:.4f} nats/point held '
            'out), so it is not named: the reference pose may be off with a clock offset '
            'beside it. A recording in which the target turns at another rate or about '
            'another axis (a clock offset follows the motion, a pose offset does not) would '
            'separate them.')


def clock_beside_pose_words(c) -> str:
    """Beside one rigid correction of the reference pose for the recording
    (``Diagnosis.clock_beside_constant_pose``: ``c.against_pose['constant_pose_footing']``
    and its ``nested`` figures, ``clock_nested``): the clock's own part on top of the
    correction and the correction's on top of the clock, both raycast, and the clock
    offset fitted beside it."""
    on = c.against_pose['constant_pose_footing']
    nest = on.get('nested') or {}
    own, pose = nest.get('clock_over_pose') or {}, nest.get('pose_over_clock') or {}
    rec = c.against_pose.get('recorded_pose') or {}
    return (f'One rigid correction of the reference pose for the whole recording takes '
            f'most of what the clock offset does (on a target turning about a moving axis a '
            f'clock offset turns the recorded attitude about the spin axis), but with the '
            f'two fitted together and every ray raycast again (the returns each puts back '
            f'counted, on {nest.get("n_points", 0)} points), the clock offset keeps a part of '
            f'its own: {own.get("gain_per_point", float("nan")):.4f} nats/point on top of the '
            f'correction (z = {own.get("z", float("nan")):.1f}), the correction '
            f'{pose.get("gain_per_point", float("nan")):.4f} (z = '
            f'{pose.get("z", float("nan")):.1f}) on top of the clock. Fitted beside the '
            f'correction the clock offset is dt_s = {on["dt_beside_pose_s"]:.4f}; the '
            'held-out gain above is its own part, the RMSE and NLL are on the reference pose '
            'corrected by that correction (fitted on top of the clock and raycast again, as '
            '--effect pose_error --fit corrects it), so the NLL after them holds the pose\'s '
            'part too. Fitted alone on the recorded pose the clock offset is '
            f'{on["dt_alone_s"]:.4f} s' + (
                f' ({rec["score"]:.4f} nats/point held out, z = {rec["z"]:.1f})'
                if rec.get('score') is not None and rec.get('z') is not None else '')
            + ': it takes part of the pose\'s offset, so correct the pose too.')


def _together_words(c) -> str:
    """Its fitted figures refitted with the effect that also explains a part in the
    model (``together``, ``Diagnosis.fit_together``), where they differ from those
    alone by more than VALUE_SHIFT."""
    tog = getattr(c, 'together', None) or {}
    moved = {k: v for k, v in (tog.get('params') or {}).items()
             if isinstance(c.params.get(k), float)
             and abs(v - c.params[k]) > VALUE_SHIFT * max(abs(c.params[k]), abs(v), 1e-12)}
    if not moved:
        return ''
    both = ', '.join(f'{k} = {v:.4g} (alone: {c.params[k]:.4g})' for k, v in moved.items())
    return (f' Fitted together with {tog["with"]} (each refitted with the other in the '
            f'model until they settle), {both}: alone it takes part of the other\'s shape, '
            f'so add both (--effect {c.name} --effect {tog["with"]} --fit fits them together).')


def _value_on_pose(c) -> str:
    """Its fitted figures with the pose corrected, where they differ from those on the
    recorded pose by more than VALUE_SHIFT (``against_pose['params_on_pose']``): the
    pose error takes part of what the effect's value rests on, one way or the other."""
    on_pose = _summary_params((c.against_pose or {}).get('params_on_pose'))[0]
    moved = {k: v for k, v in on_pose.items()
             if isinstance(v, float) and isinstance(c.params.get(k), float)
             and abs(v - c.params[k]) > VALUE_SHIFT * max(abs(c.params[k]), abs(v), 1e-12)}
    if not moved:
        return ''
    both = ', '.join(f'{k} = {v:.4g} (recorded pose: {c.params[k]:.4g})'
                     for k, v in moved.items())
    return (f' Its fitted value depends on the pose: with the pose corrected, {both}. '
            'The pose error and the effect share part of the residual, so the value is '
            'known only between the two; --effect pose_error --fit fits it on the '
            'corrected pose.')


def region_words(region) -> str:
    """A reference pose weighed against one part of a material reading off the rest
    (``region_offset.judge``), where the pose is not reported."""
    where = (f'the {region.material} faces beyond a plane of the body frame (normal '
             f'{region.axis}, at {region.threshold_m:+.2f} m; {region.points[1]} points '
             f'beyond it, {region.points[0]} before) read {100 * region.step_m:+.1f} cm '
             f'from those before it')
    split = (f'two offsets for {region.material}, one each side, gain {region.gain:.4f} '
             f'nats/point held out (z = {region.z:.1f})')
    kind = ('one rigid correction of the reference pose for the recording'
            if region.pose_constant else 'a rigid correction of the reference pose per cloud')
    pose = (f'{kind} gains {region.pose_gain_beyond:.4f} nats/point beyond them '
            f'(z = {region.pose_z_beyond:.1f})')
    if region.outcome == 'region':
        return (f'Part of the target reads off the rest of its material: {where}; '
                f'{split}, and {region.gain_beyond_pose:.4f} (z = {region.z_beyond_pose:.1f}) '
                f'on what the pose\'s correction leaves, while {pose}. So no reference-pose '
                'error is reported: this is outside the catalogue, a material the configuration '
                'does not list (or a part off its CAD) on one part of those faces; give '
                'them their own material in the mesh and materials.yaml.')
    return (f'A rigid correction of the reference pose and one part of the target reading '
            f'off the rest of its material explain the residual alike: {where}; {split}, '
            f'{region.gain_beyond_pose:.4f} (z = {region.z_beyond_pose:.1f}) on what the '
            f'pose\'s correction leaves, and {pose}. Neither adds to the other, so this '
            'recording cannot tell a reference-pose error from a part of the target '
            'reading off (a material the configuration does not list, or a part off its '
            'CAD); the pose is not asserted. A surveyed pose, or the target seen from '
            'another side, would tell them apart.')


def range_offset_beside_words(pose, named: list[str]) -> str:
    """The verdict's sentence when, beside the named effects ``named``, the clouds move
    as a range offset of the sensor changing between clouds would (``beside_tie``:
    ``Diagnosis.range_offset_beside``): a per-cloud pose correction that gains nothing
    beyond one range offset per cloud."""
    return (f'Besides, the clouds\' ranges move from cloud to cloud: with {_join(named)} in '
            f'the model, one range offset per cloud gains {pose.offset_gain:.4f} nats/point '
            f'held out (z = {pose.offset_z:.1f}), and a rigid correction of the target pose '
            f'per cloud gains no more beyond those offsets ({pose.beyond_offset_gain:.4f} '
            f'nats/point, z = {pose.beyond_offset_z:.1f}): a range offset of the sensor or '
            'the reference pose along the line of sight, changing between clouds (a '
            'temperature step of the sensor, or the tracking system), which this recording '
            'cannot tell apart; none is named. A static target on a surveyed pose, or one '
            'seen across a wide angle, separates them.')


def pose_beside_tie_words(pose, named: list[str], others: list) -> str:
    """The verdict's sentence when, beside the named effects ``named``, the reference
    pose and another explanation ``others`` (candidates: a clock offset, say) each leave
    the other nothing (``beside_tie``: ``beside.weigh_beside``): neither passes the rule
    on top of the named effects and the other."""
    kind = _correction(pose)
    pose_part = (f'{kind[0].lower()}{kind[1:]} gains {pose.gain:.4f} nats/point held out '
                 f'(z = {pose.z:.1f})')
    parts = []
    for c in others:
        b = (c.against_pose or {}).get('beside') or {}
        bp = (c.against_pose or {}).get('beside_pose') or {}
        value = (f', dt = {b["dt_s"]:+.3f} s' if b.get('dt_s') is not None else '')
        on_top = (f'{c.name} gains {b["gain"]:.4f} nats/point held out on top of '
                  f'{b["on_top_of"]} (z = {b["z"]:.1f}{value})' if b.get('gain') is not None
                  else f'{c.name} explains it too')
        if bp:
            on_top += (f'; the pose gains {bp["pose_gain_on_top"]:.4f} (z = '
                       f'{bp["pose_z_on_top"]:.1f}) on top of both, {c.name} does not pass '
                       'on top of the corrected pose')
        parts.append(on_top)
    names = [c.name for c in others]
    if names == [beside.CLOCK]:
        what = ('a clock offset between the pose and LiDAR stamps or the reference pose: '
                'on a target turning at a constant rate a clock offset moves it as one '
                'rigid correction does. A recording in which the target turns at another '
                'rate separates them (a clock offset follows the motion, a pose error does '
                'not)')
    else:
        what = (f'the reference pose or {_join(names)}, which this recording cannot tell '
                'apart')
    return (f'Besides, with {_join(named)} in the model, {pose_part}, and '
            f'{"; ".join(parts)}: {what}; none is named. If the tracking system is known to '
            f'be right, add --effect {names[0]} --fit; if the sensor is, --effect '
            'pose_error --fit.')


def _on_top_words(cands: list, name: str, named: str) -> str:
    """' (held out on top of NAMED it gains ...)' for an 'also' judged on its gain on top
    of the named effect (``diagnosis.passed_on_top_of``), else ''."""
    c = next((c for c in cands if c.name == name), None)
    if c is None or not diagnosis.passed_on_top_of(c, named):
        return ''
    b = c.against_pose['beside']
    value = f', dt = {b["dt_s"]:+.3f} s' if b.get('dt_s') is not None else ''
    return (f' (held out on top of {named} it gains {b["gain"]:.4f} nats/point, z = '
            f'{b["z"]:.1f}{value}; alone, beside the larger residual of {named}, '
            f'{c.score:.4f}, z = {c.z:.1f})')


def rolling_rows_words(rows: dict, pose_part: str, held: str, clock) -> str:
    """The verdict when the pose took a clock offset but the residual grows with the row
    (``time_offset``'s ``against_pose['row_time']``, ``row_clock.RowTime``): a time
    within the exposure the points do not carry, outside the catalogue; the clock and
    the pose stand in for its mean."""
    dt = clock.params.get('dt_s') if clock is not None else None
    mean = f' (dt = {dt:+.3f} s, the rows\' mean delay)' if dt is not None else ''
    figures = (f'the clock offset growing linearly over the rows gains '
               f'{rows["rate_gain_over_clock"]:.4f} nats/point held out on top of the clock '
               f'(z = {rows["z"]:.1f}; {rows["beyond_range_over_row_gain"]:.4f}, z = '
               f'{rows["beyond_range_over_row_z"]:.1f}, beyond a range offset growing with '
               'the row too), and on top of it one rigid correction of the pose no longer '
               f'passes ({rows["pose_gain_on_top"]:.4f}, z = {rows["pose_z_on_top"]:.1f})')
    over = (f'{rows["over_clock_and_pose_gain"]:.4f}, z = '
            f'{rows["over_clock_and_pose_z"]:.1f}')
    if rows.get('passes_over_clock_and_pose'):
        cause = (f'; on top of the clock and the pose the rows\' growth still gains {over}. '
                 'The rows were exposed at different times while the target moved (a rolling '
                 'shutter recorded as a global exposure, or a row delay the point times leave '
                 'out): outside the catalogue')
    else:
        cause = (f' (on top of the clock and the pose the rows\' growth gains {over}: a '
                 'turn of the pose about the line of sight shears the rows alike). Either '
                 'the rows were exposed at different times while the target moved (a rolling '
                 'shutter recorded as a global exposure, or a row delay the point times leave '
                 'out: outside the catalogue), or the pose is off by that turn beside the '
                 'clock; this recording cannot tell which')
    return (f'A time within the exposure that the points do not carry: {pose_part}, and a '
            f'clock offset explains the residual as well{held}, but what the pose gains '
            f'beyond the clock grows with the row: {figures}{cause}. The clock offset{mean} '
            'and the pose correction each stand in for the rows\' mean delay; none is '
            'named. Points stamped with their row\'s time, or the target turning at another '
            'rate, would show it; if the tracking system is known to be right, --effect '
            'time_offset --fit models the mean delay.')


def clock_off_footing_words(on: dict, held: str, plan: bool = False) -> str:
    """The tie of a clock offset with a pose drifting within the cloud, the clock not
    shown on the rays the pose is tested on (``clock_footing.ClockFooting.as_dict``)."""
    if on.get('clock_passes') and on.get('drift_passes'):
        there = (f'the clock growing over each scan gains {on["drift_gain"]:.4f} nats/point '
                 f'on top of it there (z = {on["drift_z"]:.1f}): the pose is read later and '
                 'later within each scan (a tracking lag that grows over the scan), which no '
                 'constant clock offset makes, and the clock offset stands for its mean')
    elif on.get('clock_passes'):
        there = (f'the per-cloud pose gains {on["pose_over_clock_gain"]:.4f} nats/point on '
                 f'top of it there (z = {on["pose_over_clock_z"]:.1f})')
    else:
        there = ('it does not pass the rule there, and a rigid correction per cloud'
                 + (' with its drift over the cloud' if on.get('rate') else '')
                 + f' gains {on["pose_gain"]:.4f} (z = {on["pose_z"]:.1f})')
    return ('A clock offset between the pose and LiDAR stamps, or the reference pose '
            f'drifting within each cloud: a clock offset explains the residual{held}, but on '
            f'the rays the reference pose is tested on ({on["rays"]} not grazing, within '
            f'five sigma) it gains {on["clock_gain"]:.4f} nats/point held out (z = '
            f'{on["clock_z"]:.1f}) and {there}. On a rigid target the two move every point '
            'by its velocity times a time, so which of them it is cannot be told from this '
            'recording; none is named. A recording in which the target turns at another '
            'rate (a clock offset moves it by its motion over the offset; a tracking '
            'system\'s drift need not follow the motion), or a static target on a surveyed '
            'pose (no tracking system), would separate them' + (' (plan.yaml)' if plan else '')
            + '; if the tracking system is known '
            'to be right, try --effect time_offset --fit, else --effect pose_error --fit.')


def pose_tie_words(decision, summary: dict, cands: list) -> str:
    """The verdict when the reference pose and a candidate explain the data equally
    (``confounded_with`` holds ``pose_error`` and the candidate)."""
    pose = decision.pose
    other = [n for n in decision.confounded_with if n != diagnosis.POSE_ERROR]
    c = next((c for c in cands if c.name in other), None)
    held = (f' ({c.name}: held-out gain {c.score:.4f} nats/point, z = {c.z:.1f}, before the '
            'pose correction)' if c is not None else '')
    pose_part = (f'{_correction(pose)[0].lower()}{_correction(pose)[1:]} gains {pose.gain:.4f} '
                 f'nats/point held out (z = {pose.z:.1f}; {pose.words()})'
                 if pose is not None else 'a rigid correction of the target pose per cloud')
    footings = (c.against_pose or {}) if c is not None else {}
    how = _corrected_how(getattr(pose, 'constant', False) is True)
    charged = footings.get('fitted_margin_charged')
    if charged is None:
        charged = footings.get('fitted_margin')
    rows = footings.get('row_time') or {}
    if other == ['time_offset'] and rows.get('significant'):
        return rolling_rows_words(rows, pose_part, held, c)
    if other == ['time_offset'] and pose is None and footings.get('pose_footing'):
        return clock_off_footing_words(
            footings['pose_footing'], f' ({c.name}: held-out gain {c.score:.4f} nats/point, '
            f'z = {c.z:.1f}, on every matched point)', bool(summary.get('separation_plan')))
    # The points carry times of their own (a time field), not the stamp's nor the pattern's.
    timed = summary.get('point_times') not in ('stamp', 'scan pattern')
    if other == ['time_offset'] and timed and footings.get('fitted_margin') is not None:
        return (f'{_clock_or_pose(pose_part, held)} Held '
                f'out the clock offset fits better by {footings["heldout_margin"]:.4f} '
                f'nats/point; with the pose corrected {how} and the model raycast again, '
                f'as --fit leaves them, the pose fits better by '
                f'{-footings["fitted_margin"]:.4f} ('
                f'{-charged:.4f} '
                'with each parameter charged one nat). The two footings disagree, so which of '
                'the two it is cannot be told from this recording; none is named. A '
                'recording in which the target turns at another rate (a clock offset moves '
                'the target by its motion over the offset, a pose error does not follow the '
                f'motion) would separate them{_motion_plan(summary)}; {_CLOCK_OR_POSE_FIT}')
    if other == ['time_offset'] and timed:
        return clock_pose_timed_words(pose_part, held, footings, summary)
    if other == ['time_offset']:
        return (f'{_clock_or_pose(pose_part, held)} The '
                'clouds carry no per-point time and their directions do not follow the '
                'configured scan pattern, so which of the two it is cannot be told from this '
                'recording; none is named. Points with their own times (a time field) would '
                f'separate them; {_CLOCK_OR_POSE_FIT}')
    if other == [diagnosis.RANGE_OF_RANGE]:
        return range_tie_words(pose, summary)
    if sorted(other) == sorted(power_incidence.PAIR):
        return pair_pose_tie_words(summary)
    if any(n in diagnosis.POSE_RIVALS for n in other):
        where = separating_recording(summary)
        steps = getattr(decision, 'beside_pose', None)
        if steps is not None:
            held += (f'; one range offset per cloud gains {steps.offset_gain:.4f} nats/point '
                     f'held out (z = {steps.offset_z:.1f}), and the pose correction gains '
                     f'no more beyond those offsets ({steps.beyond_offset_gain:.4f}, z = '
                     f'{steps.beyond_offset_z:.1f}): the clouds move only as the sensor\'s '
                     'range offset, changing between clouds, would move them')
        return (f'A range offset of the sensor or the reference pose along the line of '
                f'sight: {pose_part}, and {_join(other)} (a range error of the sensor) '
                f'explains the residual as well{held}; each leaves the other nothing, so which '
                'of them it is cannot be told from this recording, and none is named.'
                f'{where} If the tracking system is known to be right, add --effect '
                f'{other[0]} --fit; if the sensor is, --effect pose_error --fit.')
    where = ''
    if other == ['laser_pointing']:
        where = (f' The target tumbling faster ({MOTION_RIVALS["laser_pointing"][1]}) or '
                 f'held still on a surveyed pose would separate them{_motion_plan(summary)}.')
    return (f'{pose_part[0].upper()}{pose_part[1:]}, and {_join(other)} explains the '
            f'residual as well{held}: they are confounded in this recording, so none is '
            f'named.{where} Add the one you know with --effect NAME --fit (pose_error '
            'corrects the reference pose).')


_CLOCK_OR_POSE_FIT = ('if the tracking system is known to be right, try --effect time_offset '
                      '--fit, else --effect pose_error --fit.')


def _clock_or_pose(pose_part: str, held: str) -> str:
    """The opening of a clock offset's tie with the reference pose: the pose's figures
    (``pose_part``) and the clock's (``held``)."""
    return (f'A clock offset between the pose and LiDAR stamps, or the reference pose: '
            f'{pose_part}, and a clock offset explains the residual as well{held}.')


def clock_pose_timed_words(pose_part: str, held: str, footings: dict, summary: dict) -> str:
    """The tie of a clock offset with the reference pose on points that carry times of
    their own (a time field; not the stamp's nor the scan pattern's): each leaves the other
    nothing (the nested test on the raycast footing where it ran, ``footings``: the clock
    candidate's ``against_pose``), so the target's motion over the recording does not set
    a clock offset (a move by the motion over the offset) apart from a fixed pose error
    (the nineteenth holdout's timeoff: said before as 'no per-point time')."""
    nested = ((footings.get('constant_pose_footing') or {}).get('nested') or {})
    one, other = nested.get('clock_over_pose') or {}, nested.get('pose_over_clock') or {}
    figures = ''
    if one.get('gain_per_point') is not None and other.get('gain_per_point') is not None:
        figures = (f' (raycast again, the clock over the pose gains '
                   f'{one["gain_per_point"]:.4f} nats/point, z = {one["z"]:.1f}, the pose '
                   f'over the clock {other["gain_per_point"]:.4f}, z = {other["z"]:.1f})')
    return (f'{_clock_or_pose(pose_part, held)} With the '
            f'points\' own times each leaves the other nothing{figures}: over this recording '
            'the target turns too steadily for a clock offset (which moves the target by its '
            'motion over the offset) and a fixed pose error to differ, so which of the two it '
            'is cannot be told; none is named. A recording in which the target turns at '
            f'another rate would separate them{_motion_plan(summary)}; {_CLOCK_OR_POSE_FIT}')


def _motion_plan(summary: dict) -> str:
    """' (plan.yaml: ...)' where the tie of the pose with a clock or the lasers' pointing
    wrote its plan (``plan.pose_motion_plan``), else ''."""
    rows = summary.get('separation_plan') or []
    if not rows or rows[0].get('simulated') is not False:
        return ''
    return (f' (plan.yaml: {rows[0]["what"]}; the still target in its header)')


def _sunlight_named(summary: dict, c) -> str:
    """``sunlight`` named on the gain of ``c`` (``solar_background``) and the sun test
    (``compare/diagnose/sunlight.py``, ``sunlit_decision``)."""
    gain, caveat = _gain_words(summary, c)
    return (f'This is false returns from sunlight. Adding background false returns at random ranges '
            f'({c.name} with its fitted probability) {gain} (held-out gain {c.score:.4f} '
            f'nats/point, z = {c.z:.1f}), and the recording\'s sun direction shows that they '
            f'follow the sun (below).{caveat} Run again with --effect sunlight --fit: it '
            'models them from the sun, where solar_background would spread them evenly.')


def sunlight_words(sun: dict, hint: bool = True) -> str:
    """What the false returns say about sunlight, for a recording with the sun direction
    (summary.json's ``sunlight``, ``compare/diagnose/sunlight.py``); ``hint``: say which run models
    them (not when the verdict already named sunlight)."""
    counts = (f'{sun["sunlit_false_returns"]} of {sun["sunlit_points"]} sunlit rays against '
              f'{sun["shadowed_false_returns"]} of {sun["shadowed_points"]} shadowed ones, '
              f'p = {sun["excess_p_value"]:.2g}')
    lo, hi = sun['background_scale_interval_95']
    scale = (f'background_scale = {sun["background_scale"]:.3g} +- '
             f'{sun["background_scale_sigma"]:.2g} (95 % interval {lo:.3g}-{hi:.3g})')
    if not sun['supported']:
        return (f'The recording carries the sun direction, but its false returns are not '
                f'clearly more frequent on sunlit surfaces than on shadowed ones ({counts}): '
                f'the data do not show sunlight-driven false returns ({scale}).')
    where = (f'{sun["rate_ratio"]:.0f} times as often on sunlit surfaces as on shadowed ones'
             if sun['rate_ratio'] is not None else 'on sunlit surfaces only')
    text = (f'The recording carries the sun direction: false returns come {where} '
            f'({counts}), as sunlight makes them. The receiver factor fitted from them is '
            f'{scale}.')
    in_model = sun.get('model_background_scale')
    if in_model is None and hint:
        text += (' With the sun recorded, run again with --effect sunlight --fit, which models '
                 'them from the sun, rather than with the phenomenological solar_background.')
    elif in_model is not None and not lo <= in_model <= hi:
        text += (f' The model\'s sunlight effect has background_scale = {in_model:.3g}, outside '
                 'that interval: --effect sunlight --fit adopts the fitted value.')
    return text


def _nothing_named(summary: dict, attribution, cands: list) -> str:
    """Why no effect is named: nothing to explain, or nothing in the catalogue explains it."""
    best = next((c for c in diagnosis.rank(cands) if c.error is None and c.significant), None)
    why = ''
    fault = (diagnosis.naming_fault(best, summary['nll_calibrated'],
                                    summary.get('range_rmse_calibrated_m', float('nan')))
             if best is not None else None)
    along = (best.against_pose or {}) if best is not None else {}
    rival, name = same_part_rival(summary)
    # Withheld beside a rival the rule keeps from naming (``Diagnosis.rival_takes``),
    # whatever ranks first.
    held = (summary.get('withheld') or {}).get(name) if name else None
    c = next((c for c in cands if c.name == name), None)
    if held and c is not None:
        return same_part_words(c, held, rival, summary)
    kept = (summary.get('withheld') or {}).get(best.name) if best is not None else None
    if best is not None and best.vetoed:
        why = f' The best candidate, {best.name}, is set aside: {best.vetoed}.'
    elif kept:
        # Withheld by the diagnosis (``Decision.withheld``): it explains the residual by
        # the rule's gain, so what keeps it is said, not "noise".
        return (f'No catalogue effect is named. The best candidate, {best.name}, is not '
                f'named: {kept}.' + _between_words(summary, best, fault))
    elif along.get('pose_line_of_sight') and not along.get('passes_on_pose'):
        return line_of_sight_words(best)
    elif best is not None and best.practical and fault:
        why = (f' The best candidate, {best.name}, is not named: {fault}.'
               + _between_words(summary, best, fault))
    elif best is not None and not best.practical:
        why = (f' The best candidate, {best.name}, gains {best.score:.4f} nats/point held out '
               f'(z = {best.z:.1f}), less than the {diagnosis.MIN_PRACTICAL_GAIN:g} nats/point '
               'that would matter (an RMS change of the expected range of 10 % of the noise).')
    louder = _louder_but_noisy(cands, best)
    if louder is not None:
        # The one ranked first on its gain fails the z: "the best candidate" above is the
        # best of those that pass it, so the one that gains more is said too.
        noisy = (f'(z = {louder.z:.1f}, below the rule\'s bound for the candidates tried): '
                 'a gain that size is within what noise gives here.')
        if why:
            why = why.replace(' The best candidate,', ' The best candidate that passes the '
                              'z test,', 1)
            why += (f' {louder.name} gains more ({louder.score:.4f} nats/point held out) but '
                    f'not significantly {noisy}')
        else:
            why = (f' The best candidate, {louder.name}, gains {louder.score:.4f} nats/point '
                   f'held out but not significantly {noisy}')
    if attribution is not None and attribution.significant:
        return ('No catalogue effect explains it by a margin that matters.' + why
                + range_outside.words(summary)
                + ' The missing physics is outside the catalogue: write an effect '
                '(docs/effects.md, "Write your own effect") that depends on what the residual '
                'depends on, and add it with --effect file.py:Class --fit.')
    left_out = [what for what, key in (('occluded returns', 'occlusion'),
                                       ('crosstalk ghosts', 'crosstalk'),
                                       ('later returns of a shot', 'multiple_returns'))
                if (summary.get(key) or {}).get('points')]
    beside = f' once the {" and ".join(left_out)} below are left out' if left_out else ''
    return ('No catalogue effect improves the held-out likelihood by a margin that matters: '
            f'the model matches the measurements up to noise{beside}.' + why)


def _between_words(summary: dict, best, fault: str | None) -> str:
    """Where what keeps ``best`` from being named (``fault``: its ``naming_fault``) is
    that it lowers the NLL and raises the range RMSE (``diagnosis.rmse_fault``) and the
    points off the model lie between the target's edge and a surface behind it
    (``mixed_edges.shown``): that sentence, else ''."""
    figures = summary.get('mixed_edges')
    why = diagnosis.rmse_fault(best, summary.get('range_rmse_calibrated_m', float('nan')))
    if not mixed_edges.shown(figures) or why is None or fault != why:
        return ''
    return mixed_edges.words(figures)


def _louder_but_noisy(cands: list, best):
    """The candidate ranked first on its held-out gain when it does not pass the z test
    and gains more than ``best`` (the best that passes it, or None), else None."""
    top = next((c for c in diagnosis.rank(cands) if c.error is None), None)
    if top is None or top is best or top.significant or not top.practical:
        return None
    if best is not None and top.score <= best.score:
        return None
    return top


def same_part_rival(summary: dict) -> tuple[str | None, str | None]:
    """(rival, withheld): the rival a candidate was withheld beside and that candidate
    (``Diagnosis.rival_takes``: ``against_named[RIVAL]['same_part']``, its outcome not
    'named', ``of`` the candidate weighed), or (None, None)."""
    for name, w in (summary.get('against_named') or {}).items():
        part = w.get('same_part') if isinstance(w, dict) else None
        if part and part.get('outcome') != 'named':
            return name, part.get('of')
    return None, None


def same_part_words(best, held: str, rival: str, summary: dict) -> str:
    """Nothing named because ``best`` and ``rival`` explain the same part of the residual
    and ``best`` does not pass the rule on top of ``rival`` (``held``: why, in figures)."""
    return (f'{best.name} gains {best.score:.4f} nats/point held out (z = {best.z:.1f}) and '
            f'is not named: {held}. {_separation([best.name, rival], summary)} If you know '
            'which it is, add it with --effect NAME --fit.')


def line_of_sight_words(best) -> str:
    """The verdict when what the candidates gained is what one rigid correction of the
    reference pose along the line of sight leaves (``Diagnosis.weigh_line_of_sight``):
    nothing named, and the pose not reported (its own test does not pass)."""
    ap = best.against_pose
    size = ap.get('pose_translation_cm')
    return (f'No sensor effect is named. The best candidate, {best.name}, gains '
            f'{best.score:.4f} nats/point held out (z = {best.z:.1f}), but with one rigid '
            'correction of the target pose for the whole recording'
            + (f' ({size:.1f} cm, along the line of sight)' if size is not None else '')
            + f' it gains {ap["score_on_pose"]:.4f} (z = {ap["z_on_pose"]:.1f}): what it took '
            'is what a target recorded nearer or farther leaves near its limbs, where ranges '
            'change as 1 / cos(incidence). The correction\'s own held-out test does not tell '
            'it from a range offset of the sensor, so it is not reported either.')


def _separation(names: list[str], summary: dict) -> str:
    """Which recording would tell the confounded candidates apart."""
    known = [n for n in names if n in DRIVEN_BY]
    if len(known) < 2:
        return ('A recording in which what drives each of them varies independently would '
                'separate them.')
    a, b = known[:2]
    span = summary.get('range_span_m')
    narrow = (f' (this one spans only {span[0]:.1f}-{span[1]:.1f} m)' if span
              and span[1] - span[0] < 0.35 * span[1] else '')
    return (f'{a} follows the {DRIVEN_BY[a][0]}, {b} the {DRIVEN_BY[b][0]}; here the two vary '
            f'together{narrow}. A recording at {DRIVEN_BY[a][1]}, or at {DRIVEN_BY[b][1]}, '
            'would separate them.')


def plan_words(rows: list[dict], by_form_only: bool = False) -> str:
    """One sentence on the separation plan (``compare/diagnose/plan.py``): the best recording and
    its expected z, from simulating both fitted hypotheses on each candidate recording.
    ``by_form_only``: the tie is one of parts of their own (``power_incidence``), so
    this very recording flown again separates the two only by their forms as fitted,
    which is not what is in doubt: the best other recording is said."""
    if by_form_only:
        again = next((r for r in rows if r['recording'] == 'this recording'), None)
        others = [r for r in rows if r['recording'] != 'this recording']
        if others:
            head = ''
            if again is not None and again['separates'] and again['z'] is not None:
                head = (f'Simulating both as fitted on this very recording separates them '
                        f'({again["margin"]:.4f} nats/point, z = {again["z"]:.1f}) only by '
                        'the forms fitted, not by a part of their own. ')
            return head + plan_words(others)
    best = rows[0]
    ways = best['ways']
    n = min(w['diagnosed_points'] for w in ways.values() if 'skipped' not in w)
    tried = f'{len(rows)} recordings tried'
    if best['z'] is None:
        return f'Simulating both as fitted on {tried} gave no usable estimate.'
    if best['separates'] and best['recording'] == 'this recording':
        return (f'Yet simulating both as fitted on this very recording separates them '
                f'({best["margin"]:.4f} nats/point, z = {best["z"]:.1f} with {n} points): the '
                'tie may come from the diagnosis rather than from the recording (plan.yaml '
                'flies it again).')
    if best['separates']:
        return (f'Simulating both as fitted on {tried}, the best to separate them is '
                f'{best["recording"]} ({best["what"]}): expected {best["margin"]:.4f} '
                f'nats/point between them, z = {best["z"]:.1f} with {n} points (plan.yaml).')
    return (f'Simulating both as fitted on {tried}, none separates them by the rule; the '
            f'best, {best["recording"]}, gives {best["margin"]:.4f} nats/point, z = '
            f'{best["z"]:.1f} with {n} points (plan.yaml): a recording '
            'other than these would be needed.')


def bound_words(names: list[str] | None) -> str:
    """' (NAME at its search bound: ...)' for parameters a fit left at the edge of its
    search box (``fit.at_bounds``), '' for none."""
    if not names:
        return ''
    which = _join(list(names))
    return (f' ({which} at {"its" if len(names) == 1 else "their"} search bound: the data '
            'ask for at least this much, so the value bounds the size and does not measure '
            'it; an effect outside the catalogue, or this one larger than the catalogue '
            'allows)')


def range_alone_words(alone: dict) -> str:
    """The verdict's sentence when the named range term stands in for a bias of range
    alone (``range_alone.RangeAlone.as_dict``)."""
    name, offset = alone['named'], alone.get('common_offset_left_m')
    if offset is not None:
        return (f'{name} stands in here for a range error outside the catalogue: fitted, it '
                f'leaves every material\'s range {"long" if offset > 0 else "short"} by '
                f'about {100 * abs(offset):.1f} cm alike, while a range scale is zero at zero '
                'range: the residual asks for a range bias that is not a scale, whose local '
                f'slope {name} takes (or a scale and a range offset of the sensor together), '
                f'so {name} is not its cause.')
    return (f'{name} stands in here for a range error outside the catalogue: '
            'the residual it explains follows range alone, not '
            f'{alone["range_alone_against"]} (a function of range explains it better held '
            f'out by {alone["gain_per_matched_point"]:.4f} nats/point, '
            f'z = {alone["z"]:.1f}), so {name} is not its cause.')


def pose_size_words(pose: dict) -> str:
    """A per-cloud pose correction's size as summary.json holds it (``reference_pose``,
    ``pose_correction``, a rate's drift): each part only where the data show it
    (``pose_error.part_words``)."""
    parts = pose.get('parts') or {}
    return pose_error.part_words(parts.get('reported', 'both'), parts,
                                 pose['translation_rms_cm'], pose['rotation_rms_deg'])


def bound_remainder_words(left: dict) -> str:
    """Why a pose that would take what a fit at its search bound left is not claimed
    (``run.pose_beyond_a_bound``; ``left``: the pose's ``left_by_bound``)."""
    effects = left['effects']
    which = _join([f'{n}\'s {_join(list(p))}' for n, p in effects.items()])
    names = _join(list(effects))
    return (f'The fit ended at its search bound ({which}): what it leaves is the rest of '
            f'{names} beyond the box, or of an effect outside the catalogue that {names} '
            'stands in for, as much as a reference pose error. A per-cloud pose correction '
            f'would take it ({left["translation_rms_cm"]:.2f} cm and '
            f'{left["rotation_rms_deg"]:.3f} deg RMS, held-out gain '
            f'{left["test_gain_per_matched_point"]:.4f} nats/point, z = {left["test_z"]:.1f}), '
            'but the data do not tell the two apart: no pose error is claimed.')


def stand_in_remainder_words(left: dict) -> str:
    """Why a pose beside a stand-in for a bias of range alone is not claimed
    (``run.pose_beside_a_stand_in``; ``left``: the pose's ``left_by_stand_in``)."""
    name = left['named']
    return (f'What {name} leaves is the rest of the bias of range alone it stands in for, '
            'a range offset that changes as the range does, as much as a reference pose '
            'error. A per-cloud pose correction would take it '
            f'({left["translation_rms_cm"]:.2f} cm and {left["rotation_rms_deg"]:.3f} deg RMS, '
            f'held-out gain {left["test_gain_per_matched_point"]:.4f} nats/point, '
            f'z = {left["test_z"]:.1f}), but the data do not tell the two apart: no pose '
            'error is claimed.')


def across_faces_left(summary: dict, decision) -> bool:
    """Whether the pose test passed but its correction did not hold across the surfaces'
    orientations (``pose_error.faces_agree``), nothing named and no pose reported."""
    faces = (summary.get('reference_pose') or {}).get('across_faces')
    return bool(faces and not faces.get('transfers') and decision.pose is None
                and not decision.missing and not decision.confounded_with)


def across_faces_words(pose: dict) -> str:
    """Why a pose correction that does not hold across the surfaces' orientations is
    not claimed (``pose``: the summary's ``reference_pose`` with ``across_faces``)."""
    faces = pose['across_faces']
    kinds = [faces[k] for k in ('clusters', 'halves') if k in faces]
    lost = [g for f in kinds for k, g in enumerate(f['groups']) if k in f['losing_groups']]
    worst = min(lost or [g for f in kinds for g in f['groups']],
                key=lambda g: g['gain_per_group_point'])
    split = next(f for f in kinds if worst in f['groups'])
    normal = ', '.join(f'{v:.2f}' for v in worst['normal'])
    kind = ('One rigid correction of the pose for the recording' if pose.get('constant')
            else 'A per-cloud pose correction')
    # One correction is fitted on the other groups and held out on each; a per-cloud
    # one is scored on each group's share of its random held-out halves
    # (``pose_error.per_cloud_faces``).
    how = ('fitted on the surfaces facing some ways it does not hold on the others: held '
           'out on' if pose.get('constant') else
           'it does not hold on the surfaces facing every way: held out (random halves) on')
    return (f'A range error outside the catalogue that depends on which way a surface '
            f'faces: {kind[0].lower()}{kind[1:]} would take part of the residual '
            f'({pose["translation_rms_cm"]:.2f} cm and {pose["rotation_rms_deg"]:.3f} deg RMS, '
            f'held-out gain {pose["gain_per_matched_point"]:.4f} nats/point on random '
            f'halves, z = {pose["z"]:.1f}), but {how} the surfaces whose normal (sensor '
            f'frame) is near ({normal}), {100 * worst["share"]:.0f} % of the points, it '
            f'loses {-worst["gain_per_group_point"]:.4f} nats per point there '
            f'(z = {worst["z"]:.1f}); over the {len(split["groups"])} groups of that split '
            f'it gains {split["total_gain_per_matched_point"]:.4f} nats/point '
            f'(z = {split["total_z"]:.1f}). A reference pose that is off is one rigid motion '
            'every surface agrees on; this is not, so no pose error is claimed. The ranges '
            'of surfaces facing some ways read off (a sunlit, warmer face; a coating): an '
            'effect of your own that depends on the surface normal (docs/effects.md, "Write '
            'your own effect") would fit it.')


def silhouette_words(pose: dict) -> str:
    """Why a pose correction whose silhouette test the target's outline contradicts is
    not claimed (``pose``: the summary's ``reference_pose`` with
    ``left_to_edges``, ``run.pose_on_silhouette``)."""
    left = pose['left_to_edges']
    kind = ('one rigid correction of the pose for the recording' if pose.get('constant')
            else 'a per-cloud pose correction')
    took = (f'{kind} would take it ({left["translation_rms_cm"]:.2f} cm and '
            f'{left["rotation_rms_deg"]:.3f} deg RMS, held-out gain '
            f'{left["test_gain_per_matched_point"]:.4f} nats/point, z = {left["test_z"]:.1f})')
    edges = (f'with it applied, of the {left["edge_rays"]} returns whose outcome it changes '
             f'at the silhouette and depth steps {left["lost"]} fall off the model, '
             f'{left["put_back"]} come onto it and {left["jumped"]} cross a depth step: '
             f'{left["gain_per_edge_ray"]:+.2f} nats per ray (z = {left["z"]:.1f})')
    return (f'A range error outside the catalogue fixed to the body or to some of its '
            f'faces: {took}, but the target\'s outline contradicts it: {edges}. A '
            'reference pose that is off moves the silhouette across the rays; this '
            'correction moves it off returns that lay on it, so no pose error is claimed. '
            'A body built off its CAD (bent, a part moved) or faces reading off (sunlit, '
            'a coating) do this: an effect of your own on those faces (docs/effects.md, '
            '"Write your own effect") or the as-built mesh would fit it.')


def range_of_range_words(left: dict) -> str:
    """Why a per-cloud pose that a function of range alone explains as well is not
    claimed (``run.pose_against_range_alone``; ``left``: the pose's ``left_to_range``)."""
    kind = ('One rigid correction of the pose for the recording' if left.get('constant')
            else 'A per-cloud pose correction')
    pose = (f'{kind} would take it ({left["translation_rms_cm"]:.2f} cm '
            f'and {left["rotation_rms_deg"]:.3f} deg RMS, held-out gain '
            f'{left["test_gain_per_matched_point"]:.4f} nats/point, z = {left["test_z"]:.1f}), '
            f'but a smooth function of range alone ({left["knots"]} knots), '
            f'on the same held-out points, gains {left["gain_per_matched_point"]:.4f} '
            f'nats/point (z = {left["z"]:.1f}), and the pose fitted on top of it ')
    beyond = (f'{left["pose_gain_beyond"]:.4f} nats/point more '
              f'(z = {left["pose_z_beyond"]:.1f})')
    if left['outcome'] == 'range':
        return (f'A range error of the sensor outside the catalogue that follows range: '
                f'the residual changes with range as no catalogue term does. {pose}'
                f'{beyond}, no more: the ranges move as such a range error moves them; no '
                'pose error is claimed. An effect of your own that '
                'follows range (docs/effects.md, "Write your own effect") would fit it; a '
                'static target on a surveyed pose at several distances would show its shape.')
    return (f'What is left may be a range error of the sensor that follows range as much '
            f'as a reference pose error. {pose}{beyond}: the data do not tell the two apart, '
            'so no pose error is claimed.')


def pair_pose_tie_words(summary: dict) -> str:
    """The tie of the target moved along the line of sight with a range walk and an
    incidence bias fitted together (``Diagnosis.pair_against_moved_target``)."""
    los = summary.get('pose_along_line_of_sight') or {}
    f = los.get('pair') or {}
    over = f.get('pair_over_pose') or [float('nan')] * 2
    top = f.get('pose_on_top') or {}
    walk, incidence = power_incidence.PAIR
    return (f'The reference pose along the line of sight, or a range walk and an incidence '
            f'bias together: the target moved {los.get("shift_cm", float("nan")):.1f} cm '
            f'along the line of sight and raycast again gains '
            f'{los.get("gain_per_point", float("nan")):.4f} nats/point (z = '
            f'{los.get("z", float("nan")):.1f}); {walk} and {incidence} fitted together on '
            f'the recorded pose fit the same points as well (the pair over the moved target '
            f'{over[0]:.4f} nats/point, z = {over[1]:.1f}), and the move gains '
            f'{top.get("gain", float("nan")):.4f} (z = {top.get("z", float("nan")):.1f}) on '
            'top of the pair. On a flat face an incidence bias c (1/cos(theta) - 1) moves the '
            'ranges as a target moved along the line of sight does, so which it is cannot be '
            f'told from this recording; none is named.{separating_recording(summary)} If the '
            f'tracking system is known to be right, add --effect {walk} --effect {incidence} '
            '--fit; if the sensor is, --effect pose_error --fit.')


def separating_recording(summary: dict) -> str:
    """The sentence naming the recording that separates a pose from a range term of the
    sensor: plan.yaml's two distances where the plan has them."""
    plan = summary.get('separation_plan') or []
    if len(plan) >= 2:
        return (f' A static target on a surveyed pose, at {plan[0]["distance_m"]:.1f} m (seen '
                f'across a wide angle) and at {plan[1]["distance_m"]:.1f} m, would separate '
                'them (plan.yaml).')
    return (' A static target on a surveyed pose, seen across a wide angle and at two '
            'distances, would separate them.')


def range_tie_words(pose, summary: dict) -> str:
    """The tie of a per-cloud pose with a range error of the sensor that follows range
    (``confounded_with`` [pose_error, RANGE_OF_RANGE], ``run.pose_against_range_alone``)."""
    a = pose.against_range
    where = separating_recording(summary)
    return (f'A range offset of the sensor or the reference pose along the line of sight: '
            f'{_correction(pose)[0].lower()}{_correction(pose)[1:]} gains {pose.gain:.4f} '
            f'nats/point held out (z = {pose.z:.1f}; {pose.words()}), and a function of '
            f'range alone ({a.knots} knots), a range error of the '
            f'sensor outside the catalogue that follows range, gains {a.range_gain:.4f} '
            f'(z = {a.range_z:.1f}) on the same held-out points; fitted on top of it the '
            f'pose gains {a.pose_beyond_gain:.4f} nats/point more (z = '
            f'{a.pose_beyond_z:.1f}), short of the rule, so which of them it is cannot be '
            'told from this recording, '
            f'and none is named.{where} If the sensor is known to be right, --effect '
            'pose_error --fit; if the tracking system is, an effect of your own that follows '
            'range (docs/effects.md, "Write your own effect").')


_PER_LASER_ANGLE = re.compile(r'^laser_\d+_(az|el)_deg$')


def walk_scale_words(gain: dict | None, params: dict | None) -> str:
    """What the intensity's scale leaves open of a walk's k read through it: '' where k
    reads the model's power, the layout fixes the scale, or (log counts) the range within
    one material and incidence pins b (``recording/intensity.py``: read with it, or the
    model's fit confirmed). Otherwise which of these is missing."""
    gain, params = gain or {}, params or {}
    if (params.get('power', 'measured') != 'measured'
            or not gain.get('used_for_power_driven_effects')
            or gain.get('unit_slope')):
        return ''
    lever = gain.get('counts_per_efold') or {}
    if lever.get('used'):
        return ''
    if not lever.get('log_shape_from'):
        lever = {}          # not log counts: the range's b is not their scale
    if lever.get('pinned'):
        ratio = float(lever['fitted_on_model']) / float(lever['per_efold'])
        if abs(ratio - 1.0) <= max(0.02, 2.0 * float(lever['rel_se'])):
            return ''
        return (f' k is read through log counts whose b was fitted on the model\'s power '
                f'({lever["fitted_on_model"]:.3g} per e-fold); the range within one material '
                f'and incidence gives {lever["per_efold"]:.3g} +- {lever["se"]:.2g}, so k may '
                f'be off by their ratio ({100 * (ratio - 1):+.0f} %), short of the margin at '
                'which the range\'s b replaces the fit (what the range itself can miss by '
                'where the reference pose is off).')
    words = (' k is read through the intensity, whose scale was fitted on the model\'s '
             'power: where the model\'s reflectance law spans less received power than the '
             'true one, k is over-read by that ratio (more, under-read)')
    if lever:
        return words + (f'; the range within one material and incidence gives the log '
                        f'counts\' b {lever["per_efold"]:.3g} +- {lever["se"]:.2g} per e-fold '
                        f'(fitted on the model: {lever["fitted_on_model"]:.3g}), too loose '
                        f'to read (range sd {lever["range_sd_within_cells"]:.3g} in ln within '
                        'a cell); a recording over a wider span of distances pins it.')
    return words + (', which this recording does not check (not log counts, whose b the '
                    'range checks); a sensor whose intensity convention is known, or a '
                    'recording over a range of distances, does.')


def _summary_params(params: dict | None) -> tuple[dict, int]:
    """A candidate's parameters less its per-laser angles (``laser_pointing``'s two per
    laser, summary.json carries them), and how many lasers those were."""
    params = params or {}
    kept = {k: v for k, v in params.items() if not _PER_LASER_ANGLE.match(k)}
    return kept, (len(params) - len(kept)) // 2


def _params_words(params: dict | None) -> str:
    """A candidate's fitted parameters as the verdict quotes them: 'k = v, ...', floats
    to four significant figures; per-laser pointing angles by their RMS (and where the
    rest are)."""
    kept, lasers = _summary_params(params)
    words = ', '.join(f'{k} = {v:.4g}' if isinstance(v, float) else f'{k} = {v}'
                      for k, v in kept.items())
    if lasers:
        words += (f' (an azimuth and an elevation offset for each of {lasers} lasers: '
                  'summary.json)')
    return words


def _join(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ', '.join(names[:-1]) + ' and ' + names[-1]


def _change(what: str, before: float, after: float, unit: str, fmt: str, down: str,
            up: str = 'raises') -> str:
    """'cuts WHAT from a to b', 'raises WHAT from a to b' or 'leaves WHAT at a'."""
    a, b = f'{before:{fmt}}', f'{after:{fmt}}'
    if a == b:
        return f'leaves {what} at {a}{unit}'
    return f'{down if after < before else up} {what} from {a}{unit} to {b}{unit}'


def _gain_words(summary: dict, c) -> tuple[str, str]:
    """What adding candidate ``c`` brings, before and after on one basis (each
    material's offset and sigma scale refit, as --fit does), and any caveat sentence.
    An outlier effect is judged by the NLL and the robust (MAD) spread: a plain RMSE is
    dominated by the far outliers, which stay in the data whether or not the model
    expects them."""
    missed, back = diagnosis.footing_gains(c)
    nll = _change('the NLL', summary['nll_calibrated'], diagnosis.fitted_footing(c), '',
                  '.3f', 'lowers') + ' per point'
    if missed:
        # A false-return effect's footing (``diagnosis.naming_fault``): its evidence
        # sits mostly on the shots that missed the target.
        nll += (', counting the false returns among the shots that missed the target '
                f'({c.nll_after:.3f} on the matched points alone)')
    elif back:
        # A footprint's footing: the returns it puts back on the target count.
        nll += (', counting the returns it puts back on the target '
                f'({c.nll_after:.3f} on the matched points alone)')
    if c.effect is None or not diagnosis.is_outlier_effect(type(c.effect)):
        rmse = _change('the range RMSE', summary['range_rmse_calibrated_m'],
                       c.range_rmse_after_m, ' m', '.4f', 'cuts')
        return f'{rmse} and {nll}', ''
    text = nll
    before = summary.get('range_robust_sigma_calibrated_m', float('nan'))
    after = c.range_robust_sigma_after_m
    if np.isfinite(before) and np.isfinite(after):
        text += ' and ' + _change('the robust (MAD) spread of the range residual', before,
                                  after, ' m', '.4f', 'narrows', 'widens')
    caveat = (f' The plain range RMSE ({summary["range_rmse_calibrated_m"]:.4g} m) is '
              'dominated by the far outliers, which stay in the data: it does not measure '
              'this effect.')
    if c.unmatched_explained > 0.01:
        caveat += (f' It also explains {100 * c.unmatched_explained:.0f} % of the points '
                   'that miss the target.')
    return text, caveat


def summary_lines(s: dict, files: list[Path]) -> list[str]:
    analysed = s.get('points_analysed', s['points'])
    cut = (f', {analysed} analysed (--max-points): ' if analysed < s['points'] else ' (')
    lines = [f'points: {s["points"]}{cut}{s["matched_points"]} matched, '
             f'{s["unmatched_points"]} unmatched = {100 * s["unmatched_fraction"]:.2f} %'
             + ('' if analysed < s['points'] else ')'),
             f'range RMSE: {s["range_rmse_m"]:.4f} m   NLL: {s["nll_per_point"]:.3f} per point'
             f'   (per-material offsets refit: {s["range_rmse_calibrated_m"]:.4f} m, '
             f'{s["nll_calibrated"]:.3f})']
    rate = s.get('scan_pattern_rate_error')
    if rate is not None:
        lines.append(f'scan pattern: the pattern runs {100 * abs(rate):.2f} % '
                     f'{"fast" if rate > 0 else "slow"}: times from its curve (frequencies x '
                     f'{1 + rate:.5f}; summary.json: scan_pattern_rate_error)')
    occluded = (s.get('occlusion') or {}).get('points')
    if occluded:
        lines.append(f'occluded: {occluded} returns from something in front of the target '
                     'left out (summary.json: occlusion)')
    ghosts = s.get('crosstalk') or {}
    if ghosts.get('points'):
        lines.append(f'crosstalk: {ghosts["points"]} ghost returns {ghosts["offset_m"]:.2f} m '
                     'behind a return of the adjacent laser left out (summary.json: crosstalk)')
    later = s.get('multiple_returns') or {}
    if later.get('points'):
        lines.append(f'later returns: {later["points"]} later returns of the same shot (a '
                     'multi-return receiver) left out of the fit (summary.json: multiple_returns)')
    for e in s['fitted_effects']:
        params = ', '.join(f'{k} = {v:.6g}' if isinstance(v, float) else f'{k} = {v}'
                           for k, v in e['params'].items())
        lines.append(f'fitted {e["name"]}: {params}{bound_words(e.get("at_bound"))}')
    pc = s.get('pose_correction')
    if pc:
        rate = pc.get('rate') or {}
        drift = (', drifting within each cloud by '
                 + pose_size_words({'translation_rms_cm': rate['drift_per_cloud_rms_cm'],
                                    'rotation_rms_deg': rate['drift_per_cloud_rms_deg'],
                                    'parts': rate.get('parts')})
                 + ' RMS over the scan' if rate.get('supported') else '')
        lines.append(f'fitted pose_error: reference pose corrected per cloud by '
                     f'{pose_size_words(pc)} RMS '
                     f'over {len(pc["clouds"])} clouds{drift} (held-out gain '
                     f'{pc["gain_per_matched_point"]:.4f} nats/point, z = {pc["z"]:.1f})')
    lines.append('features: ' + ', '.join(f'{f["name"]} {f["score"]:.4f}'
                                          for f in s['features'][:4]))
    lines.append('candidates: ' + ', '.join(
        f'{c["name"]} {c["score"]:.4f}' if c['score'] is not None else f'{c["name"]} failed'
        for c in s['candidates']))
    sun = s.get('sunlight')
    if sun:
        lines.append(f'sunlight: background_scale {sun["background_scale"]:.4g} +- '
                     f'{sun["background_scale_sigma"]:.2g}; false returns on '
                     f'{sun["sunlit_false_returns"]}/{sun["sunlit_points"]} sunlit, '
                     f'{sun["shadowed_false_returns"]}/{sun["shadowed_points"]} shadowed rays '
                     f'({"sunlight-driven" if sun["supported"] else "not shown to follow the sun"})')
    lines.append(f'missing effect: {s["missing_effect"]}')
    rp = s.get('reference_pose')
    if s.get('reference_pose_off') and rp:
        lines.append(f'reference pose: off by {pose_size_words(rp)} RMS per cloud '
                     f'(z = {rp["z"]:.1f}): run again with --effect pose_error --fit')
    region = s.get('region_offset') or {}
    if region.get('outcome') in ('region', 'tie') and not s.get('reference_pose_off'):
        said = ('part of the target reads off the rest' if region['outcome'] == 'region'
                else 'the pose and part of the target reading off not told apart')
        lines.append(f'{said}: {region["material"]} split by a body plane (normal '
                     f'{region["plane_normal_body"]}), {100 * region["step_m"]:+.1f} cm '
                     f'(z = {region["z"]:.1f}); the pose beyond it z = '
                     f'{region["pose_beyond"]["z"]:.1f} (summary.json: region_offset)')
    if s.get('confounded_with'):
        lines.append(f'confounded: {", ".join(s["confounded_with"])}')
    lines.append(f'verdict: {s["verdict"]}')
    lines += [f'wrote {p}' for p in files]
    return lines
