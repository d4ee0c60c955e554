"""The sensor's range terms (POSE_RIVALS: a range scale, a range offset drifting over the
recording) weighed where the diagnosis would leave the residual's structure outside the
catalogue: nothing named, no tie, no candidate withheld, and the attribution finds a
dependence on the features (``Attribution.significant``).

They are no default candidates: a bias linear in range fits a part of any smooth pattern
across a target whose range follows its azimuth (an encoder error, a cyclic error of the
receiver). So one is named here only where it passes the rule of any candidate (vetoes,
``decide``) **and** explains most of what the features show: its held-out gain on the
matched points at least NAME_SHARE of the attribution's structure (``share_veto``'s
measure, "explains N % of the residual's dependence on X"). Below that, the larger part
of the structure has another shape than the range term, and the verdict stays "outside
the catalogue", saying what the range term was weighed at (``against_named[NAME]
['weighed_outside']``).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

from lidar_sim_ros.compare.diagnose.candidate import POSE_RIVALS, Candidate, Decision, _num

# Least share of the feature structure a range term weighed beside an empty decision
# explains to be named: "most" of it, more than any other shape could still hold. Chosen
# before any held-out run; the share veto's MIN_SHARE (0.25) is the floor for a candidate
# that passed the rule unaided.
NAME_SHARE = 0.5


def applies(decision: Decision, attribution) -> bool:
    """Whether the verdict would say "outside the catalogue": nothing named, no tie, no
    candidate withheld, a significant structure in the features."""
    return bool(decision.missing is None and not decision.confounded_with
                and not decision.withheld and attribution is not None
                and getattr(attribution, 'significant', False))


def figures(c: Candidate) -> dict:
    """What the verdict says of a range term weighed and not named."""
    return {'score': _num(c.score), 'z': _num(c.z), 'share': _num(c.share),
            'significant': bool(c.significant), 'vetoed': c.vetoed}


def weigh(diag, decision: Decision, cands: list[Candidate], rivals: list,
          attribution, rank: Callable) -> tuple[Decision, list[Candidate]]:
    """The range terms among ``rivals`` scored with the vetoes and ``decide`` run again
    among all: the decision names one only where it is the one decided (alone, no tie)
    and its share of the structure is at least NAME_SHARE; then the scored terms are
    returned as candidates. Otherwise the decision is left and each range term's gain,
    z and share are kept in ``pair_z[NAME]['weighed_outside']`` (none returned)."""
    ranged = [r for r in rivals if r.name in POSE_RIVALS]
    if not ranged or not applies(decision, attribution):
        return decision, []
    scored = diag.scored_with_vetoes(ranged, attribution)
    again = diag.decide(rank([*cands, *scored]))
    named = next((c for c in scored if c.name == again.missing), None)
    if (named is not None and not again.confounded_with and named.share is not None
            and named.share >= NAME_SHARE):
        return replace(decision, missing=again.missing, confounded_with=[],
                       also=again.also, pair_z=again.pair_z), scored
    pair_z = dict(decision.pair_z)
    for c in scored:
        if c.error is None:
            pair_z[c.name] = {**pair_z.get(c.name, {}), 'weighed_outside': figures(c)}
    return replace(decision, pair_z=pair_z), []


def words(summary: dict) -> str:
    """The verdict's sentence on the range terms weighed beside an empty decision (or '')."""
    parts = []
    for name, w in (summary.get('against_named') or {}).items():
        f = w.get('weighed_outside') if isinstance(w, dict) else None
        if not f or f.get('score') is None:
            continue
        share = f.get('share')
        what = (f', {100 * share:.0f} % of the residual\'s dependence on the features'
                if share is not None else f'; set aside: {f["vetoed"]}' if f.get('vetoed')
                else '')
        parts.append(f'{name} {f["score"]:.4f} nats/point held out (z = {f["z"]:.1f}{what})')
    if not parts:
        return ''
    return (' The range terms of the sensor, no default candidates, were weighed too: '
            + '; '.join(parts) + '. None is named: one is named here only where it passes '
            f'the rule and explains at least {100 * NAME_SHARE:.0f} % of that dependence.')
