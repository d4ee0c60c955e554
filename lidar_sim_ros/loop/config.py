"""The closed loop's configuration (``config/loop.yaml``): pydantic models and the loader.

Frames and units: LVLH is the target's Hill frame (x radial out, y along-track = V-bar,
z orbit normal), metres and m/s; body inertias are kg m^2 about the centre of mass in
the body axes; angles in degrees; times in seconds; forces in newtons.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from lidar_sim_ros.core.config import ConfigError, _Model, parse, read_yaml, resolve

PositiveFloat = Annotated[float, Field(gt=0.0)]
NonNegFloat = Annotated[float, Field(ge=0.0)]
Vector3 = tuple[float, float, float]
# Proximity operations: the chaser starts within 10 km of the target at under 100 m/s (the
# CW frame, the sensor's 250 m gate); 1e300 m overflowed in the frame chain with no key named.
PositionM = Annotated[float, Field(ge=-10_000.0, le=10_000.0)]
VelocityMps = Annotated[float, Field(ge=-100.0, le=100.0)]
Direction = Annotated[float, Field(ge=-1e6, le=1e6)]   # any scale that a norm cannot overflow


def _inertia_ok(v: tuple[Vector3, Vector3, Vector3]):
    m = np.asarray(v, dtype=float)
    if not np.allclose(m, m.T):
        raise ValueError('inertia must be symmetric')
    if np.linalg.eigvalsh(m).min() <= 0:
        raise ValueError('inertia must be positive definite')
    return v


def _nonzero(v: Vector3) -> Vector3:
    if float(np.linalg.norm(v)) < 1e-12:
        raise ValueError('must not be the zero vector')
    return v


def _unit_quaternion(q: tuple[float, float, float, float]):
    if abs(float(np.linalg.norm(q)) - 1.0) > 1e-3:
        raise ValueError(f'must be a unit quaternion (xyzw), its norm is {float(np.linalg.norm(q)):g}')
    return q


class OrbitConfig(_Model):
    """The target's circular low Earth orbit (point-mass Earth: no harmonics, no files)."""

    altitude_m: Annotated[float, Field(gt=100e3, lt=3000e3)] = Field(
        500e3, description='altitude above the equatorial radius 6378.1366 km (m)')
    inclination_deg: Annotated[float, Field(ge=0, le=180)] = 51.6
    raan_deg: float = 0.0
    arg_latitude_deg: float = Field(0.0, description='argument of latitude at t = 0 (deg)')


class RigidBodyConfig(_Model):
    """Mass (kg) and inertia (kg m^2, body axes about the centre of mass)."""

    mass_kg: PositiveFloat
    inertia_kg_m2: tuple[Vector3, Vector3, Vector3]

    _inertia = field_validator('inertia_kg_m2')(_inertia_ok)


class TargetConfig(RigidBodyConfig):
    """The tumbling rocket body. Its body frame is the mesh's (long axis +Z, origin
    mid-length, taken as the centre of mass)."""

    tumble_rate_dps: Annotated[float, Field(ge=0.0, le=180.0)] = Field(3.0, description=(
        'initial angular rate (deg/s; at most 180: debris tumbles at a few deg/s, and at 1e6 '
        'deg/s the 100 Hz truth samples alias and the frame chain gave NaN)'))
    tumble_axis_body: tuple[Direction, Direction, Direction] = Field((0.3, 0.0, 1.0), description=(
        'initial rotation axis in the body frame; off the principal axes, so the body '
        'nutates (torque-free)'))
    quat_xyzw_lvlh: tuple[float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 1.0), description='initial attitude: body -> LVLH rotation (xyzw)')

    _axis = field_validator('tumble_axis_body')(_nonzero)
    _quat = field_validator('quat_xyzw_lvlh')(_unit_quaternion)


class MountConfig(_Model):
    """Where the lidar sits on the chaser: p_body = R p_lidar + t (m)."""

    position_m: tuple[PositionM, PositionM, PositionM] = (1.0, 0.0, 0.0)
    quat_xyzw: tuple[float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 1.0), description='lidar -> chaser body rotation (xyzw)')

    _quat = field_validator('quat_xyzw')(_unit_quaternion)


class ChaserConfig(RigidBodyConfig):
    mount: MountConfig = MountConfig()
    attitude_law: Literal['point_at_target', 'hold_lvlh'] = Field(
        'point_at_target', description='point_at_target: lidar boresight on the target centre, '
        'its z toward LVLH +x (radial) as far as it can be; hold_lvlh: body x along +V-bar, '
        'body z radial out')
    thrust_limit_n: PositiveFloat = Field(2.0, description='largest force per LVLH axis (N)')
    dead_band_n: NonNegFloat = Field(0.02, description='commands weaker than this (norm, N) are not fired')


class GuidanceConfig(_Model):
    """V-bar approach: the chaser behind the target (LVLH y < 0) holding at each range in turn."""

    hold_ranges_m: list[PositiveFloat] = Field([30.0, 15.0, 8.0], min_length=1)
    hold_time_s: NonNegFloat = Field(10.0, description='dwell at each hold point once settled (s)')
    settle_radius_m: PositiveFloat = Field(0.3, description='within this of the hold point (m) ...')
    settle_speed_mps: PositiveFloat = Field(0.02, description='... and slower than this, the hold counts (m/s)')
    approach_speed_mps: PositiveFloat = Field(0.25, description='reference speed between holds (m/s)')
    approach_accel_mps2: PositiveFloat = Field(0.01, description='reference acceleration between holds (m/s^2)')
    natural_frequency_rad_s: PositiveFloat = Field(0.25, description='PD closed-loop bandwidth (rad/s)')
    damping_ratio: PositiveFloat = 0.9
    filter_alpha: Annotated[float, Field(gt=0, le=1)] = Field(
        0.4, description='alpha-beta filter gain on the estimated relative position')
    filter_beta: Annotated[float, Field(gt=0, le=1)] = Field(
        0.05, description='alpha-beta filter gain on the estimated relative velocity')

    @field_validator('hold_ranges_m')
    @classmethod
    def _decreasing(cls, v):
        if any(b >= a for a, b in zip(v, v[1:])):
            raise ValueError('hold ranges must decrease')
        return v


class InitialStateConfig(_Model):
    """The chaser's start relative to the target, LVLH (m, m/s), and its seeded dispersion."""

    position_m: tuple[PositionM, PositionM, PositionM] = Field(
        (0.0, -30.0, 0.0), description='per axis within +-10 km (proximity operations)')
    velocity_mps: tuple[VelocityMps, VelocityMps, VelocityMps] = Field(
        (0.0, 0.0, 0.0), description='per axis within +-100 m/s')
    position_sigma_m: Annotated[float, Field(ge=0.0, le=1000.0)] = 0.0
    velocity_sigma_mps: Annotated[float, Field(ge=0.0, le=10.0)] = 0.0


class SunDirectionConfig(_Model):
    """An analytic sun: a fixed inertial direction (it moves ~1 deg/day: fixed over a run)."""

    direction_inertial: tuple[Direction, Direction, Direction] = (1.0, 0.0, 0.0)
    eclipse: bool = Field(True, description=(
        "the Earth's shadow (a cylinder of the Earth's radius behind it): while the chaser is "
        'in it, the in-process loop simulates its frames without the sun (no sunlight, no solar '
        'background)'))

    _dir = field_validator('direction_inertial')(_nonzero)


class TimingConfig(_Model):
    mode: Literal['lockstep', 'realtime'] = 'lockstep'
    command_timeout_s: PositiveFloat = Field(
        2.0, description='lock-step: wall time to wait for a step command before going on (logged)')
    startup_timeout_s: PositiveFloat = Field(
        30.0, description=(
            "lock-step: the wait (wall s) until the run's first command (the first acquisition "
            'takes 0.5-3 s of compute; logged once per period it expires)'))
    realtime_waits_for_first_command: bool = Field(True, description=(
        "real time: pace on the wall clock from the GNC's first command on, the periods before "
        'it waiting as in lock-step (up to startup_timeout_s each): the first acquisition is not '
        'counted late; false: pace from the first period'))
    pose_rate_hz: Annotated[float, Field(ge=10, le=1000)] = Field(
        100.0, description='dynamics sub-steps and /target/pose per second')


class GncConfig(_Model):
    """Your own controller and navigation filter (``loop.user_gnc``): entry points
    ``module:factory`` or ``file.py:factory`` (a file relative to the loop config), loaded
    when a run starts; None: the built-in PD and alpha-beta filter."""

    controller: str | None = Field(None, description=(
        "factory(config) -> control(t_s, rho_m, rho_dot_mps, reference, n_rad_s) -> force (N, LVLH)"))
    navigation: str | None = Field(None, description=(
        'factory(config) -> an object with update(t_s, rho_measured_m | None) and at(t_s) -> '
        '(rho_m, rho_dot_mps) | None'))

    @field_validator('controller', 'navigation')
    @classmethod
    def _entry_point(cls, v):
        if v is not None:
            where, sep, name = v.rpartition(':')
            if not sep or not where or not name.isidentifier():
                raise ValueError("must be 'module:function' or 'file.py:function'")
        return v


class LoopConfig(_Model):
    """Everything one closed-loop run needs (config/loop.yaml)."""

    seed: int = 0
    scenario: str = Field('scenario_all_effects.yaml', description=(
        "the simulator's scenario (sensor, materials, mesh, effects, sun irradiance); "
        'its initial_pose and motion are unused: the dynamics drives the pose'))
    duration_s: PositiveFloat = 120.0
    control_period_s: PositiveFloat = Field(0.1, description='one lidar frame: one step (s)')
    tracker_threads: Annotated[int, Field(ge=1, le=64)] = Field(1, description=(
        "threads of the tracker's ICP (small_gicp). 1 keeps runs identical to the bit; 2 "
        'makes the in-process loop ~12 % faster on two cores (5.2-5.9x real time against '
        '4.9-5.1x with every effect) but sums in another order from run to run (estimates '
        'differ by ~1e-14 m); a campaign always runs 1 per worker'))
    acquire_from_cloud: bool = Field(True, description=(
        'capture the first pose (and again after a loss) from the cloud alone '
        '(gnc/acquire.py); false: capture from the true pose, a reference for what the '
        'acquisition costs (the GNC side then reads the truth once per capture)'))
    cloud_gate_m: NonNegFloat = Field(8.0, description=(
        'cloud points farther than this from the last estimated target centre are dropped '
        'before the tracker (m; 0 = none): far background returns cost the nearest-neighbour '
        'search ~15x the time of the target points (measured, docs/loop.md)'))
    capture_gate_m: NonNegFloat = Field(12.0, description=(
        'before a capture from the cloud (no estimate yet, or after a loss) points farther than '
        'this from the cloud\'s median point are dropped (m; 0 = none); larger than the body '
        '(10.8 m across its ends) so that no target point is lost while the median is on it'))
    orbit: OrbitConfig = OrbitConfig()
    target: TargetConfig
    chaser: ChaserConfig
    initial: InitialStateConfig = InitialStateConfig()
    guidance: GuidanceConfig = GuidanceConfig()
    sun: SunDirectionConfig = SunDirectionConfig()
    timing: TimingConfig = TimingConfig()
    gnc: GncConfig = GncConfig()

    @model_validator(mode='after')
    def _substeps(self):
        n = self.control_period_s * self.timing.pose_rate_hz
        if abs(n - round(n)) > 1e-9 or round(n) < 1:
            raise ValueError(f'control_period_s * timing.pose_rate_hz = {n:g} must be a whole number >= 1')
        return self

    @property
    def substeps(self) -> int:
        """Dynamics sub-steps (pose samples) per control period."""
        return int(round(self.control_period_s * self.timing.pose_rate_hz))


def load_loop_config(path: str | Path) -> tuple[LoopConfig, Path]:
    """The loop config and the resolved path of its scenario; ConfigError names file/key/value."""
    path = Path(path)
    cfg = parse(LoopConfig, read_yaml(path), path)
    if cfg.gnc.controller or cfg.gnc.navigation:   # files beside the config, wherever the run starts
        from lidar_sim_ros.loop.user_gnc import resolve_spec
        base = path.resolve().parent
        cfg = cfg.model_copy(update={'gnc': GncConfig(controller=resolve_spec(cfg.gnc.controller, base),
                                                      navigation=resolve_spec(cfg.gnc.navigation, base))})
    scenario = resolve(cfg.scenario, path.resolve().parent)
    if not scenario.is_file():
        raise ConfigError(path, 'scenario', cfg.scenario, f'scenario file not found at {scenario}')
    return cfg, scenario
