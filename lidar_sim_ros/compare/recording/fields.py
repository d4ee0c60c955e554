"""Which fields of a measured PointCloud2 mean what: intensity, point time, laser, flags.

Every driver names its fields its own way. ``resolve_fields`` reads the field list of
the first cloud and decides, once for the recording, which field is

* the intensity: ``--intensity-field``, else ``intensity`` or ``reflectivity`` (the
  Cepton SDK2 driver's name);
* the point time: ``--time-field`` (one field, or ``SECONDS,SUBSECONDS``, or ``none``),
  else the Cepton SDK3 pair ``timestamp_s`` + ``timestamp_us``, else one of
  ``measurements.POINT_TIME_FIELDS``. A pair is read as integer nanoseconds,
  seconds x 1e9 + sub-seconds x their unit (``_ms``/``_us``/``_ns`` suffix of the
  second name, else from its largest value), exactly, whatever the clock. So a pair
  must be integers (``check_time_pair``): the seconds at least 32 bits (an epoch
  clock), the sub-seconds wide enough for their unit (999,999 us needs 32 bits);
  FLOAT32 or UINT8 members are refused, and so is a sub-seconds value outside
  [0, one second) (``point_time_ns``): the layout is misread;
* the laser: ``--laser-field``, else ``ring``, ``channel_id``, ``channel``, ``laser``,
  ``laser_id``, ``line``;
* the Cepton point flags (``io/cepton.py``): ``flags`` in a recording with the Cepton
  layout (``channel_id`` present; its SECOND_RETURN bit marks a later return of a
  shot); the SDK2 driver's ``valid`` (0: not a return);
* the return index of a multi-return receiver: one of ``RETURN_FIELDS`` (ours and
  LAS-style ``return_number`` count from 1, others from 0: the recording's smallest
  index is its first return, ``multiple_returns.py``). Nebula's ``return_type`` is an
  echo *type* (first, last, strongest ... as an enum), not an index: listed as ignored.

Everything else is listed as ignored. ``FieldMap.lines()`` is what the terminal
prints: every field recognised, converted or ignored, with its datatype.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidar_sim_ros.io import cepton

INTENSITY_FIELDS = ('intensity', 'reflectivity')
LASER_FIELDS = ('ring', 'channel_id', 'channel', 'laser', 'laser_id', 'line')
# The return (echo) index of a multi-return receiver, matched case-insensitively in this
# order: ours (1 = the first) and holdout labs' ``return``, LAS/laspy ``return_number``
# (1-based), and the index spellings of other drivers.
RETURN_FIELDS = ('return', 'return_number', 'return_index', 'return_idx', 'return_id',
                 'return_num', 'returnnum', 'echo', 'echo_index', 'echo_id', 'echo_num')
CEPTON_TIME_PAIR = ('timestamp_s', 'timestamp_us')
_SUB_UNITS = {'_ms': 1_000_000, '_us': 1_000, '_ns': 1}
# One second less one tick, in each sub-seconds unit: the largest value a member can hold.
_SUB_MAX = {'_ms': 999, '_us': 999_999, '_ns': 999_999_999}
# Fields known to carry nothing the comparison needs (the measured x, y, z decide).
KNOWN_UNUSED = {'azimuth': 'the direction is taken from x, y, z',
                'elevation': 'the direction is taken from x, y, z',
                'range': 'the range is taken from |x, y, z|',
                'relative_timestamp': 'a narrow counter, not a time since the stamp',
                'return_type': 'an echo type (an enum: first, last, strongest...), not a '
                               'return index; shots\' later returns are found by shared '
                               'point times'}


class FieldError(ValueError):
    """A named field is missing or cannot carry what it was named for."""


@dataclass(frozen=True)
class FieldMap:
    """The recording's fields and what each is used for (module doc)."""

    intensity: str | None
    time: tuple[str, ...]                # () none, (name,) one field, (seconds, sub) a pair
    laser: str | None
    flags: str | None                    # Cepton point flags
    valid: str | None                    # SDK2 valid byte
    dtypes: dict[str, str]
    ignored: dict[str, str] = field(default_factory=dict)
    layout: str = 'generic'              # 'native', 'cepton sdk3', 'cepton sdk2' or 'generic'
    returns: str | None = None           # the return index of a multi-return receiver

    @property
    def time_name(self) -> str | None:
        """The time field's name for the summary (``a+b`` for a pair)."""
        return '+'.join(self.time) if self.time else None

    def lines(self) -> list[str]:
        """One line per field: what it was recognised as and how it is read."""
        out = [f'point layout: {self.layout}']
        for name in ('x', 'y', 'z'):
            out.append(f'  {name} ({self.dtypes[name]}): position, m')
        if self.intensity:
            out.append(f'  {self.intensity} ({self.dtypes[self.intensity]}): intensity '
                       '(converted to received power by the intensity calibration)')
        if len(self.time) == 1:
            out.append(f'  {self.time[0]} ({self.dtypes[self.time[0]]}): point time '
                       '(unit and reference from the name, type and magnitude)')
        elif len(self.time) == 2:
            s, sub = self.time
            out.append(f'  {s} ({self.dtypes[s]}) + {sub} ({self.dtypes[sub]}): point time, '
                       'seconds + sub-seconds, read as integer nanoseconds')
        if self.laser:
            out.append(f'  {self.laser} ({self.dtypes[self.laser]}): laser id')
        if self.flags:
            out.append(f'  {self.flags} ({self.dtypes[self.flags]}): Cepton point flags '
                       '(SATURATED, NO_RETURN, NOISE, BLOCKED counted; NO_RETURN points are '
                       'known misses, not points)')
        if self.valid:
            out.append(f'  {self.valid} ({self.dtypes[self.valid]}): points with 0 dropped')
        if self.returns:
            out.append(f'  {self.returns} ({self.dtypes[self.returns]}): return index of a '
                       'multi-return receiver (a shot\'s later returns are left out of the fit)')
        for name, why in self.ignored.items():
            out.append(f'  {name} ({self.dtypes.get(name, "?")}): ignored ({why})')
        return out

    def as_dict(self) -> dict:
        return {'layout': self.layout, 'intensity': self.intensity, 'time': list(self.time),
                'laser': self.laser, 'flags': self.flags, 'valid': self.valid,
                'returns': self.returns,
                'ignored': dict(self.ignored), 'dtypes': dict(self.dtypes)}


def resolve_fields(dtype: np.dtype, intensity_field: str | None = None,
                   time_field: str | None = None, laser_field: str | None = None,
                   find_time=None) -> FieldMap:
    """The FieldMap of a decoded cloud's dtype (module doc). ``find_time``: the single-field
    time finder (``measurements.find_time_field``). Raises FieldError for a named field
    that is not there or not numeric, naming the fields present."""
    names = list(dtype.names or ())
    dtypes = {n: _kind(dtype[n]) for n in names}

    def named(option: str, value: str) -> str:
        if value not in names:
            raise FieldError(f'{option} {value!r}: no such field; fields present: {names}')
        if dtype[value].kind not in 'iuf':
            raise FieldError(f'{option} {value!r} has dtype {dtype[value]}, expected a number')
        return value

    if intensity_field:
        inten = named('--intensity-field', intensity_field)
    else:
        inten = next((n for n in INTENSITY_FIELDS if n in names), None)
    if time_field and time_field.strip().lower() == 'none':
        times = ()
    elif time_field:
        parts = tuple(p.strip() for p in time_field.split(','))
        if len(parts) > 2 or not all(parts):
            raise FieldError(f'--time-field {time_field!r}: give one field, SECONDS,SUBSECONDS '
                             'or none')
        times = tuple(named('--time-field', p) for p in parts)
        if len(times) == 2:
            check_time_pair(dtype, times, f'--time-field {time_field!r}')
    elif all(n in names for n in CEPTON_TIME_PAIR):
        times = CEPTON_TIME_PAIR
        check_time_pair(dtype, times, 'the Cepton time pair',
                        ' (name another time field with --time-field, or --time-field none)')
    else:
        single = find_time(names) if find_time is not None else None
        times = (single,) if single else ()
    laser = (named('--laser-field', laser_field) if laser_field
             else next((n for n in LASER_FIELDS if n in names), None))
    is_cepton = 'channel_id' in names
    flags = 'flags' if is_cepton and 'flags' in names and dtype['flags'].kind in 'iu' else None
    valid = 'valid' if 'valid' in names and dtype['valid'].kind in 'iu' else None
    by_lower = {n.lower(): n for n in names}
    returns = next((by_lower[n] for n in RETURN_FIELDS if n in by_lower
                    and dtype[by_lower[n]].kind in 'iuf'), None)
    used = {'x', 'y', 'z', inten, laser, flags, valid, returns, *times}
    ignored = {n: KNOWN_UNUSED.get(n, 'not used by the comparison') for n in names
               if n not in used}
    if names[:3] == ['x', 'y', 'z'] and {'t', 'ring', 'material'} <= set(names):
        layout = 'native (lidar_sim_ros)'
    elif is_cepton and times == CEPTON_TIME_PAIR:
        layout = 'cepton sdk3 driver'
    elif is_cepton and 'reflectivity' in names:
        layout = 'cepton sdk2 driver'
    else:
        layout = 'generic'
    if 'material' in ignored:
        ignored['material'] = 'the model casts the mesh itself'
    return FieldMap(inten, times, laser, flags, valid, dtypes, ignored, layout, returns)


def check_time_pair(dtype: np.dtype, pair: tuple[str, str], what: str,
                    hint: str = '') -> None:
    """A seconds + sub-seconds pair is read as exact integer nanoseconds: both members
    integers, the seconds at least 32 bits (an epoch clock), the sub-seconds able to hold
    their unit's largest value (``_SUB_MAX``; no unit suffix: at least 999 ms). FieldError
    naming the member and its datatype otherwise (FLOAT32 seconds are 128 s steps at
    epoch 1.7e9; UINT8 microseconds wrap every 256 us)."""
    s_name, sub_name = pair
    for name in pair:
        if dtype[name].kind not in 'iu':
            raise FieldError(f'{what}: {name} is {_kind(dtype[name])}; a seconds + sub-seconds '
                             'pair is read as exact integer nanoseconds, so both must be '
                             f'integers (the Cepton driver: INT32){hint}')
    if dtype[s_name].itemsize < 4:
        raise FieldError(f'{what}: {s_name} is {_kind(dtype[s_name])}, too narrow for a clock '
                         f'in seconds (INT32 or wider){hint}')
    suffix = _sub_suffix(sub_name) or '_ms'
    if np.iinfo(dtype[sub_name]).max < _SUB_MAX[suffix]:
        raise FieldError(f'{what}: {sub_name} is {_kind(dtype[sub_name])}, which cannot hold '
                         f'{_SUB_MAX[suffix]:,} {suffix[1:]} (INT32 or wider){hint}')


MAX_RETURN_INDEX = 15
"""The largest return index read as one: LAS 1.4 gives a pulse at most 15 returns
(4 bits); a larger index is a misread field, refused."""


def return_indices(values: np.ndarray, name: str) -> np.ndarray:
    """One cloud's return-index field as int64, each a whole number in [0,
    MAX_RETURN_INDEX]; FieldError naming the field and the first bad value otherwise
    (negative, fractional, NaN or larger: the field is not a return index)."""
    v = np.asarray(values)
    if v.dtype.kind == 'f':
        with np.errstate(invalid='ignore'):
            bad = ~np.isfinite(v) | (v != np.round(v)) | (np.abs(v) > MAX_RETURN_INDEX)
        ids = np.where(bad, -1, v).astype(np.int64)
    else:
        bad = np.zeros(len(v), bool)
        ids = v.astype(np.int64)
    bad |= (ids < 0) | (ids > MAX_RETURN_INDEX)
    if bad.any():
        raise FieldError(f'return field {name!r} = {v[bad][0]} ({int(bad.sum())} point(s)): a '
                         f'return index is a whole number in [0, {MAX_RETURN_INDEX}] (the '
                         'first return 0 or 1); is the field layout right?')
    return ids


def _sub_suffix(name: str) -> str | None:
    return next((k for k in _SUB_UNITS if name.lower().endswith(k)), None)


def point_time_ns(points: np.ndarray, pair: tuple[str, str]) -> tuple[np.ndarray, str]:
    """A seconds + sub-seconds pair as integer nanoseconds (exact), and the sub-seconds'
    unit (``'us'``...): from the second name's suffix, else its largest value (below 1e3
    ms, below 1e6 us, else ns). A sub-seconds value outside [0, one second) raises
    FieldError naming the field and the value (``timestamp_us`` = 2e9 is no time)."""
    s_name, sub_name = pair
    sec = np.asarray(points[s_name]).astype(np.int64)
    sub = np.asarray(points[sub_name]).astype(np.int64)
    suffix = _sub_suffix(sub_name)
    if suffix is None:
        top = int(np.abs(sub).max()) if len(sub) else 0
        suffix = '_ms' if top < 1_000 else '_us' if top < 1_000_000 else '_ns'
    bad = (sub < 0) | (sub > _SUB_MAX[suffix])
    if bad.any():
        raise FieldError(f'{sub_name} = {int(sub[bad][0])} ({int(bad.sum())} point(s)): sub-seconds '
                         f'in {suffix[1:]} must lie in [0, {_SUB_MAX[suffix]:,}]; is the field '
                         'layout right?')
    return sec * 1_000_000_000 + sub * _SUB_UNITS[suffix], suffix[1:]


def flag_counts(flags: np.ndarray) -> dict[str, int]:
    """How many points carry each Cepton flag (only the flags seen)."""
    f = np.asarray(flags, np.int64)
    return {name: int(np.count_nonzero(f & bit)) for name, bit in cepton.FLAGS.items()
            if np.any(f & bit)}


def _kind(dt: np.dtype) -> str:
    base = {'f4': 'FLOAT32', 'f8': 'FLOAT64', 'i1': 'INT8', 'u1': 'UINT8', 'i2': 'INT16',
            'u2': 'UINT16', 'i4': 'INT32', 'u4': 'UINT32'}
    return base.get(dt.base.str[1:], str(dt))


def range_exponents(field_map: dict | None) -> tuple[float, ...]:
    """The intensity readings ``intensity.calibrate_intensity`` may choose from: the
    Cepton drivers publish a range-compensated reflectivity (-2 only); any other layout
    lets the data decide (0 or -2)."""
    from lidar_sim_ros.compare.recording.intensity import RANGE_EXPONENTS
    layout = (field_map or {}).get('layout', '')
    return (-2.0,) if layout.startswith('cepton') else RANGE_EXPONENTS


def slope_known(field_map: dict | None) -> bool:
    """Whether the layout says the intensity is proportional to P r^2 (the Cepton drivers'
    reflectivity), so ``intensity.calibrate_intensity`` holds the slope of ln I at 1."""
    return (field_map or {}).get('layout', '').startswith('cepton')


def flag_lines(fmap: FieldMap, counts: dict[str, int], no_return: int,
               invalid: int) -> list[str]:
    """Terminal lines: the Cepton flags seen, the known misses, NOISE/BLOCKED kept, and
    the points dropped for ``valid`` = 0."""
    lines = []
    if fmap.flags:
        seen = ', '.join(f'{k} {v}' for k, v in counts.items()) or 'none set'
        lines.append(f'  flags seen: {seen}')
        if no_return:
            lines.append(f'  {no_return} NO_RETURN shots: known misses (fired, nothing came back)')
        if counts.get('NOISE') or counts.get('BLOCKED'):
            lines.append(f'  NOISE {counts.get("NOISE", 0)}, BLOCKED {counts.get("BLOCKED", 0)} '
                         'points kept as measured (the driver marked them; the false-return '
                         'candidates see them)')
    if fmap.valid and invalid:
        lines.append(f'  {invalid} points with {fmap.valid} = 0 dropped')
    return lines


def intensity_reading(calibration: dict | None, field_name: str | None,
                      known: bool = False) -> str:
    """One terminal line: how the intensity was read (proportional to the received power,
    a range-compensated reflectivity: ``intensity.py``'s range exponent 0 or -2, or log
    counts: its scale test),
    ``known`` from the layout or detected from the data."""
    if field_name is None:
        return 'intensity: none in the recording (the model\'s power drives power effects)'
    if calibration is None:
        return f'intensity ({field_name}): too few matched points to calibrate'
    test = calibration.get('scale_test') or {}
    lever = calibration.get('counts_per_efold') or {}
    if calibration.get('intensity_scale') == 'log':
        kind = (f'log counts, a + b ln P (b {test.get("log_b_per_efold", float("nan")):.3g} '
                'per e-fold of power; against a power law: unexplained '
                f'{test.get("unexplained_log", 0):.3g} vs {test.get("unexplained_linear", 0):.3g} '
                'in ln P), no range compensation; the power read '
                + ('as exp((I - a) / b)' if test.get('read_through') == 'log'
                   else 'through the monotone map (it fits the model\'s power better)'))
        if test.get('read_through') == 'range':
            kind = (f'log counts, a + b ln P (b {lever["per_efold"]:.3g} +- {lever["se"]:.2g} per '
                    'e-fold of power from the range within one material and incidence; '
                    f'{lever["fitted_on_model"]:.3g} fitted on the model\'s power, whose '
                    'reflectance law spans another range of power), no range compensation; '
                    'the power read as exp((I - a) / b)')
    elif calibration.get('range_exponent', 0.0) < -1.0:
        kind = 'a range-compensated reflectivity (~ P r^2)'
        if calibration.get('unit_slope'):
            kind += ', the slope of ln I held at 1'
    else:
        kind = 'grows with the received power (no range compensation detected)'
        if calibration.get('intensity_scale') == 'linear':
            kind += (f'; a power law of it (P^{test.get("power_law_exponent", 1.0):.3g}), '
                     'not log counts')
    if lever.get('log_shape_from') and not lever.get('used'):
        off = 100.0 * (lever['fitted_on_model'] / lever['per_efold'] - 1.0)
        kind += ('; the range within one material and incidence ' +
                 ('gives b ' if calibration.get('intensity_scale') == 'log'
                  else 'reads log counts, b ')
                 + f'{lever["per_efold"]:.3g} +- {lever["se"]:.2g}'
                 + (f' (the fit on the model\'s power {off:+.0f} % from it, short of the '
                    'margin to replace it)' if lever.get('pinned') else ', too loose to read'))
    kind += ' (as the layout says)' if known else ' (detected from the data)'
    use = ('used for power-driven effects' if calibration.get('used_for_power_driven_effects')
           else 'not used: it explains too little of the model\'s power')
    gain = calibration.get('cloud_gain') or {}
    if gain.get('used'):
        use += (f'; scaled per cloud (a gain control: sd {gain["log_gain_sd"]:.2f} in ln over '
                f'{gain["clouds"]} clouds, taken out)')
    return (f'intensity ({field_name}): read as {kind}; explains '
            f'{100 * calibration.get("power_explained", 0.0):.0f} % of the model\'s ln power, {use}')


def saturation_evidence(saturated: np.ndarray | None, model_power_w: np.ndarray,
                        saturation_power_w: float) -> dict | None:
    """What the SATURATED returns say about the saturation level: the model's received
    power on the matched saturated and unsaturated returns against the configured level.
    ``saturated`` and ``model_power_w`` are over the matched points (None: no flags)."""
    if saturated is None:
        return None
    sat = np.asarray(saturated, bool)
    p = np.asarray(model_power_w, float)
    out = {'points': int(sat.sum()), 'configured_saturation_power_w': float(saturation_power_w)}
    if sat.any():
        out['model_power_w_saturated_p5_p50'] = [float(x) for x in np.percentile(p[sat], [5, 50])]
        out['saturated_below_configured'] = float(np.mean(p[sat] < saturation_power_w))
    if (~sat).any():
        out['model_power_w_unsaturated_p95'] = float(np.percentile(p[~sat], 95))
        out['unsaturated_above_configured'] = float(np.mean(p[~sat] >= saturation_power_w))
    return out


def saturation_line(ev: dict | None) -> str | None:
    """The terminal line of ``saturation_evidence``."""
    if not ev or not ev['points']:
        return None if not ev else 'saturation: no matched return is flagged SATURATED'
    below = ev.get('saturated_below_configured', 0.0)
    return (f'saturation: {ev["points"]} matched returns flagged SATURATED, model power median '
            f'{ev["model_power_w_saturated_p5_p50"][1]:.3g} W; {100 * below:.0f} % of them below '
            f'the configured {ev["configured_saturation_power_w"]:.3g} W'
            + (' (the sensor saturates earlier than configured)' if below > 0.5 else ''))
