"""Which recording would separate a tie: the separation plan (``plan.yaml``).

When two candidates are confounded in a recording (``Decision.confounded_with``: each
explains the data, neither by a margin that matters as --fit leaves them), the
question is which other recording would tell them apart. Each tied candidate is a
hypothesis: the model with that effect at its fitted parameters and the materials as
--fit would leave them with it (each material's bias and sigma refit on top of the
effect, ``materials_under``). For a few candidate recordings derived from the one
compared (``candidate_recordings``: the recording itself; where a time offset is tied,
the target held still or tumbling twice as fast; approaching from twice to half the
distance within one recording; turned so that other incidence angles and faces meet
the beam; at half and twice the distance), both hypotheses are flown through the
core simulator (``Simulator.simulate_frame``, no second physics) and each simulated
recording is diagnosed as ``lidar-sim compare`` would diagnose it
(``diagnosis.Diagnosis``: both candidates cross-fitted on halves, each material's
offset and sigma scale profiled). The expected separation of a recording is the
paired held-out margin of the true hypothesis over the other on its own data, nats per
point (``Diagnosis.paired``), the smaller of the two ways (A's data: A over B; B's
data: B over A), and its z with the points compare would diagnose in that recording
(at most ``DIAGNOSIS_MAX_MATCHED``; the z of the bounded sample scaled by the square
root of the point counts). A recording separates the pair when both ways the margin is
at least the practical margin and the z at least the decision bound: then compare,
run on it, would name the true one.

Costs stay bounded: SIM_FRAMES frames per recording and hypothesis (more, up to
MAX_SIM_FRAMES, when they hold fewer than SAMPLE_POINTS points), at most SAMPLE_POINTS
points of them diagnosed (SAMPLE_POINTS_CAST for an effect that casts its own rays),
the second way not flown when the first fails, and no further recording once one
separates the pair by ENOUGH_Z times the bound; power-driven effects read the model's power
(the simulated intensity is the model's own, so no calibration is needed).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose import diagnosis, fit_data
from lidar_sim_ros.compare.model import likelihood as lk, materials as mat, neighbours
from lidar_sim_ros.compare.model.matching import Model, match
from lidar_sim_ros.compare.recording.measurements import Measurements
from lidar_sim_ros.core.config import MaterialsConfig
from lidar_sim_ros.core.effects import Effect
from lidar_sim_ros.core.pose import PoseSource, ScenarioTrajectory

SIM_FRAMES = 2            # frames simulated per candidate recording and hypothesis, ...
MAX_SIM_FRAMES = 12       # ... or more, up to this, until they hold SAMPLE_POINTS
SAMPLE_POINTS = 4000      # points of them diagnosed (the z is scaled to the recording's)
# ... and for a tie with an effect that casts rays of its own (a beam footprint, ghosts:
# each fit trial re-casts every ray), fewer: its fits cost ~10 times more per point.
SAMPLE_POINTS_CAST = 1500
# Once a recording separates the pair with this many times the decision bound in z, the
# candidates after it are not flown (the table lists those flown).
ENOUGH_Z = 1.5
DISTANCE_FACTORS = (0.5, 2.0)
TURN_DEG = 60.0           # the target turned about the lidar's z and y axes by this much
TUMBLE_FACTOR = 2.0       # "tumbling faster": this many times the recorded rate
# "Approach": from the farthest to the nearest of DISTANCE_FACTORS within one recording of
# APPROACH_S s, so the range (and the power) vary within it: a per-material offset cannot
# take up what changes with the distance, as it does between recordings.
APPROACH_S = 10.0


@dataclass(frozen=True)
class Recording:
    """A candidate recording as a scenario's trajectory: the target's pose at the start
    (lidar frame; ``position_m`` m, ``quat_xyzw``), closing speed along the initial line
    of sight (m/s), tumble about a lidar-frame axis (deg/s), and its length (frames of
    ``period_s`` s)."""

    label: str
    what: str
    position_m: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]
    approach_speed_mps: float
    tumble_axis: tuple[float, float, float]
    tumble_rate_dps: float
    frames: int
    period_s: float

    def trajectory(self) -> ScenarioTrajectory:
        axis = np.asarray(self.tumble_axis, float)
        return ScenarioTrajectory(np.asarray(self.position_m, float),
                                  Rotation.from_quat(self.quat_xyzw), self.approach_speed_mps,
                                  axis / np.linalg.norm(axis), np.radians(self.tumble_rate_dps))

    @property
    def duration_s(self) -> float:
        return self.frames * self.period_s

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(self.position_m))

    def scenario_keys(self) -> dict:
        """The scenario's ``initial_pose`` and ``motion`` sections."""
        return {'initial_pose': {'position_m': [round(float(x), 4) for x in self.position_m],
                                 'quat_xyzw': [round(float(x), 6) for x in self.quat_xyzw]},
                'motion': {'approach_speed_mps': round(float(self.approach_speed_mps), 5),
                           'tumble_axis': [round(float(x), 5) for x in self.tumble_axis],
                           'tumble_rate_dps': round(float(self.tumble_rate_dps), 4)}}


def recorded_motion(poses: PoseSource, t_start_s: float, t_end_s: float, period_s: float,
                    pose_times_s: np.ndarray | None = None) -> Recording:
    """The recording's own motion as a scenario trajectory: its pose at the start, the
    mean closing speed (m/s, from the distance at start and end) and the mean angular
    velocity (the rotation increments between pose samples summed, lidar frame)."""
    t0, t1 = float(t_start_s), float(max(t_end_s, t_start_s))
    if hasattr(poses, 'start_s'):      # a PoseTrack: stay within what it answers
        t0 = max(t0, poses.start_s)
        t1 = max(min(t1, poses.end_s + poses.max_extrapolation_s), t0)
    ts = np.unique(np.concatenate([[t0, t1], [] if pose_times_s is None else
                                   np.asarray(pose_times_s, float)]))
    ts = ts[(ts >= t0) & (ts <= t1)]
    p = poses.at(ts)
    rot = p.rotation
    pos = np.asarray(p.position_m, float).reshape(-1, 3)
    span = t1 - t0
    if len(ts) > 1 and span > 0:
        steps = (rot[1:] * rot[:-1].inv()).as_rotvec()
        w = steps.sum(axis=0) / span
        speed = (np.linalg.norm(pos[0]) - np.linalg.norm(pos[-1])) / span
    else:
        w, speed = np.zeros(3), 0.0
    rate = float(np.linalg.norm(w))
    axis = tuple(w / rate) if rate > 1e-12 else (0.0, 0.0, 1.0)
    frames = max(int(round(span / period_s)), 1)
    return Recording('this recording', 'the recording compared, flown again', tuple(pos[0]),
                     tuple(rot[0].as_quat()), float(speed), axis, float(np.degrees(rate)),
                     frames, period_s)


def candidate_recordings(rec: Recording, names: list[str]) -> list[Recording]:
    """Recordings that vary what drives each tied candidate (``verdict.DRIVEN_BY``), in
    the order they are flown: the recording itself; where a time offset is tied, held
    still or tumbling faster (the offset acts through the motion only); approaching from
    the farther to the nearer distance within one recording (APPROACH_S); turned (other
    incidence angles and faces at the same distance); at other distances (power at the
    same incidence; footprint size)."""
    out = [rec]
    if 'time_offset' in names:
        out.append(replace(rec, label='static', what='the target held still (no tumble, no '
                           'approach)', approach_speed_mps=0.0, tumble_rate_dps=0.0))
        out.append(replace(rec, label=f'{TUMBLE_FACTOR:g}x the tumble rate',
                           what=f'the target tumbling {TUMBLE_FACTOR:g} x as fast '
                                f'({TUMBLE_FACTOR * rec.tumble_rate_dps:.2g} deg/s)',
                           tumble_rate_dps=TUMBLE_FACTOR * rec.tumble_rate_dps))
    near, far = min(DISTANCE_FACTORS), max(DISTANCE_FACTORS)
    frames = max(int(round(APPROACH_S / rec.period_s)), 1)
    speed = (far - near) * rec.distance_m / (frames * rec.period_s)
    out.append(replace(rec, label=f'approach {far:g}x to {near:g}x',
                       what=f'the target approaching from {far * rec.distance_m:.1f} m to '
                            f'{near * rec.distance_m:.1f} m in {frames * rec.period_s:g} s '
                            f'({speed:.2g} m/s), same attitude and tumble: the range varies '
                            'within the recording',
                       position_m=tuple(far * np.asarray(rec.position_m)),
                       approach_speed_mps=speed, frames=frames))
    for axis_name, axis in (('z', (0.0, 0.0, 1.0)), ('y', (0.0, 1.0, 0.0))):
        turn = Rotation.from_rotvec(np.radians(TURN_DEG) * np.asarray(axis))
        out.append(replace(rec, label=f'turned {TURN_DEG:g} deg about {axis_name}',
                           what=f'the target turned {TURN_DEG:g} deg about the lidar {axis_name} '
                                'axis (about its own centre): other incidence angles and faces '
                                'at the same distance',
                           quat_xyzw=tuple((turn * Rotation.from_quat(rec.quat_xyzw)).as_quat())))
    for f in DISTANCE_FACTORS:
        word = 'closer' if f < 1 else 'farther'
        out.append(replace(rec, label=f'{f:g}x the distance',
                           what=f'the target {word}: {f:g} x {rec.distance_m:.1f} m, same '
                                'attitude and motion',
                           position_m=tuple(f * np.asarray(rec.position_m)),
                           approach_speed_mps=f * rec.approach_speed_mps))
    return out


def simulate_measurements(model: Model, materials: MaterialsConfig, effects: list[Effect],
                          rec: Recording, seed: int, first_frame: int = 0,
                          max_points: int = SAMPLE_POINTS) -> tuple[Measurements, int]:
    """Fly ``rec`` with the core simulator (``model``'s sensor and target, ``materials``,
    ``effects``): SIM_FRAMES frames spread over the recording (more, up to
    MAX_SIM_FRAMES, until they hold SAMPLE_POINTS points), at most SAMPLE_POINTS of
    their points (seeded draw), as Measurements; and the number of
    points the whole recording would hold (points per simulated frame x frames)."""
    sim = replace(model, sun=None).simulator(materials=materials, effects=effects)
    traj = rec.trajectory()
    first = sim.simulate_frame(0.0, traj, first_frame)
    # Enough frames for the sample (a far target gives few points per frame: a fit on a
    # few hundred points is not what compare would see), spread over the recording.
    wanted = max(SIM_FRAMES, int(np.ceil(max_points / max(len(first), 1))))
    pick = np.unique(np.round(np.linspace(0, rec.frames - 1,
                                          min(rec.frames, wanted, MAX_SIM_FRAMES))))
    frames = [first] + [sim.simulate_frame(float(k) * rec.period_s, traj, first_frame + int(k))
                        for k in pick.astype(int) if k > 0]
    n_per_frame = float(np.mean([len(f) for f in frames]))
    cloud = np.concatenate([np.full(len(f), i) for i, f in enumerate(frames)])
    xyz = np.concatenate([f.xyz_m for f in frames])
    t_frame = np.concatenate([f.t_s for f in frames])
    stamps = np.array([f.stamp_s for f in frames])
    keep = np.arange(len(xyz))
    if len(keep) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(keep, max_points, replace=False))
    rng_m = np.linalg.norm(xyz, axis=1)
    meas = Measurements(
        bag=Path(f'plan:{rec.label}'), xyz_m=xyz[keep], range_m=rng_m[keep],
        directions=xyz[keep] / np.maximum(rng_m[keep], 1e-12)[:, None],
        intensity=np.concatenate([f.intensity for f in frames])[keep],
        t_s=(stamps[cloud] + t_frame)[keep], t_frame_s=t_frame[keep], cloud=cloud[keep],
        laser=np.concatenate([f.ring for f in frames])[keep], has_point_time=True,
        cloud_stamps_s=stamps, epoch_s=0.0, poses=traj, material_names=None)
    return meas, int(round(n_per_frame * rec.frames))


def materials_under(model: Model, data: lk.FitData, effect: Effect) -> MaterialsConfig:
    """Each material's bias and sigma refit on top of ``effect`` (and ``data``'s base
    effects): the materials as ``--effect NAME --fit`` leaves them."""
    on = lk.model_on_rays(data, [effect])
    residual = np.asarray(data.measured_range_m, float) - on.expected_range_m
    pred = replace(data.baseline, sigma_m=on.sigma_m)
    stats = mat.material_stats(model.materials, pred, residual,
                               np.isfinite(residual))
    return mat.refit_materials(model.materials, stats)


def one_way(model: Model, base: list[Effect], true: Effect, other: Effect,
            meas: Measurements, seed: int, z_crit: float) -> dict:
    """The simulated recording of ``true`` diagnosed as compare would (``model`` with
    ``base``): the paired held-out ``margin`` of ``true``'s class over ``other``'s (nats
    per point, both cross-fitted), its ``z``, the points diagnosed (``n``) and each
    one's held-out gain and fitted parameters."""
    geom = model.simulator(effects=[lk.RaysOnly(e) for e in lk.moving(base)])
    m = match(geom, meas, model.divergence_rad, edges=False)
    rays = fit_data.RaySet(meas, np.flatnonzero(m.matched), np.flatnonzero(~m.matched),
                            pred=m.pred, blocks=neighbours.blocks(meas.directions, meas.cloud))
    diag = diagnosis.Diagnosis(model, base, rays, seed)
    diag.z_crit = z_crit         # the bound of the comparison that found the tie
    a, b = diag.score(type(true)), diag.score(type(other))
    out = {'n': diag.n_total, 'margin': float('nan'), 'z': float('nan'),
           'gain_true': a.score, 'gain_other': b.score,
           'fitted_true': a.params, 'fitted_other': b.params}
    if not (a.error or b.error):
        out['margin'], out['z'] = diag.paired(a, b)
    return out


@dataclass(frozen=True)
class Hypothesis:
    """A tied candidate: its fitted effect and the materials --fit leaves with it."""

    effect: Effect
    materials: MaterialsConfig

    @property
    def name(self) -> str:
        return self.effect.name


def hypotheses(model: Model, data: lk.FitData, effects: list[Effect]) -> list[Hypothesis]:
    """The tied candidates' fitted ``effects`` as hypotheses, each with the materials
    refit on top of it (on ``data``, the diagnosed points)."""
    return [Hypothesis(e, materials_under(model, data, e)) for e in effects]


def separation(model: Model, base: list[Effect], a: Hypothesis, b: Hypothesis,
               rec: Recording, seed: int, z_crit: float, max_diagnosed: int) -> dict:
    """The expected separation of ``a`` and ``b`` by ``rec`` (module doc): each flown
    with its own effect and materials, diagnosed against the other. When the first way
    already fails the rule the recording cannot separate them, and the second is not
    flown (``skipped``): the row's margin and z are then the first way's, an upper
    bound of the weaker way's."""
    rows = {}
    for k, (true, other) in enumerate(((a, b), (b, a))):
        if rows and not _passes(next(iter(rows.values())), z_crit):
            rows[true.name] = {'skipped': True}
            continue
        meas, n_rec = simulate_measurements(model, true.materials, [*base, true.effect], rec,
                                            seed + k, first_frame=1000 * (k + 1),
                                            max_points=sample_points(a, b))
        got = one_way(model, base, true.effect, other.effect, meas, seed, z_crit)
        n, z = got['n'], got['z']
        n_diag = min(n_rec, max_diagnosed)
        rows[true.name] = {'margin': got['margin'], 'z_sample': z, 'sample_points': n,
                           'z': z * np.sqrt(n_diag / max(n, 1)) if np.isfinite(z) else z,
                           'points': n_rec, 'diagnosed_points': n_diag,
                           'gain_true': got['gain_true'], 'gain_other': got['gain_other'],
                           'fitted_true': got['fitted_true'],
                           'fitted_other': got['fitted_other']}
    done = {n: r for n, r in rows.items() if not r.get('skipped')}
    margins = [r['margin'] for r in done.values()]
    zs = [r['z'] for r in done.values()]
    ok = all(np.isfinite(margins)) and all(np.isfinite(zs))
    worst = int(np.argmin(zs)) if ok else 0
    margin = float(min(margins)) if ok else float('nan')
    z = float(min(zs)) if ok else float('nan')
    return {
        'recording': rec.label, 'what': rec.what,
        'distance_m': round(rec.distance_m, 3), 'frames': rec.frames,
        'duration_s': round(rec.duration_s, 3),
        'points': int(max(r['points'] for r in done.values())),
        'margin': _num(margin), 'z': _num(z),
        'separates': bool(ok and len(done) == 2 and all(_passes(r, z_crit)
                                                        for r in done.values())),
        'z_bound': round(float(z_crit), 3),
        'weaker_way': list(done)[worst],
        'ways': {n: {k: _num(v) if isinstance(v, float) else v for k, v in r.items()}
                 for n, r in rows.items()},
        **rec.scenario_keys(),
    }


def sample_points(a: Hypothesis, b: Hypothesis) -> int:
    """Points diagnosed per simulated recording: fewer when an effect casts its own rays."""
    casts = any(type(h.effect).cast is not Effect.cast for h in (a, b))
    return SAMPLE_POINTS_CAST if casts else SAMPLE_POINTS


def _passes(way: dict, z_crit: float) -> bool:
    """Whether one way clears compare's rule: margin and z (NaN: no)."""
    return bool(way['margin'] >= diagnosis.MIN_PRACTICAL_GAIN and way['z'] >= z_crit)


def separation_plan(model: Model, base: list[Effect], a: Hypothesis, b: Hypothesis,
                    recorded: Recording, seed: int, z_crit: float,
                    max_diagnosed: int) -> list[dict]:
    """The candidate recordings' expected separations, best first (separating ones
    first, then by z), flown in ``candidate_recordings``' order until one separates the
    pair with ENOUGH_Z times the bound."""
    rows = []
    for rec in candidate_recordings(recorded, [a.name, b.name]):
        rows.append(separation(model, base, a, b, rec, seed, z_crit, max_diagnosed))
        if rows[-1]['separates'] and rows[-1]['z'] >= ENOUGH_Z * z_crit:
            break
    return sorted(rows, key=lambda r: (not r['separates'],
                                       -(r['z'] if r['z'] is not None else -np.inf)))


def scenario_yaml(head: list[str], keys: dict, scenario_seed: int, mesh: Path,
                  sensor: Path, materials: Path, base: list[Effect]) -> str:
    """plan.yaml's text: the comment lines ``head``, then a scenario with the
    configuration's files, the recording's ``initial_pose`` and ``motion`` (``keys``,
    ``Recording.scenario_keys``) and the effects ``base``."""
    body = {'seed': int(scenario_seed), 'mesh': str(mesh), 'sensor': str(sensor),
            'materials': str(materials), 'frame_id': 'lidar',
            **keys, 'effects': [_entry(e) for e in base]}
    return '\n'.join(head) + '\n' + yaml.safe_dump(body, sort_keys=False,
                                                   default_flow_style=None)


def plan_yaml(row: dict, a: Hypothesis, b: Hypothesis, scenario_seed: int, mesh: Path,
              sensor: Path, materials: Path, base: list[Effect], period_s: float) -> str:
    """plan.yaml: the best recording as a scenario ``lidar-sim simulate`` flies (and a lab
    can reproduce), with what it separates and the expected z in its header."""
    def spec(h: Hypothesis) -> str:
        entry = _entry(h.effect)
        return f'{entry["name"]}=' + yaml.safe_dump(entry['params'],
                                                    default_flow_style=True).strip()
    verdict = ('separates them' if row['separates'] else
               'does not separate them by the rule; it is the best of those tried')
    head = [
        '# Separation plan written by lidar-sim compare: the recording that best tells',
        f'# {a.name} from {b.name} (confounded in the recording compared).',
        f'# Recording: {row["what"]}; {row["distance_m"]:.2f} m, {row["frames"]} frames '
        f'({row["duration_s"]:.2f} s at {1 / period_s:g} Hz).',
        f'# Expected: {row["margin"]:.4f} nats/point held out between the two (the weaker '
        f'way, {row["weaker_way"]}\'s data), z = {row["z"]:.1f} with '
        f'{min(r["diagnosed_points"] for r in row["ways"].values() if "skipped" not in r)} '
        'points diagnosed: '
        f'{verdict}.',
        f'# The z assumes those points on the target: about {row["points"] // max(row["frames"], 1)} '
        'a frame from this sensor model.',
        '# A sensor that returns fewer needs more frames (z grows as the square root of',
        '# the points); with fewer points a null verdict means too little data, not no effect.',
        '# Fly it (or reproduce it in the lab) and compare:',
        f'#   lidar-sim simulate plan.yaml --frames {row["frames"]} --out DIR',
        '# The two hypotheses as fitted (to check the plan in simulation):',
        f'#   --effect "{spec(a)}"',
        f'#   --effect "{spec(b)}"',
    ]
    return scenario_yaml(head, {'initial_pose': row['initial_pose'], 'motion': row['motion']},
                         scenario_seed, mesh, sensor, materials, base)


def _entry(effect: Effect) -> dict:
    """The effect's scenario ``effects:`` entry (``Effect.to_yaml_snippet``: a catalogue
    name or the ``module:Class`` / ``file.py:Class`` that loads a user effect again)."""
    return yaml.safe_load(effect.to_yaml_snippet())[0]


def _num(x: float) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


# A reference pose off along the line of sight against a range error of the sensor
# (``Diagnosis.weigh_pose_rivals``): the distances of the two recordings that separate them.
POSE_RANGE_DISTANCES = (0.5, 2.0)
POSE_RANGE_FRAMES = 100


def pose_range_recordings(rec: Recording) -> list[Recording]:
    """The recordings that tell a reference pose off along the line of sight from a
    range error of the sensor: the target held still on a surveyed pose (no tracking
    system between it and the truth), near, so that it spans a wide angle (a pose
    error moves each ray's range by n.d / (n.u), which changes across a wide view; a
    range offset is the same on every ray), and far (a range scale grows with the
    distance; a pose error does not). Both at least as long as the recording compared
    (POSE_RANGE_FRAMES at least), for a slow drift to show."""
    out = []
    frames = max(POSE_RANGE_FRAMES, rec.frames)     # as long as the recording compared
    for f in POSE_RANGE_DISTANCES:
        word = 'near, seen across a wide angle' if f < 1 else 'far'
        out.append(replace(rec, label=f'static, surveyed, {f:g}x the distance',
                           what=f'the target held still on a surveyed pose, {word}: '
                                f'{f * rec.distance_m:.1f} m ({f:g} x {rec.distance_m:.1f} m), '
                                f'{frames} frames',
                           position_m=tuple(f * np.asarray(rec.position_m)),
                           approach_speed_mps=0.0, tumble_rate_dps=0.0, frames=frames))
    return out


def unflown_rows(recs: list[Recording], rival: str) -> list[dict]:
    """Summary rows of a plan not simulated (a reference pose error is no sensor effect
    the simulator flies): each recording's geometry and scenario keys, the pose and
    ``rival`` as its two ways, no margin or z."""
    return [{'recording': r.label, 'what': r.what, 'distance_m': round(r.distance_m, 3),
             'frames': r.frames, 'duration_s': round(r.duration_s, 3), 'points': 0,
             'margin': None, 'z': None, 'separates': None, 'simulated': False,
             'ways': {diagnosis.POSE_ERROR: {'margin': None, 'z': None},
                      rival: {'margin': None, 'z': None}},
             **r.scenario_keys()} for r in recs]


def pose_range_plan(rec: Recording, rival: str, scenario_seed: int, mesh: Path, sensor: Path,
                    materials: Path, base: list[Effect], period_s: float
                    ) -> tuple[list[dict], str]:
    """The separation plan of a reference pose tied with a range error of the sensor
    (``rival``): summary rows (not simulated: a reference pose error is no sensor effect
    the simulator flies, and the separation is geometric) and plan.yaml, the near
    recording as a scenario with the far one in its header."""
    recs = pose_range_recordings(rec)
    rows = unflown_rows(recs, rival)
    near, far = recs
    far_keys = far.scenario_keys()
    head = [
        '# Separation plan written by lidar-sim compare: the recordings that tell a',
        f'# reference pose off along the line of sight from {rival} (a range error of the',
        '# sensor); they explained the recording compared equally well.',
        '# Hold the target still on a surveyed pose (no tracking system between it and the',
        '# truth) and record it twice, each long enough for a slow drift to show:',
        f'#   1. {near.what} (this scenario): a pose error moves each ray\'s range by',
        '#      n.d / (n.u), which changes across the wide view; a range offset does not.',
        f'#   2. {far.what}: initial_pose position_m {far_keys["initial_pose"]["position_m"]}',
        '#      (same attitude): a range scale grows with the distance, a pose error does not.',
        ('# Then compare each with --effect pose_error --fit and with --effect '
         f'{rival} --fit.' if rival != diagnosis.RANGE_OF_RANGE else
         '# Then compare each with --effect pose_error --fit: a range error that follows '
         'range stays.'),
        f'#   lidar-sim simulate plan.yaml --frames {near.frames} --out DIR',
    ]
    return rows, scenario_yaml(head, near.scenario_keys(), scenario_seed, mesh, sensor,
                               materials, base)


# What a faster tumble and a still target show of each rival of a reference pose that
# moves the target with its motion (``pose_motion_plan``): (rival's name, what it is,
# how the faster tumble tells it from the pose).
MOTION_RIVALS = {
    'time_offset': ('a clock offset between the pose and LiDAR stamps',
                    'a clock offset moves the target by its motion over the offset, '
                    f'{TUMBLE_FACTOR:g} x as far here; a tracking system\'s error need not '
                    'follow the motion'),
    'laser_pointing': ('some lasers off their configured directions',
                       'a tracking system\'s drift or lag grows with the motion; a laser\'s '
                       'pointing does not, and it stays on the still target'),
}


def pose_motion_plan(rec: Recording, scenario_seed: int, mesh: Path, sensor: Path,
                     materials: Path, base: list[Effect], rival: str = 'time_offset'
                     ) -> tuple[list[dict], str]:
    """The separation plan of a reference pose error (constant, or drifting within each
    cloud) tied with ``rival`` (a key of MOTION_RIVALS: a clock offset, or lasers off
    their directions): summary rows (not simulated: a reference pose error is no sensor
    effect the simulator flies) and plan.yaml, the same recording with the target
    tumbling TUMBLE_FACTOR x as fast. A clock offset moves the target by its motion over
    the offset, so its displacement grows with the tumble rate; a tracking system's error
    need not, and a laser's pointing does not. A static target on a surveyed pose, in the
    header: no tracking system moves it there."""
    what, how = MOTION_RIVALS[rival]
    fast = replace(rec, label=f'{TUMBLE_FACTOR:g}x the tumble rate',
                   what=f'the target tumbling {TUMBLE_FACTOR:g} x as fast '
                        f'({TUMBLE_FACTOR * rec.tumble_rate_dps:.2g} deg/s)',
                   tumble_rate_dps=TUMBLE_FACTOR * rec.tumble_rate_dps)
    still = replace(rec, label='static, surveyed', what='the target held still on a surveyed '
                    'pose (no tumble, no tracking system between it and the truth)',
                    approach_speed_mps=0.0, tumble_rate_dps=0.0)
    rows = unflown_rows([fast, still], rival)
    left = ('a residual left there is neither' if rival == 'time_offset' else
            f'a residual left there is {rival}\'s, not the reference pose\'s')
    head = [
        '# Separation plan written by lidar-sim compare: the recordings that tell',
        f'# {what} ({rival}) from a reference pose error (constant or drifting within each',
        '# cloud); they explained the recording compared equally well.',
        f'#   1. {fast.what} (this scenario): {how}.',
        f'#   2. {still.what}: {left}.',
        f'# Then compare each with --effect {rival} --fit and with --effect pose_error --fit.',
        f'#   lidar-sim simulate plan.yaml --frames {fast.frames} --out DIR',
    ]
    return rows, scenario_yaml(head, fast.scenario_keys(), scenario_seed, mesh, sensor,
                               materials, base)
