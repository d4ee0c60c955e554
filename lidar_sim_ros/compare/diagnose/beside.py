"""Beside the named effect: the reference pose, the clock and what the decision holds
beside the named effect, each asked on top of the others, both ways (``weigh_beside``).

``Diagnosis.judge_pose`` asks whether the reference pose passes on top of the named
effect and of what the decision holds beside it (its 'also', ``pose_beside_named``).
Asked one way only, the pose was dropped wherever the 'also' took its part, and the
'also' kept its place whatever it had taken: the eleventh holdout's ``toff_incid``
(an incidence elongation and poses 30 ms late on a tumble) named incidence_angle with
laser_bias 'also' (no laser offsets in the truth), the pose passing on top of
incidence_angle alone (z 22) but not beside the lasers, and no one asked whether the
lasers pass on top of incidence_angle with the pose corrected (they do not: 0.0008
nats/point). A clock offset was never weighed there at all: alone, beside an
incidence residual ten times its size, it gains 0.0065 nats/point (z 1.0), while on
top of incidence_angle it gains 0.045.

So beside the named effect ``best`` each pair of contenders (the pose; the clock, where
it passes the rule on top of ``best``; each effect the decision holds beside ``best``)
is asked both ways, each on top of ``best`` and the other:

* the clock and an effect beside ``best``: each cross-fitted on top of ``best`` and the
  other (``Diagnosis._passes_on_top``, the rule's z, total and practical gain);
* the pose and an effect X: the pose's test on top of ``best`` and X, and X on top of
  ``best`` on the pose-corrected model (``on_pose``: the re-cast diagnosis
  ``judge_pose`` weighs candidates on).

The one that passes on top of the other keeps its place, the other is dropped (it stood
in for it); both passing, both stay; neither passing, the recording cannot tell them
apart: a tie beside the named effect (``Decision.beside_tie``, as [pose_error,
range_drift] already is, ``Diagnosis.range_offset_beside``). Nothing here names an
effect the decision did not hold except the clock, and the clock only where it passed
the rule on top of ``best``.
"""
from __future__ import annotations

from dataclasses import replace

CLOCK = 'time_offset'


def clock_on_top(diag, best, clock) -> dict | None:
    """The clock (``time_offset``) fitted on top of the named ``best`` (all the
    diagnosed points, as --fit with both would fit it, ``best`` fixed) where it passes
    the rule there: held out on top of ``best`` (``_passes_on_top``) and, fitted, the
    NLL of both below that of ``best`` alone. Returns {'effect', 'gain', 'z', 'dt_s'}
    or None."""
    from lidar_sim_ros.compare.diagnose.variants import calibrated_figures
    from lidar_sim_ros.compare.model.fit import fit_effect
    if (clock is None or clock is best or clock.variant is None or clock.error is not None
            or best.effect is None):
        return None
    try:
        if not diag._passes_on_top([best.effect], clock):
            return None
        gain, z = diag.memo('on_top_figures')[(clock.name, best.name)]
        diag.finalized(best)
        effect = fit_effect(clock.variant, diag.full, [best.effect]).effect
        after = calibrated_figures(diag.full, [best.effect, effect])[0]
    except Exception:  # noqa: BLE001 - the clock not shown beside it
        return None
    if not after < best.nll_after:
        return None
    return {'effect': effect, 'gain': gain, 'z': z,
            'dt_s': float(getattr(effect.params, 'dt_s', float('nan')))}


def weigh_beside(diag, decision, best, cands: list, beside: list, test, pose, on_pose,
                 again: list):
    """The decision beside the named ``best`` with each pair of contenders asked both
    ways (module doc). ``beside``: the candidates the decision holds beside ``best``
    (its 'also' and what ``pose_beside_named`` fitted with it; may be empty); ``test``:
    the pose test ``judge_pose`` chose (per cloud or one for the recording), called
    with the effects on top; ``pose``: its correction; ``on_pose``: the diagnosis on
    the corrected pose; ``again``: the candidates scored there. Records each answer on
    the candidates (``against_pose``: ``beside``, ``beside_clock``, ``beside_pose``).
    Returns the decision, or None where no pair could be asked (nothing scored on the
    corrected pose) or the pose takes every contender (it passes on top of each, none
    passes on the corrected pose): ``judge_pose``'s decision then stands as without
    this (the pose reported beside ``best`` where its test passed on top of it and what
    the decision holds beside it, else not)."""
    from lidar_sim_ros.compare.diagnose.candidate import POSE_ERROR, _num
    by_name = {c.name: c for c in cands}
    clock = by_name.get(CLOCK)
    fitted_clock = (clock_on_top(diag, best, clock)
                    if all(b is not clock for b in beside) else None)
    effect_of = {b.name: b.effect for b in beside}
    kept = list(beside)
    if fitted_clock is not None:
        effect_of[CLOCK] = fitted_clock['effect']
        clock.against_pose = {**(clock.against_pose or {}), 'beside': {
            'on_top_of': best.name, 'gain': fitted_clock['gain'], 'z': fitted_clock['z'],
            'dt_s': _num(fitted_clock['dt_s'])}}
        clock_stays = True
        for b in beside:
            b_over = diag._passes_on_top([best.effect, fitted_clock['effect']], b)
            c_over = diag._passes_on_top(diag._fitted_together([best.effect, b.effect]),
                                         clock)
            b.against_pose = {**(b.against_pose or {}), 'beside_clock': {
                'passes_on_top_of_clock': bool(b_over), 'clock_passes_on_top': bool(c_over)}}
            if c_over and not b_over:
                kept.remove(b)             # it stood in for the clock
            elif b_over and not c_over:
                clock_stays = False        # the clock stood in for it
        if clock_stays:
            kept.append(clock)
    if not kept:
        return None
    on = {a.name: a for a in again}
    on_best = on.get(best.name)
    stays, tie, pose_stays, asked = [], [], True, False
    for x in kept:
        a = on.get(x.name)
        if on_best is None or a is None or a.variant is None:
            stays.append(x)                # not scored on the corrected pose: not asked
            pose_stays = False
            continue
        asked = True
        pose_over = test(diag._fitted_together([best.effect, effect_of[x.name]])
                         if x is not clock else [best.effect, effect_of[x.name]])
        x_over = bool(on_pose._passes_on_top([on_best.effect], a))
        x.against_pose = {**(x.against_pose or {}), 'beside_pose': {
            'pose_gain_on_top': _num(pose_over.gain), 'pose_z_on_top': _num(pose_over.z),
            'pose_passes_on_top': bool(pose_over.significant),
            'passes_on_top_on_pose': x_over}}
        if x_over:
            stays.append(x)
            pose_stays = pose_stays and bool(pose_over.significant)
        elif not pose_over.significant:
            tie.append(x)
        # else the pose takes it: it stood in for the pose
    if not asked or (not stays and not tie):
        return None
    also = stays[0].name if stays else None
    if not tie:
        # Each that stays passes on top of the pose; the pose stays reported only where
        # it passes on top of each of them too.
        return replace(decision, also=also, pose=pose if pose_stays else None)
    return replace(decision, also=also, pose=None,
                   beside_tie=[POSE_ERROR, *[x.name for x in tie]],
                   beside_pose=test([best.effect]))
