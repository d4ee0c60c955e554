"""A named effect against a rival the rule keeps from naming, on the same part of the residual.

``Diagnosis.decide`` asks the named effect to be decisively better than every other
candidate that may be named. A candidate that may not be named (its held-out gain not
decisive across the neighbourhoods, or set aside by the share of the structure) is not
asked about, yet it may explain the very part the named one explains: beside per-laser
offsets at grazing incidence, a range walk on the received power and an incidence
elongation both follow the weak, grazing returns (``bench/walk_graze_eval.py`` s1:
the walk 0.0212 nats/point, z 2.7, incidence 0.0218, z 8.3, incidence named).

Such a rival (``rivals_of``: one parameter set for all lasers, a bias or noise effect,
its gain practical and at least MIN_TOTAL_GAIN in total, kept from naming by its z or its
share alone) that the named effect does not beat by decide's rule for two candidates is
weighed on top: each cross-fitted on the other, fitted together with the effects set aside
beside the named one (the lasers' offsets) on the same held-out folds (``outcome``):

* the named one passes the rule on top of the rival: it explains a part the rival does not,
  and stands;
* it does not, and the rival passes on top of it: the rival explains all the named one
  explains and more; the named one is withheld (the rival is not named by this: it is
  still kept by its own rule);
* neither passes on top of the other: the recording cannot tell them apart; the named one
  is withheld, and nothing is named (the rival may not be named, so no tie is stated).
"""
from __future__ import annotations

from typing import Callable

NAMED, RIVAL, TIE = 'named', 'rival', 'tie'


def rivals_of(best, cands: list, may_name: Callable, per_laser: Callable,
              bias_or_noise: Callable, min_share: float, min_total: float,
              n_total: int) -> list:
    """Candidates that may explain ``best``'s part but the rule keeps from naming: not
    ``best``, fitted without error, one parameter set for all lasers (``per_laser``
    False), a bias or noise effect (``bias_or_noise``), not nameable (``may_name``
    False), practical and at least ``min_total`` nats in all (``n_total`` points), and
    kept only by their z or by a share below ``min_share`` (no other veto). Ranked as
    given."""
    out = []
    for c in cands:
        if (c is best or c.error is not None or c.effect is None or c.variant is None
                or per_laser(c.effect) or not bias_or_noise(c.effect) or may_name(c)
                or not c.practical or c.score * n_total < min_total):
            continue
        share_only = c.vetoed is None or (c.share is not None and c.share < min_share
                                          and c.vetoed.startswith('it explains only'))
        if share_only:
            out.append(c)
    return out


def outcome(named_on_rival: tuple[float, float], rival_on_named: tuple[float, float] | None,
            passes: Callable[[float, float], bool]) -> str:
    """NAMED, RIVAL or TIE (module doc) from each one's held-out gain and z on top of the
    other (``passes``: the naming rule on a gain in nats/point and its z; the rival's
    figures are not needed where the named one passes)."""
    if passes(*named_on_rival):
        return NAMED
    if rival_on_named is not None and passes(*rival_on_named):
        return RIVAL
    return TIE


def withheld_words(named: str, rival, named_on_rival: tuple[float, float],
                   rival_on_named: tuple[float, float], kind: str, beside: list[str]) -> str:
    """Why ``named`` is withheld beside ``rival`` (a Candidate), in the fit's figures."""
    with_ = f' and {" and ".join(beside)}' if beside else ''
    fault = (f'set aside for its share: {rival.vetoed}' if rival.vetoed
             else f'its held-out gain alone, {rival.score:.4f} nats/point (z = {rival.z:.1f}), '
                  'is not decisive')
    head = (f'{rival.name} explains the same part of the residual: fitted on top of '
            f'{rival.name}{with_}, it gains {named_on_rival[0]:.4f} nats/point held out '
            f'(z = {named_on_rival[1]:.1f}), which does not pass the rule, ')
    if kind == RIVAL:
        return (head + f'while {rival.name} gains {rival_on_named[0]:.4f} (z = '
                f'{rival_on_named[1]:.1f}) on top of it: {rival.name} explains all it '
                f'explains and more ({rival.name} is not named: {fault})')
    return (head + f'and {rival.name} gains {rival_on_named[0]:.4f} (z = '
            f'{rival_on_named[1]:.1f}) on top of it, which does not pass either: this '
            f'recording cannot tell which of the two it is ({rival.name} is not named: '
            f'{fault})')
