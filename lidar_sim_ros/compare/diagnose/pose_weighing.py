"""The reference pose weighed against what the diagnosis named (``PoseWeighing``, a part
of ``Diagnosis``): whether the pose is off per cloud or once for all clouds, what it
leaves the named effects, the range terms of the sensor (``POSE_RIVALS``) and a clock
offset weighed against it on the same held-out footing, and the ties where the data
cannot tell them. Gains in nats per point, ranges in m.
"""
from __future__ import annotations

import copy
from dataclasses import is_dataclass, replace

import numpy as np

from lidar_sim_ros.compare.diagnose import beside, power_incidence
from lidar_sim_ros.compare.diagnose.candidate import (MIN_PRACTICAL_GAIN, POSE_ERROR,
                                                      POSE_RIVALS, RANGE_DRIFT, Candidate,
                                                      Decision, _num)
from lidar_sim_ros.compare.diagnose.features import Attribution
from lidar_sim_ros.compare.diagnose.variants import heldout_nll
from lidar_sim_ros.core.effects import Effect


def _moved_target_words(on_moved, fault: str) -> str:
    """Why a candidate is withheld beside the target moved along the line of sight: its
    figures there (``on_moved``: the candidate scored on the moved target) and why it
    may not be named there (``fault``: the naming rule's reason, ``naming_fault``)."""
    return (f'explained by the target moved along the line of sight, raycast again and '
            f'scored as the candidates are: on the moved target it gains '
            f'{on_moved.score:.4f} nats/point (z = {on_moved.z:.1f}), and may not be named '
            f'there: {fault}')


def _with_raycast(pose, raycast: dict):
    """``pose`` (a ``pose_error.PoseError``, or a stand-in) reported on the raycast
    footing: a copy carrying ``raycast``."""
    if is_dataclass(pose):
        return replace(pose, raycast=raycast)
    out = copy.copy(pose)
    out.raycast = raycast
    return out


def _better_of(held: float, fitted: float, charged: float) -> int:
    """A named candidate against the reference pose that explains the same residual:
    1 the candidate, -1 the pose, 0 a tie. ``held``: the candidate's held-out gain less
    the pose's (nats/point); ``fitted``: the pose-corrected model's NLL less the
    candidate's, as --fit leaves them; ``charged``: the same with each parameter charged
    one nat (AIC), so the pose's six per cloud gain nothing by their number alone.
    MIN_PRACTICAL_GAIN apart held out, the better one stands, unless the charged fitted
    footing says the opposite by as much: the pose's held-out test is linear in the
    correction (points a pose error moves across a depth step leave it as outliers)
    while the candidate and the fitted pose are raycast again, so the two footings
    disagreeing by a margin is a tie, not a winner. Held out closer than the margin,
    the fitted footing decides; closer there too, a tie."""
    if abs(held) >= MIN_PRACTICAL_GAIN:
        if abs(charged) >= MIN_PRACTICAL_GAIN and (held > 0) != (charged > 0):
            return 0
        return 1 if held > 0 else -1
    if abs(fitted) >= MIN_PRACTICAL_GAIN:
        return 1 if fitted > 0 else -1
    return 0


def _fitted_against_pose(pose, c: Candidate, on_pose: 'Diagnosis', same_points,
                         default_params: int) -> tuple[float, float]:
    """How much better the candidate ``c`` fits than the pose-corrected model
    (``on_pose``), as --fit leaves them (nats per point; the two NLLs on the same points
    where ``same_points`` is given), and that margin charged: in-sample the pose's
    parameters (``default_params`` if it does not say) fit better by their number
    alone, so each is charged one nat (AIC) on the points the pose was fitted on."""
    if same_points is not None:
        pose_nll, c_nll = same_points(pose, c.effect)
        fitted = float(pose_nll - c_nll)
    else:
        fitted = float(on_pose.before_nll - c.nll_after)
    charged = fitted + ((getattr(pose, 'n_params', default_params) - (c.n_params or 1))
                        / max(len(on_pose.rays.matched), 1))
    return fitted, charged


def _range_rival_tied(decision: Decision, cands: list[Candidate]) -> Candidate | None:
    """The range term of the sensor (POSE_RIVALS) a reported pose is tied with, alone
    beside it (``confounded_with`` [pose_error, that term], nothing named), as a scored
    candidate; else None."""
    tie = list(decision.confounded_with or [])
    if decision.missing or len(tie) != 2 or POSE_ERROR not in tie:
        return None
    other = next(n for n in tie if n != POSE_ERROR)
    if other not in POSE_RIVALS:
        return None
    return next((c for c in cands if c.name == other and c.effect is not None
                 and c.error is None), None)


def _fitted_clock(cands: list[Candidate]) -> Candidate | None:
    """The clock offset (``time_offset``) among ``cands``, fitted without an error; else
    None."""
    clock = next((c for c in cands if c.name == beside.CLOCK), None)
    return None if clock is None or clock.effect is None or clock.error is not None else clock


class PoseWeighing:
    """The reference pose against the named effects: methods of ``Diagnosis`` (they use
    its folds, scores and rule), kept apart as one decision."""

    def pose_corrected(self, correction_m: np.ndarray) -> 'Diagnosis':
        """This diagnosis on the model with a reference-pose correction (m of range per
        matched point of ``self.full``, ``pose_error.corrected``)."""
        from lidar_sim_ros.compare.diagnose.pose_error import corrected
        out = copy.copy(self)
        out.full = corrected(self.full, correction_m)
        out.fold_data = [corrected(d, correction_m[self.places(f.matched)])
                         for d, f in zip(self.fold_data, self.folds)]
        out._base_nll = [heldout_nll(d, []) for d in out.fold_data]
        out._before_nll = None
        out._before_rmse = None
        out._core = None
        out._memos = {}        # the copy shares them with this model otherwise
        return out

    def judge_pose(self, pose_test, cands: list[Candidate], decision: Decision,
                   recast=None, constant_test=None, same_points=None,
                   row_test=None) -> Decision:
        """Whether the reference pose is off, and what it leaves the candidates.
        ``pose_test(effects)``: the per-cloud rigid correction's test
        (``pose_error.fit_reference_pose``) on the model with ``effects``;
        ``constant_test(effects)``: one rigid correction for all the clouds (an extrinsic
        error: six parameters, asked when the per-cloud test fails). Each named (or
        confounded) candidate is weighed against the pose both ways on the same held-out
        footing, as ``weigh_pose_rivals`` weighs the range terms: the pose's test on top
        of it, and the candidate scored again on the model with the pose corrected
        (``recast(pose)``: the diagnosis raycast again with the corrected pose, on a
        sample drawn anew as a --fit run draws it, ``run.recast_all_points``; without
        it, the linear range correction,
        ``pose_corrected``, which leaves the residuals at silhouettes and depth steps).
        - The candidate passes the rule on the corrected pose: it explains what the pose
          cannot; it is named (the pose reported beside it if its test passes on top).
        - It does not, and the pose passes on top of it: the pose explains the
          residual; no sensor effect is named (unless another candidate passes on the
          corrected pose: decided among those as before).
        - Neither adds to the other: held out (the candidate's gain against the pose's)
          and, where those are closer than MIN_PRACTICAL_GAIN, as --fit leaves them (the
          candidate's fitted NLL against the pose-corrected model's, the footing
          ``weigh_pose_rivals`` uses; ``same_points(pose, effect)``: the two NLLs on the
          same points), MIN_PRACTICAL_GAIN apart the better one stands; closer, a tie
          (``confounded_with``: pose_error and the candidate). Held out and fitted
          disagreeing by the margin is a tie too (``_better_of``). The held-out
          footing comes first: in-sample, six parameters per cloud always fit better
          than one of a clock offset.
        - The pose takes a named clock offset (it passes on top of it, the clock not on
          the corrected pose), but what it gains beyond the clock grows with the row
          (``row_test(effect)``: ``row_clock.row_time_test``, asked where the points
          carry no time within a cloud): a time within the exposure the points do not
          carry, which neither explains; the two stand in for its mean, a tie
          (``rows_under_clock``).
        - Beside a named effect that stands, the pose, the clock and what the decision
          holds beside it are asked on top of each other both ways
          (``beside.weigh_beside``): the one that passes on top of the other keeps its
          place; neither, a tie beside the named effect (``beside_tie``)."""
        tests = [pose_test] + ([constant_test] if constant_test is not None else [])
        alone = [(t, t([])) for t in tests]
        passed = [(t, p) for t, p in alone if p.significant]
        by_name = {c.name: c for c in cands}
        named = [by_name[n] for n in [decision.missing, *decision.confounded_with]
                 if n in by_name and by_name[n].effect is not None]
        self.pose_on_top = []          # what the pose weighed had in the model (summary)
        if not passed and named:
            self.pose_on_top = [c.name for c in named]
            # The pose off beside the named effect: its test passes with the effect in
            # the model (an effect's wider sigma at the edges takes what a weak per-cloud
            # test, 40 clouds of jitter, leaves in its noise), so it is weighed all the
            # same; reported only as the weighing below decides.
            on_top = [c.effect for c in named]
            passed = [(t, p) for t, p in ((t, t(on_top)) for t in tests) if p.significant]
        if not passed:
            along = [p for _, p in alone[1:] if getattr(p, 'joint', False)]
            if not along:
                return decision
            if named:
                return self.weigh_line_of_sight(along[0], named, decision, recast, same_points)
            return self.line_of_sight_alone(along[0], decision, recast, same_points)
        # Per cloud or one for the whole recording: the larger held-out gain (the
        # per-cloud correction's extra parameters are paid for on the held-out half).
        test, pose = max(passed, key=lambda tp: getattr(tp[1], 'gain', 0.0))
        # Named candidates that leave the pose nothing (its test fails on top of them).
        explain = []
        for c in named:
            on_top = test([c.effect])
            c.pose_on_top = {'pose_constant': bool(getattr(on_top, 'constant', False)),
                             'gain': _num(getattr(on_top, 'gain', None)),
                             'z': _num(getattr(on_top, 'z', None)),
                             'significant': bool(on_top.significant)}
            if not on_top.significant:
                explain.append(c)
        from_beside = not explain
        if not explain:
            explain = self.pose_beside_named(test, pose, decision, cands)
        if not any(c.admissible and c.effect is not None for c in cands):
            # Reported as --effect pose_error --fit would correct it: fitted on every
            # matched point and raycast again until the step is small (the sample's
            # linear fit, on the rays the recorded pose matched, falls short of a large
            # error: 3.5 cm for (3, 2, -3) cm); its test stays the sample's.
            if recast is not None:
                pose = recast(pose)[1]
            return replace(decision, pose=pose)
        # Scored again on the corrected pose: every candidate, as the next run with the
        # pose corrected would score it, also those a signature test set aside on the
        # recorded pose (asked again there) and those that did not pass the rule: a
        # pose error hides a range walk beside it (z 1.0 on the recorded pose) as it
        # hides a laser's offsets across its tile (the fifth holdout's laser_jitter).
        contenders = [c for c in cands if c.effect is not None and c.error is None]
        if recast is not None:
            on_pose, pose = recast(pose)
        else:
            on_pose = self.pose_corrected(pose.correction_m)
        again = [on_pose.score(type(c.effect)) for c in contenders]
        passes = {a.name: on_pose.nameable(a) for a in again}
        for c, a in zip(contenders, again):
            c.against_pose = {**(c.against_pose or {}),
                              'pose_constant': bool(getattr(pose, 'constant', False)),
                              'score_on_pose': _num(a.score), 'z_on_pose': _num(a.z),
                              'passes_on_pose': bool(passes[a.name]),
                              'pose_corrected_nll': _num(on_pose.before_nll),
                              **({'params_on_pose': a.params} if a.params else {})}
        if explain:
            if any(passes.get(c.name) for c in explain):
                # It explains what the pose cannot: it stands. What the decision holds
                # beside it took the pose's part: asked the other way too, with the
                # clock (``beside.weigh_beside``).
                if from_beside:
                    lead = by_name[decision.missing]
                    held = [by_name[n] for n in lead.pose_beside['with'] if n in by_name]
                    weighed = beside.weigh_beside(self, decision, lead, cands, held, test,
                                                  pose, on_pose, again)
                    if weighed is not None:
                        return weighed
                return decision
            # Neither adds to the other: held out (the candidate's gain against the
            # pose's), then as --fit leaves them (its fitted NLL against the
            # pose-corrected model's); MIN_PRACTICAL_GAIN apart the better one stands.
            better = {}
            for c in explain:
                if not self.nameable(c):
                    continue
                held = float(c.score - pose.gain)
                fitted, charged = _fitted_against_pose(pose, c, on_pose, same_points, 0)
                c.against_pose.update(heldout_margin=_num(held), fitted_margin=_num(fitted),
                                      fitted_margin_charged=_num(charged))
                if getattr(pose, 'constant', False):
                    # One correction for the recording: six parameters on every point,
                    # so its raycast footing, charged, is as good as held out, and the
                    # held-out test is linear (it cannot see the rays a moved target
                    # puts across a silhouette or a depth step, where a candidate's
                    # wider sigma gains).
                    better[c.name] = _better_of(charged, fitted, charged)
                else:
                    better[c.name] = _better_of(held, fitted, charged)
            if any(b > 0 for b in better.values()):
                return decision            # the candidate explains more than the pose
            tied = [n for n, b in better.items() if b == 0]
            if tied:
                # What explained a separate part stays when it passes the rule on the
                # corrected pose too (the pose does not take it): a range walk beside
                # a pose held at 10 Hz, tied with a clock offset.
                also = (decision.also if decision.also and passes.get(decision.also)
                        else None)
                return Decision(None, [POSE_ERROR, *tied], pose=pose, also=also,
                                withheld=dict(decision.withheld))
            return Decision(None, [], pose=pose, withheld=dict(decision.withheld))
        if not any(passes.values()):
            if self.rows_under_clock(named, row_test):
                return Decision(None, [POSE_ERROR, beside.CLOCK], pose=pose,
                                withheld=dict(decision.withheld))
            return Decision(None, [], pose=pose)
        # The pose is off beside what was named (its test passes on top of it): the
        # candidates are decided again on the pose-corrected model, which is named, a
        # tie, and what also explains another part. On the recorded pose a drifting
        # pose's residual at silhouettes reads as incidence: beside a range walk it
        # was named, or said to explain a part of its own ("also").
        final = replace(on_pose.decide(again), pose=pose, withheld=dict(decision.withheld))
        lead = by_name.get(final.missing)
        if lead is not None and final.missing == decision.missing and lead.effect is not None:
            # The pose beside the named effect, against the clock (``beside.weigh_beside``).
            held = [by_name[final.also]] if final.also in by_name else []
            weighed = beside.weigh_beside(self, final, lead, cands, held, test, pose,
                                          on_pose, again)
            if weighed is not None:
                return weighed
        return final

    def rows_under_clock(self, named: list[Candidate], row_test) -> bool:
        """Whether a named clock offset (``time_offset``, nameable) that the pose took
        stands, with the pose, for a time that grows with the row (``row_test(effect)``,
        called with the clock's effect: a ``row_clock.RowTime``; None: not asked). The
        test's figures are recorded on the clock's ``against_pose['row_time']``."""
        clock = next((c for c in named if c.name == beside.CLOCK), None)
        if clock is None or row_test is None or not self.nameable(clock):
            return False
        rows = row_test(clock.effect)
        clock.against_pose = {**(clock.against_pose or {}), 'row_time': rows.as_dict()}
        return bool(rows.significant)

    def pose_beside_named(self, test, pose, decision: Decision,
                          cands: list[Candidate]) -> list[Candidate]:
        """The named candidates, when the pose's test fails on top of everything the
        decision holds beside the named effect, fitted together (``_fitted_together``,
        as --fit fits them): the effect that also explains another part (``also``) and
        the decisive effects set aside beside it (``set_aside_beside``), and a per-laser
        candidate the tile test set aside whose offsets hold across the tiles with all of
        these in the model (``tile_veto`` on top, as ``lasers_beside`` asks). A pose that
        passes on top of each alone may only take what another of them explains: per-laser
        range offsets are a fixed pattern over the target in every cloud (each laser's
        tile), which one rigid correction for the recording partly fits (the ninth
        holdout's walk+laser: a walk named, the lasers 'also', and the pose 'off' by
        1-3 cm with exact poses). Returned as ``judge_pose``'s ``explain``: the pose is
        then weighed against them as against a named effect that leaves it nothing.
        Records the test on ``pose_beside`` of the named candidate. Empty (the pose
        judged as before) with nothing beside the named effect, or where the pose still
        passes on top of them all."""
        by_name = {c.name: c for c in cands}
        best = by_name.get(decision.missing)
        if best is None or best.effect is None:
            return []
        beside = [by_name[decision.also]] if decision.also in by_name else []
        beside += [c for c in self.set_aside_beside(best, cands)
                   if all(c is not b for b in beside)]
        beside = [c for c in beside if c.effect is not None and c.error is None]
        if not beside:
            return []
        try:
            self.finalized(best, *beside)
            together = self._fitted_together([best.effect, *[c.effect for c in beside]])
            # Lasers the tile test set aside, asked again with all of these in the model
            # (as ``lasers_beside`` asks beside the named one alone): the pattern the
            # tiles cut up may be theirs together (a walk beside false returns).
            lasers = [c for c in cands if c.tile_vetoed and c.significant and c.error is None
                      and c.effect is not None and all(c is not b for b in beside)
                      and self.tile_veto(c, together) is None]
            if lasers:
                beside += lasers[:1]
                self.finalized(lasers[0])
                together = self._fitted_together([best.effect,
                                                  *[c.effect for c in beside]])
            on_all = test(together)
        except Exception:  # noqa: BLE001 - the pose judged as before
            return []
        best.pose_beside = {'with': [c.name for c in beside],
                            'pose_constant': bool(getattr(pose, 'constant', False)),
                            'gain': _num(on_all.gain), 'z': _num(on_all.z),
                            'significant': bool(on_all.significant)}
        return [] if on_all.significant else [best]

    def weigh_line_of_sight(self, pose, named: list[Candidate], decision: Decision,
                            recast=None, same_points=None) -> Decision:
        """A constant correction along the line of sight whose own test fails, against
        the named (or tied) candidates. ``pose``: one rigid correction for the recording
        fitted jointly with the material offsets, which took their common offset
        (``PoseError.joint``: the target recorded nearer or farther). Its held-out test
        is linear and leaves grazing rays out, so beyond the offsets (which a range
        offset of the sensor gives alike) it sees little; but a target moved along the
        line of sight changes the ranges near its limbs as 1 / cos(incidence), which
        ``surface_offset`` and ``incidence_angle`` (with a negative bias) take. So each
        named candidate is scored again on the pose-corrected model (``recast``, as
        ``judge_pose`` weighs a pose that passes): if one still passes the rule there,
        or fits decisively better than the corrected pose as --fit leaves them
        (``same_points``, each parameter charged a nat, ``_better_of``), the decision
        stands. Otherwise what they gained is what the pose leaves, and nothing is
        named. If the corrected pose fits decisively better than every one of them
        (MIN_PRACTICAL_GAIN, charged), it is reported (``PoseError.raycast``): each
        passed the rule against the model without it, whose per-material offsets are
        what a range offset of the sensor gives, so the pose explains the data better
        than the sensor's offset too. Closer, a tie: the pose is not reported (its own
        test did not pass) and the verdict says the materials' common offset is a range
        offset of the sensor or the reference pose along the line of sight, which this
        recording cannot tell apart."""
        if recast is not None:
            on_pose, pose = recast(pose)
        else:
            on_pose = self.pose_corrected(pose.correction_m)
        better, margins = [], []
        for c in named:
            a = on_pose.score(type(c.effect))
            passes = on_pose.nameable(a)
            c.against_pose = {**(c.against_pose or {}), 'pose_constant': True,
                              'pose_line_of_sight': True, 'pose_significant': False,
                              'pose_translation_cm': _num(getattr(pose, 'size_cm', None)),
                              'score_on_pose': _num(a.score), 'z_on_pose': _num(a.z),
                              'passes_on_pose': bool(passes),
                              'pose_corrected_nll': _num(on_pose.before_nll),
                              **({'params_on_pose': a.params} if a.params else {})}
            if passes or not self.nameable(c):
                better.append(1 if passes else 0)
                continue
            fitted, charged = _fitted_against_pose(pose, c, on_pose, same_points, 6)
            c.against_pose.update(fitted_margin=_num(fitted), fitted_margin_charged=_num(charged))
            better.append(_better_of(charged, fitted, charged))
            margins.append(charged)
        if any(b > 0 for b in better):
            return decision
        why = ('explained as well by one rigid correction of the reference pose along the '
               'line of sight (it does not pass on the corrected pose)')
        withheld = {**decision.withheld, **{c.name: why for c in named}}
        if better and all(b < 0 for b in better):
            raycast = {'explains': [c.name for c in named],
                       'fitted_margin_charged': _num(-max(margins))}
            return Decision(None, [], pose=_with_raycast(pose, raycast), withheld=withheld)
        return Decision(None, [], withheld=withheld)

    def line_of_sight_alone(self, pose, decision: Decision, recast=None,
                            same_points=None) -> Decision:
        """Nothing named, and a constant correction along the line of sight whose own
        test fails (``weigh_line_of_sight``'s ``pose``): raycast again with it, against
        the model without it on the same points (``same_points(pose, None)``), as --fit
        leaves them. The model without it holds the per-material offsets, which is what
        a range offset of the sensor gives; the moved target changes the ranges near
        its limbs and across depth steps besides, which the offsets cannot. Fitting
        MIN_PRACTICAL_GAIN better, its six parameters charged a nat each, it is
        reported (``PoseError.raycast``); closer, the decision stands (the verdict's
        sentence on a common offset of the materials: the sensor or the pose)."""
        if recast is None or same_points is None:
            return decision
        on_pose, pose = recast(pose)
        pose_nll, base_nll = same_points(pose, None)
        margin = float(base_nll - pose_nll) - (getattr(pose, 'n_params', 6)
                                               / max(len(on_pose.rays.matched), 1))
        if not margin >= MIN_PRACTICAL_GAIN:
            return decision
        return replace(decision, pose=_with_raycast(pose, {
            'explains': [], 'fitted_margin_charged': _num(margin)}))

    def weigh_pose_rivals(self, decision: Decision, rivals: list[type[Effect]], pose_test,
                          on_pose, scored: dict | None = None,
                          attribution: Attribution | None = None
                          ) -> tuple[Decision, list[Candidate]]:
        """A reported pose error against range errors of the sensor (POSE_RIVALS: a
        range offset drifting over the recording, a range scale), on the same footing:
        each rival that passes the naming rule is weighed both ways, the pose's test on
        top of it (``pose_test([rival])``) and the rival scored on the pose-corrected
        model (``on_pose()``: the re-cast diagnosis). A rival that still passes on the
        corrected pose explains what the pose cannot: it is named (the pose reported
        beside it only if its test passes on top of the rival). A rival the pose
        leaves nothing to, and that leaves the pose nothing, is then weighed as --fit
        leaves them (``decide``'s second footing): the rival's fitted NLL against the
        pose-corrected model's; MIN_PRACTICAL_GAIN apart, the better one stands (the
        rival named, or the pose alone); closer, they explain the data as well: a tie,
        ``confounded_with`` [pose_error, rival]. Returns the decision and the rivals
        scored (for the summary's candidates). A rival scored here passes the vetoes
        every candidate does (``share_veto`` on ``attribution``): a range scale that
        explains a fifth of a structure the lasers' offsets hold is no rival of the
        pose (thirteenth holdout walk_laser_graze_2: named as a stand-in)."""
        if decision.pose is None or decision.missing or decision.confounded_with:
            return decision, []
        done = dict(scored or {})
        scored, wins, ties = [], [], []
        for cls in rivals:
            r = done.get(cls.name)
            if r is None:
                r = self.score(cls)
                self.share_veto(r, attribution)
            scored.append(r)
            if not self.nameable(r):
                continue
            pose_on_top = pose_test([r.effect])
            corrected = on_pose()
            again = corrected.score(cls)
            passes_on_pose = corrected.nameable(again)
            # As --fit leaves them: the rival fitted, against the pose corrected and the
            # model raycast again (rays at silhouettes and depth steps meet the surfaces
            # the corrected pose puts there, which a range offset does not move).
            fitted = float(corrected.before_nll - r.nll_after)
            r.against_pose = {'pose_constant': bool(getattr(decision.pose, 'constant', False)),
                              'pose_gain_on_top': _num(pose_on_top.gain),
                              'pose_z_on_top': _num(pose_on_top.z),
                              'pose_significant_on_top': bool(pose_on_top.significant),
                              'score_on_pose': _num(again.score), 'z_on_pose': _num(again.z),
                              'passes_on_pose': bool(passes_on_pose),
                              'nll_after': _num(r.nll_after),
                              'pose_corrected_nll': _num(corrected.before_nll),
                              'fitted_margin': _num(fitted)}
            if passes_on_pose:
                wins.append((r, pose_on_top.significant))
            elif pose_on_top.significant:
                continue                       # the pose explains what the rival cannot
            elif fitted >= MIN_PRACTICAL_GAIN:
                wins.append((r, False))        # as --fit leaves them, the rival is better
            elif fitted > -MIN_PRACTICAL_GAIN:
                ties.append(r)                 # else the corrected pose is better: it stays
        if wins:
            best, pose_left = max(wins, key=lambda w: w[0].score)
            # Two range terms that each beat the pose are weighed against each other by
            # ``decide``'s rule: on an approach, where the range falls with time, a
            # drift and a scale can fit alike (a tie, the plan separating them).
            pair_z = dict(decision.pair_z)
            tied = []
            for r, _ in wins:
                if r is best:
                    continue
                margin, z = self.paired(best, r)
                fitted = self.fitted_margin(best, r)
                pair_z[r.name] = {'margin': _num(margin), 'z': _num(z),
                                  'fitted_margin': _num(fitted)}
                if not self.apart(margin, z, fitted):
                    tied.append(r.name)
            pose = decision.pose if pose_left else None
            if tied:
                return replace(decision, missing=None, confounded_with=[best.name, *tied],
                               pose=pose, pair_z=pair_z), scored
            return replace(decision, missing=best.name, pose=pose, pair_z=pair_z), scored
        if ties:
            return replace(decision, confounded_with=[POSE_ERROR, *[t.name for t in ties]]), scored
        return decision, scored

    def range_offset_beside(self, decision: Decision, cands: list[Candidate],
                            pose_test) -> Decision:
        """A per-cloud pose correction reported (alone, or beside a named effect) against
        a range offset of the sensor that changes between clouds (a temperature step, a
        counter reset), on the same held-out footing: the pose's test on the model with
        the named effect and its 'also' (``pose_test(effects)``) fits one range offset
        per cloud on the same halves (``PoseError.offset_gain``) and the rigid
        correction beyond it, nested (``beyond_offset_*``). ``range_drift``, the
        catalogue's drifting range offset, is linear in time and a step is not, so
        weighed as a candidate (``weigh_pose_rivals``) it loses to six parameters a
        cloud; one offset a cloud is the sensor's side of the same footing. A
        correction that gains nothing beyond the offsets, where they pass the rule,
        moves the clouds only as the sensor's range offset would: beside a named effect
        the two are a tie of their own (``beside_tie``); alone, the tie
        ``confounded_with`` [pose_error, range_drift] (``range_drift`` passing the rule
        on the recorded pose, as ``settle`` asks). Where the pose gains beyond them (a
        rotation, a motion across the line of sight) or drifts within the clouds, it
        stays."""
        pose = decision.pose
        if (pose is None or getattr(pose, 'constant', False)
                or getattr(pose, 'rate_supported', False) or decision.confounded_with):
            return decision
        by_name = {c.name: c for c in cands}
        if not decision.missing and not (RANGE_DRIFT in by_name
                                         and self.nameable(by_name[RANGE_DRIFT])):
            return decision
        on_top = [by_name[n].effect for n in (decision.missing, decision.also)
                  if n in by_name and by_name[n].effect is not None]
        test = pose_test(on_top)
        offsets = test.offset_z >= self.z_crit and test.offset_gain >= MIN_PRACTICAL_GAIN
        beyond = (test.beyond_offset_z >= self.z_crit
                  and test.beyond_offset_gain >= MIN_PRACTICAL_GAIN)
        if beyond or not offsets:
            return decision
        if decision.missing:
            return replace(decision, pose=None, beside_tie=[POSE_ERROR, RANGE_DRIFT],
                           beside_pose=test)
        return replace(decision, confounded_with=[POSE_ERROR, RANGE_DRIFT],
                       beside_pose=test)

    def rivals_beside_pose(self, decision: Decision, cands: list[Candidate],
                           rivals: list[type[Effect]],
                           attribution: Attribution | None = None) -> list[Candidate]:
        """The sensor's range terms (``rivals``: POSE_RIVALS) not scored yet, scored with
        the vetoes every candidate passes (``share_veto``), where the decision reports
        the pose and names nothing; else none. ``weigh_rivals`` scores them only beside a
        name, so with the pose alone ``range_term_beside_constant_pose`` had none to fit
        the constant pose on top of, and only the pose fitted alone was weighed against
        them (``weigh_pose_rivals``). On a body tilted toward the line of sight a range
        scale on a hold is, beyond the materials' common offset, a turn of the pose
        (delta ~ s tan(tilt)): the pose fitted alone takes it, turned a little and
        across the line of sight, and the scale then gains nothing on the corrected
        pose; fitted on top of the scale, the constant correction is the motion along
        the line of sight the pose has (a 1 % scale beside 6 cm along the line of
        sight: the pose alone 0.6-1.1 cm, 2-17 % along the line of sight; on top of the
        scale 5.2 cm, 99 %). Returns the candidates scored here."""
        if decision.pose is None or decision.missing or decision.confounded_with:
            return []
        have = {c.name for c in cands}
        return self.scored_with_vetoes(
            [cls for cls in rivals if (getattr(cls, 'name', '') or cls.__name__) not in have],
            attribution)

    def range_term_beside_constant_pose(self, decision: Decision, cands: list[Candidate],
                                        constant_test, on_constant_pose) -> Decision:
        """A range error of the sensor (POSE_RIVALS) that passes the held-out rule but is
        not named (set aside, ranked below, or one of a tie), beside a reference pose off
        by one constant motion along the line of sight (the ninth holdout's
        drift+pose_los: the range drifting 4 cm/min and the pose 3 cm off along the line
        of sight). The two hide each other. The pose's
        constant part goes to the materials' offsets (a translation along the line of
        sight moves every range alike), and what it leaves is its pattern at the limbs,
        n.d / n.u less its mean: a range change growing toward grazing, which
        ``surface_offset`` and ``incidence_angle`` take, on the recorded pose and on the
        per-cloud corrected one (the per-cloud correction leaves the common offset to
        the materials too, ``pose_error.fit_clouds``). The drift, on a turning target,
        moves the offsets of materials seen at different times by different amounts, so
        one correction for the recording, fitted on the recorded pose, goes through
        those offsets (``through_materials``) instead of taking their common part; and
        the limb pattern, differing by material, sets the range term aside by the
        cross-material test (``material_veto``).
        Fitted on top of the range term (``constant_test([effect])``: six parameters on
        the sample's held-out halves, as ``judge_pose`` asks it), one correction for the
        recording that passes the rule and took the materials' common offset
        (``PoseError.joint``: along the line of sight) is applied and the model raycast
        again (``on_constant_pose(effect)``: the re-cast diagnosis, the correction fitted
        on every matched point, and the per-cloud test there). The range term is named,
        the constant pose reported beside it, when on that corrected pose: it passes the
        rule with every veto (``nameable``); nothing the decision named passes there
        (each took only what the pose left); the per-cloud correction gains nothing on top
        of the range term (the pose is off by one motion, not cloud by cloud); and held
        out, the range term gains MIN_PRACTICAL_GAIN more than the per-cloud correction
        alone (``judge_pose``'s first footing; closer, the two are the tie
        [pose_error, the range term], the pose quoted the per-cloud one). Otherwise the
        decision stands. Each figure is recorded on the range term's ``against_pose``."""
        names = {decision.missing, decision.also, *decision.confounded_with}
        rivals = [c for c in cands if c.name in POSE_RIVALS and c.name != decision.missing
                  and c.effect is not None and c.error is None and c.significant
                  and c.practical]
        for r in sorted(rivals, key=lambda c: -c.score):
            test = constant_test([r.effect])
            r.against_pose = {**(r.against_pose or {}), 'constant_on_top': {
                'gain': _num(getattr(test, 'gain', None)), 'z': _num(getattr(test, 'z', None)),
                'significant': bool(test.significant),
                'joint': bool(getattr(test, 'joint', False)),
                'line_of_sight_share': _num(getattr(test, 'line_of_sight_share', None)),
                'translation_cm': _num(getattr(test, 'size_cm', None))}}
            if not (test.significant and getattr(test, 'joint', False)):
                continue
            on_pose, pose, per_cloud = on_constant_pose(r.effect)
            again = on_pose.score(type(r.effect))
            record = {'pose_constant': True, 'pose_line_of_sight': True,
                      'pose_gain_on_top': _num(test.gain), 'pose_z_on_top': _num(test.z),
                      'pose_translation_cm': _num(pose.size_cm),
                      'score_on_pose': _num(again.score), 'z_on_pose': _num(again.z),
                      'passes_on_pose': on_pose.naming_fault(again) is None,
                      **({'fault_on_pose': on_pose.naming_fault(again)}
                         if on_pose.naming_fault(again) else {}),
                      **({'params_on_pose': again.params} if again.params else {}),
                      **({'veto_on_recorded_pose': r.vetoed} if r.vetoed else {})}
            r.against_pose = {**(r.against_pose or {}), **record}
            if not record['passes_on_pose']:
                continue
            named = [c for c in cands if c.name in names and c.name not in (POSE_ERROR, r.name)
                     and c.effect is not None and c.error is None]
            displaced = {}
            for c in named:
                a = on_pose.score(type(c.effect))
                displaced[c.name] = [_num(a.score), _num(a.z)]
                if on_pose.nameable(a):
                    r.against_pose['named_passes_on_pose'] = c.name
                    return decision        # it explains what the constant pose cannot
            beyond = per_cloud([again.effect])
            alone = per_cloud([])
            held = float(again.score - alone.gain) if alone.significant else float('inf')
            r.against_pose.update(per_cloud_gain_on_top=_num(beyond.gain),
                                  per_cloud_z_on_top=_num(beyond.z),
                                  per_cloud_gain=_num(alone.gain),
                                  heldout_margin=_num(held), displaced=displaced)
            if beyond.significant:
                continue                   # the pose varies between clouds beyond it
            why = ('with one correction of the reference pose along the line of sight '
                   f'fitted on top of {r.name}, it does not pass the rule: it took what '
                   'the constant pose leaves at the limbs')
            withheld = {**decision.withheld, **{n: why for n in displaced}}
            # Asked again on the corrected pose, where it holds (the recorded pose's
            # limb pattern set it aside): the rule's candidate is the recorded pose's.
            r.vetoed = None
            if held >= MIN_PRACTICAL_GAIN:
                return Decision(r.name, [], pose=pose, withheld=withheld)
            # The tie is the per-cloud correction's (on top of the constant one, which it
            # could take too) with the range term: the pose quoted is that correction.
            return Decision(None, [POSE_ERROR, r.name], pose=alone, withheld=withheld)
        return decision

    def weigh_on_ray_footing(self, decision: Decision, cands: list[Candidate],
                             rivals: list[type[Effect]], los_fit, on_shift,
                             as_pose, versus=None) -> Decision:
        """The named (or tied) sensor effects against the target moved along the line of
        sight, on the candidates' own footing (``line_of_sight``): every ray raycast
        again, each point scored by the likelihood a candidate is scored by, the points
        put back or lost counted as a candidate's unmatched points, each material's
        offset profiled (the common offset stays the materials'). ``los_fit(on_top)``:
        the translation that fits best with ``on_top`` in the model (along the line of
        sight, then across it) and its gain (``line_of_sight.LineOfSightPose``);
        ``on_shift(los)``: the diagnosis with every ray raycast with the target so moved;
        ``as_pose(los, explains)``: the pose to report (``explains`` None: beside a name).
        - The move does not pass the rule: the decision stands.
        - The named effect (or every member of a tie) passes the rule on the moved
          target: it explains what the pose cannot; the decision stands. Of a tie, the
          members that pass there stay tied; one alone is named, its figures there,
          the pose beside it if the move passes with it in the model.
        - None does: they took what the pose leaves (its perspective at the limbs and
          the returns beyond them), none is named. A range term of the sensor
          (``rivals``) that passes the rule on the moved target is named (its figures
          those on the moved target), the pose reported beside it if the shift still
          passes with the term in the model; one that passed on the recorded pose and
          does not on the moved one, while the shift does not pass on top of it, is
          tied with the pose; else, before the pose is reported alone, a range walk
          and an incidence bias fitted together are weighed against it
          (``pair_against_moved_target``, with ``versus``); else the pose alone."""
        named = [c for c in cands if c.name in (decision.missing, *decision.confounded_with)
                 and c.name != POSE_ERROR and c.effect is not None and c.error is None]
        if not named:
            return decision
        los = los_fit([])
        self.line_of_sight = {'tested_against': [c.name for c in named], **los.as_dict()}
        if not los.significant:
            return decision
        on_pose = on_shift(los)
        again, passing, faults = {}, [], {}
        for c in named:
            a = again[c.name] = on_pose.score(type(c.effect))
            faults[c.name] = on_pose.naming_fault(a)
            passes = faults[c.name] is None
            c.against_pose = {**(c.against_pose or {}), 'line_of_sight': {
                'shift_cm': _num(100 * los.shift_m), 'pose_gain': _num(los.gain),
                'pose_z': _num(los.z), 'score_on_pose': _num(a.score),
                'z_on_pose': _num(a.z), 'passes_on_pose': bool(passes)}}
            if passes:
                passing.append(c)
        withheld = {**decision.withheld,
                    **{c.name: _moved_target_words(again[c.name], faults[c.name])
                       for c in named if c not in passing}}
        explains = [c.name for c in named if c not in passing]
        by_name = {c.name: c for c in cands}
        if passing:
            self.line_of_sight['stands'] = [c.name for c in passing]
            if decision.missing is not None or len(passing) == len(named):
                return decision
            if len(passing) > 1:
                return replace(decision, confounded_with=[c.name for c in passing],
                               withheld=withheld)
            # One member of a tie keeps a decisive part on the moved target: it is
            # named, its figures those there, the pose beside it if the move passes
            # with it in the model.
            lead, a = passing[0], again[passing[0].name]
            under = los_fit([a.effect])
            a.against_pose = lead.against_pose
            vars(lead).update(vars(a))
            return Decision(lead.name, [], pose=as_pose(under, None) if under.significant
                            else None, withheld=withheld)
        for cls in rivals:
            name = getattr(cls, 'name', '') or cls.__name__
            a = on_pose.score(cls)
            if a.effect is None or not on_pose.nameable(a):
                continue
            under = los_fit([a.effect])
            a.against_pose = {**(a.against_pose or {}), 'line_of_sight': {
                'scored_on_moved_target': True, 'shift_cm': _num(100 * los.shift_m),
                'pose_gain_on_top': _num(under.gain), 'pose_z_on_top': _num(under.z),
                'pose_shift_on_top_cm': _num(100 * under.shift_m)}}
            # The candidate the verdict quotes is the one scored on the moved target.
            if name in by_name:
                vars(by_name[name]).update(vars(a))
            else:
                cands.append(a)
            self.line_of_sight['named'] = name
            pose = as_pose(under, None) if under.significant else None
            return Decision(name, [], pose=pose, withheld=withheld)
        for c in cands:
            if c.name not in POSE_RIVALS or c.effect is None or not self.nameable(c):
                continue
            under = los_fit([c.effect])
            c.against_pose = {**(c.against_pose or {}), 'line_of_sight': {
                'passes_on_moved_target': False, 'pose_gain_on_top': _num(under.gain),
                'pose_z_on_top': _num(under.z)}}
            if not under.significant:
                self.line_of_sight['tie'] = c.name
                return Decision(None, [POSE_ERROR, c.name], pose=as_pose(los, explains),
                                withheld=withheld)
        pose = as_pose(los, explains)
        if versus is not None:
            paired = self.pair_against_moved_target(cands, los, los_fit, versus, pose,
                                                    withheld)
            if paired is not None:
                return paired
        return Decision(None, [], pose=pose, withheld=withheld)

    def pair_against_moved_target(self, cands: list[Candidate], los, los_fit, versus,
                                  pose, withheld: dict) -> Decision | None:
        """A range walk and an incidence bias refitted together (``_fitted_together``)
        against the target moved along the line of sight, before that move is reported
        alone. On a flat face a bias c (1/cos(theta) - 1) is nearly what a target moved
        along the line of sight gives (delta n.x / n.u), and beside a walk of the other
        sign each alone fits only their net (the walk's lone fit even takes the wrong
        sign): each alone gains nothing on the moved target, the pair may explain as
        much. ``los_fit(on_top)`` as in ``weigh_on_ray_footing``; ``versus(effects, los)``:
        on the same points, ray footing, the pair on the recorded pose against the
        moved target and against the recorded pose alone, each a (gain per point, z,
        passes) of the first over the second: {'pair_over_pose', 'pose_over_pair',
        'pair_over_none'}.
        - The move still passes on top of the pair, or the moved target fits better
          than the pair by the rule: None (the pose is reported, as before).
        - Else, the pair not passing over the recorded pose alone: None.
        - The pair fits better than the moved target by the rule: the pair named (both,
          the one gaining more alone named, the other 'also', where each passes on top of
          the other, ``each_on_top``; else their tie), no pose.
        - Else they explain the data alike: the tie [pose_error, walk, incidence], the
          pose quoted as the moved target.
        Figures in ``line_of_sight['pair']``; None where not weighed."""
        two = [next((c for c in cands if c.name == n and c.error is None
                     and c.effect is not None and c.variant is not None
                     and c.heldout_nll is not None), None) for n in power_incidence.PAIR]
        if None in two:
            return None
        named, other = sorted(two, key=lambda c: -c.score)
        try:
            effects = self._fitted_together([named.effect, other.effect])
            under = los_fit(effects)
            weighed = versus(effects, los)
        except Exception:  # noqa: BLE001 - not weighed: the pose as before
            return None
        figures = {'with': [named.name, other.name],
                   'params': {e.name: {k: _num(v) for k, v in e.params.model_dump().items()
                                       if isinstance(v, (int, float))} for e in effects},
                   'pose_on_top': {'gain': _num(under.gain), 'z': _num(under.z),
                                   'significant': bool(under.significant),
                                   'shift_cm': _num(100 * under.shift_m)},
                   **{k: [_num(v[0]), _num(v[1]), bool(v[2])] for k, v in weighed.items()}}
        self.line_of_sight['pair'] = figures
        if under.significant or weighed['pose_over_pair'][2]:
            figures['outcome'] = 'pose'
            return None
        if not weighed['pair_over_none'][2]:
            figures['outcome'] = 'pair_not_shown'
            return None
        withheld = {k: v for k, v in withheld.items() if k not in power_incidence.PAIR}
        if not weighed['pair_over_pose'][2]:
            figures['outcome'] = 'tie'
            for c in two:
                c.jointly = {'with': (other if c is named else named).name,
                             'against_moved_target': figures, 'passes': True}
            return Decision(None, [POSE_ERROR, named.name, other.name], pose=pose,
                            withheld=withheld)
        try:
            _, other_on_top, named_on_top = self.each_on_top(named, other)
        except Exception:  # noqa: BLE001 - not split: their tie
            other_on_top = named_on_top = (0.0, 0.0)
        outcome = power_incidence.pair_outcome(True, self.passes_rule(*other_on_top),
                                               self.passes_rule(*named_on_top))
        figures['outcome'] = 'pair_both' if outcome == power_incidence.BOTH else 'pair_tie'
        for c, on_top in ((named, named_on_top), (other, other_on_top)):
            c.jointly = {'with': (other if c is named else named).name,
                         'on_top': [_num(v) for v in on_top],
                         'against_moved_target': figures, 'passes': True}
        if outcome == power_incidence.BOTH:
            return Decision(named.name, [], other.name, withheld=withheld)
        return Decision(None, [named.name, other.name], withheld=withheld)

    def clock_off_footing(self, decision: Decision, cands: list[Candidate],
                          footing_test) -> Decision:
        """A named clock offset (``time_offset``) with the reference pose not reported,
        weighed against the per-cloud pose on the pose test's own rays and halves
        (``footing_test(effect)``: ``clock_footing.clock_on_pose_footing`` with the
        clock's effect; its figures on the clock's ``against_pose['pose_footing']``;
        None where the points carry no time within their cloud: no drift within it to
        weigh, the clock against a rigid pose is ``clock_tie``'s and ``rows_under_clock``'s).
        Where the clock does not pass the rule there, or the pose passes on top of it
        there, its gain lies on rays the pose test cannot weigh (grazing, beyond five
        sigma) or the pose does as well: a clock offset and a pose drifting within the
        cloud move a rigid target alike, so the two are a tie (``confounded_with``:
        pose_error and time_offset), not the clock."""
        if (decision.missing != beside.CLOCK or decision.pose is not None
                or decision.confounded_with or footing_test is None):
            return decision
        clock = next((c for c in cands if c.name == beside.CLOCK), None)
        if clock is None or clock.effect is None or not self.nameable(clock):
            return decision
        try:
            on = footing_test(clock.effect)
        except Exception:  # noqa: BLE001 - not weighed: the decision stands
            return decision
        clock.against_pose = {**(clock.against_pose or {}), 'pose_footing': on.as_dict()}
        if on.stands:
            return decision
        return Decision(None, [POSE_ERROR, beside.CLOCK], also=decision.also,
                        withheld=dict(decision.withheld))

    def clock_beside_constant_pose(self, decision: Decision, cands: list[Candidate],
                                   footing_test, pose_on_clock, nested=None
                                   ) -> tuple[Decision, Candidate | None]:
        """One rigid correction for the recording reported alone, nothing named, and a
        clock offset (``time_offset``) among the candidates: the two fitted jointly on
        the pose test's own rays and halves (``footing_test(effect)``:
        ``clock_footing.clock_on_pose_footing`` with the clock's effect and
        ``constant``, on the model the correction leaves, raycast again, where what is
        left of a pose off by centimetres is linear; on the recorded pose its remainder
        lent a clock a part of its own with no clock in the data; its figures on the
        clock's ``against_pose['constant_pose_footing']``; a part decisive but below the
        margin that matters is said in the verdict, not named).
        On a target turning about a moving axis (a spin on a tumble) a clock offset
        reads the attitude off by the spin times dt about the body's spin axis, which
        turns with the body: one rotation for the recording takes most of it, so the
        pose fitted alone reports a rotation the poses do not have, and the clock
        fitted alone fights the pose's offset (its dt off, its held-out gain even below
        zero) and is lost. The linear footing's part is only said: the decision is
        the nested test on the candidates' own raycast footing (``nested(effect,
        dt_joint)``: ``clock_nested``, the pose alone, the clock alone and both, raycast
        on the same points, the clock beside the correction profiled over dt from the
        linear joint fit's, the clock's alone times its column's scale; its figures
        under ``['nested']``). Where the clock's own part passes the rule there, the
        correction is fitted again on top of the clock at the profile's dt and raycast
        as --fit corrects it (``pose_on_clock(effect)``: the re-cast diagnosis without
        the clock, and the correction's report); the clock is scored again there (its
        fitted figures; the held-out gain quoted is its own part on the nested
        footing). It is named if it may be named there (``naming_fault`` on the re-cast
        diagnosis), with the correction reported beside it where the correction's own
        part passes on top of the clock there and its test on top of the clock passes
        too. Where each passes alone and neither on top of the other (and the clock is
        nameable alone): the tie [pose_error, time_offset]. Returns the decision and
        the clock as scored on the corrected pose (None: the decision stands). Where
        the clock has no part of its own (a clock and a constant pose on a target
        turning about a fixed axis are the same data; a pose alone), or no nested test
        is given, the decision stands.
        A tie of sensor effects beside the constant pose that the naming gate
        (``diagnosis.settle``) leaves none of is the pose alone here, as the verdict will
        give it (held-out clock_pose_spin seed 9: [incidence_angle, snr_noise], one
        withheld, the pose alone reported)."""
        pose = decision.pose
        if (not decision.missing and decision.confounded_with and nested is not None
                and POSE_ERROR not in decision.confounded_with):
            from lidar_sim_ros.compare.diagnose.diagnosis import settle
            gated = settle(decision, cands, self.naming_fault, self.tile_fault)
            if not gated.missing and not gated.confounded_with:
                named, _ = self.clock_beside_constant_pose(gated, cands, footing_test,
                                                           pose_on_clock, nested)
                return (decision, None) if named is gated else (named, _)
        if (decision.missing or decision.confounded_with or pose is None
                or not getattr(pose, 'constant', False) or footing_test is None
                or getattr(pose, 'rate_supported', False)):
            # A correction whose rate over the scan passed on top of it (a tracking lag
            # growing within each scan) is no constant offset a clock could stand for:
            # a clock offset makes no growth over the scan (``clock_footing``'s drift).
            return decision, None
        clock = _fitted_clock(cands)
        if clock is None:
            return decision, None
        try:
            on = footing_test(clock.effect)
        except Exception:  # noqa: BLE001 - not weighed: the decision stands
            return decision, None
        figures = on.as_dict()
        clock.against_pose = {**(clock.against_pose or {}), 'constant_pose_footing': figures}
        dt_alone = float(clock.effect.params.dt_s)
        dt_joint = float(on.clock_scale * dt_alone) if np.isfinite(on.clock_scale) else dt_alone
        figures.update(dt_alone_s=_num(dt_alone), dt_joint_s=_num(dt_joint))
        if nested is None:
            return decision, None
        try:
            nest = nested(clock.effect, dt_joint)
        except Exception:  # noqa: BLE001 - not weighed on the candidates' footing
            return decision, None
        figures['nested'] = nest.as_dict()
        return self.decided_by_nest(decision, clock, nest, figures, pose_on_clock)

    def clock_beside_per_cloud_pose(self, decision: Decision, cands: list[Candidate],
                                    nested, pose_on_clock
                                    ) -> tuple[Decision, Candidate | None]:
        """A correction per cloud reported alone (no rate over the scan), nothing named,
        and a clock offset (``time_offset``) among the candidates: on a target spinning
        about an axis that turns with a tumble, a clock offset reads each cloud's attitude
        off about a different lidar-frame axis, so the pose test takes it as a pose
        varying per cloud and the constant nested test (``clock_beside_constant_pose``)
        is never asked. Here ``nested(effect)`` (``clock_nested.PerCloudClock``) weighs
        the clock with one correction against the per-cloud correction on the same
        raycast points, each charged its parameters (6 x clouds against 7), beside the
        constant nested test. Its outcome 'clock': the clock named (``clock_named_beside``:
        the correction fitted again on top of it at the profile's dt, reported beside it
        where its own part passes); 'tie': [pose_error, time_offset] with the per-cloud
        pose (the clock nameable alone); else the decision stands. Figures on the clock's
        ``against_pose['constant_pose_footing']`` (``nested``, with ``per_cloud``)."""
        pose = decision.pose
        rival = _range_rival_tied(decision, cands)
        if (decision.missing or (decision.confounded_with and rival is None) or pose is None
                or nested is None or getattr(pose, 'constant', True)
                or getattr(pose, 'rate_supported', False)):
            return decision, None
        clock = _fitted_clock(cands)
        if clock is None:
            return decision, None
        try:
            nest = nested(clock.effect)
        except Exception:  # noqa: BLE001 - not weighed: the decision stands
            return decision, None
        figures = {'dt_alone_s': _num(float(clock.effect.params.dt_s)),
                   'dt_joint_s': _num(nest.nested.dt_beside_pose_s), 'per_cloud_pose': True,
                   'nested': nest.as_dict()}
        clock.against_pose = {**(clock.against_pose or {}), 'constant_pose_footing': figures}
        named, again = self.decided_by_nest(decision, clock, nest, figures, pose_on_clock,
                                            may_tie=rival is None)
        if rival is None or again is None:
            return named, again
        return self.range_rival_beside_clock(decision, named, again, rival, figures)

    def decided_by_nest(self, decision: Decision, clock: Candidate, nest, figures: dict,
                        pose_on_clock, may_tie: bool = True
                        ) -> tuple[Decision, Candidate | None]:
        """What a nested test (``nest``: ``clock_nested``'s ``NestedClock`` or
        ``PerCloudClock``) decides beside the reported pose: its outcome 'tie' the tie
        [pose_error, time_offset] with that pose (where the clock is nameable alone, which
        fits it on all the points if not done yet, and ``may_tie``), 'clock' the clock
        named (``clock_named_beside``), else the decision stands."""
        if nest.outcome == 'tie' and self.nameable(clock) and may_tie:
            return Decision(None, [POSE_ERROR, beside.CLOCK], withheld=dict(decision.withheld),
                            pose=decision.pose), None
        if nest.outcome != 'clock':
            return decision, None
        return self.clock_named_beside(decision, clock, nest, figures, pose_on_clock)

    def range_rival_beside_clock(self, decision: Decision, named: Decision,
                                 clock: Candidate, rival: Candidate, figures: dict
                                 ) -> tuple[Decision, Candidate | None]:
        """A pose per cloud tied with a range term of the sensor (``rival``: POSE_RIVALS)
        where the clock with one correction won over the per-cloud correction
        (``clock_beside_per_cloud_pose``): the range term scored again on the pose
        corrected beside the clock, on top of the clock there (``clock_on_pose``). The
        clock is named (``named``) only where the range term no longer passes the rule
        there (the clock and the pose took what it stood for); else the tie ``decision``
        stands. Its figures under ``figures['range_rival_beside_clock']``."""
        on_pose = self.clock_on_pose[0]
        try:
            again = on_pose.score(type(rival.effect))
            fault = on_pose.naming_fault(again)
        except Exception:  # noqa: BLE001 - not weighed: the tie stands
            self.clock_on_pose = None
            return decision, None
        figures['range_rival_beside_clock'] = {
            'name': rival.name, 'score': _num(again.score), 'z': _num(again.z),
            'passes': fault is None, **({'why_not': fault} if fault else {})}
        if fault is None:
            self.clock_on_pose = None
            return decision, None
        return named, clock

    def clock_named_beside(self, decision: Decision, clock: Candidate, nest, figures: dict,
                           pose_on_clock) -> tuple[Decision, Candidate | None]:
        """The clock whose own part passed a nested test (``nest``: ``clock_nested``'s
        ``NestedClock`` or ``PerCloudClock``) named, the correction beside it fitted
        again on top of the clock at the profile's dt (``pose_on_clock``) where its own
        part passes there too (``clock_beside_constant_pose``); the decision as it was
        where the clock may not be named on the corrected pose."""
        beside_pose = type(clock.effect)({'dt_s': float(nest.dt_beside_pose_s)})
        try:
            on_pose, report = pose_on_clock(beside_pose)
            again = on_pose.score(type(clock.effect))
            fault = on_pose.naming_fault(again)
        except Exception:  # noqa: BLE001 - not weighed on the corrected pose
            return decision, None
        figures.update(score_on_pose=_num(again.score), z_on_pose=_num(again.z),
                       dt_beside_pose_s=_num(nest.dt_beside_pose_s),
                       dt_rescored_on_pose_s=_num(getattr(again.effect.params, 'dt_s', None)
                                                  if again.effect is not None else None),
                       passes_on_pose=fault is None,
                       **({'why_not_on_pose': fault} if fault else {}))
        if fault is not None:
            return decision, None
        self.clock_on_pose = (on_pose, copy.copy(again))   # ``turn_beside_clock``
        # The held-out gain quoted is the clock's own part on top of the correction: its
        # score on a correction fitted beside the clock it assumed is not independent
        # (that correction leaves the clock's pose-shaped part for the clock to find).
        again.score = float(nest.clock_over_pose.gain)
        again.z = float(nest.clock_over_pose.z)
        again.against_pose = {**(again.against_pose or {}), 'constant_pose_footing': figures,
                              'recorded_pose': {'score': _num(clock.score),
                                                'z': _num(clock.z),
                                                'params': dict(clock.params or {})}}
        keep = nest.pose_over_clock.passes and bool(getattr(report, 'significant', False))
        return Decision(beside.CLOCK, [], also=None, withheld=dict(decision.withheld),
                        pose=report if keep else None), again

    def turn_beside_clock(self, cands: list[Candidate]) -> None:
        """Lasers' pointing set aside as mostly a common turn of every beam
        (``own_part_veto``) where a clock offset was named beside the pose
        (``clock_named_beside``): a pose offset across the line of sight and a clock's
        turn of the target are, seen from the sensor, a turn of every beam. The turn is
        fitted again on the pose corrected beside the clock, on top of the clock there
        (``pointing.SensorTurn``, cross-fitted); where it no longer passes the rule the
        reason given says that the clock and the pose take it (not a mount), with its
        figures under ``own_part['beside_clock']``. Where it still passes, the reason
        stands."""
        from lidar_sim_ros.compare.model import pointing
        held = getattr(self, 'clock_on_pose', None)
        lp = next((c for c in cands if c.vetoed and c.own_part and c.effect is not None
                   and pointing.turn_of(c.variant) is not None), None)
        if held is None or lp is None:
            return
        on_pose, clock = held
        if clock.effect is None or clock.heldout_nll is None:
            return
        try:
            turn = Candidate(lp.name)
            turn.effect = lp.effect
            nll, explained = on_pose.cross_fit(pointing.SensorTurn, [clock.effect])
            on_pose._set_gain(turn, nll, explained)
            gain, z = on_pose.paired(turn, clock)
        except Exception:  # noqa: BLE001 - not weighed: the reason stands
            return
        passes = on_pose.passes_rule(gain, z)
        lp.own_part = {**lp.own_part, 'beside_clock': {'score': _num(gain), 'z': _num(z),
                                                       'passes': passes}}
        if passes:
            return
        part = lp.own_part
        lp.vetoed = (f'its offsets are mostly a common turn of every beam (it gains '
                     f'{part["turn_score"]:.4f} nats/point held out on the recorded pose), '
                     f'which the clock offset and the reference pose correction named here '
                     f'take: seen from the sensor, a target moved across the line of sight '
                     f'or turned by a clock is a turn of every beam. On the pose corrected '
                     f'beside the clock, on top of the clock, that turn gains {gain:.4f} '
                     f'nats/point (z = {z:.1f}), which does not pass the rule; over the turn '
                     f'each laser\'s own part gains {part["score"]:.4f} nats/point '
                     f'(z = {part["z"]:.1f})')

    def clock_tie(self, decision: Decision, cands: list[Candidate],
                  no_point_times: bool) -> Decision:
        """Clouds without usable point times, the reference pose reported off and a
        ``time_offset`` that passed the rule before the pose correction: a clock offset
        moves each cloud as a rigid correction per cloud partly does, so the two are a
        tie (``confounded_with``: pose_error and time_offset), not a pose error."""
        if (not no_point_times or decision.pose is None or decision.missing
                or decision.confounded_with):
            return decision
        c = next((c for c in cands if c.name == 'time_offset'), None)
        if c is None or not self.nameable(c):
            return decision
        return replace(decision, confounded_with=[POSE_ERROR, c.name])
