"""Validated configuration: sensor, materials and scenario, loaded from YAML.

Every model is a frozen pydantic model with ``extra='forbid'``: an unknown key, a
missing key or an out-of-range value raises :class:`ConfigError`, whose message
names the file, the key path and the offending value.
"""
from __future__ import annotations

import difflib
import reprlib
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
import yaml
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError,
                      field_validator, model_serializer, model_validator)

from lidar_sim_ros.core.vectors import QUAT_NORM_TOL, unit_vector
from lidar_sim_ros.paths import share_dir


# Size limits: a config past one of these is refused before anything is allocated.
MAX_SHOTS_PER_FRAME = 5_000_000
MAX_LASERS = 1024
"""Laser ids run 0 .. MAX_LASERS - 1 (the largest sensors have 128 channels): a scan
pattern, a recording's laser field or laser_bias offsets beyond it are refused, not
wrapped into the uint16 laser field (a CSV laser of 70000 read as 4464)."""
"""Shots in one frame (the P-60 fires 21,120); each shot costs ~1 kB through the pipeline."""
MAX_YAML_NODES = 200_000
"""Values in one YAML document counted with aliases expanded (an alias bomb stops here)."""
MAX_VALUE_CHARS = 120
"""Longest rendering of an offending value in an error message."""

_SHORT = reprlib.Repr()
_SHORT.maxlevel, _SHORT.maxdict, _SHORT.maxlist, _SHORT.maxtuple = 3, 4, 6, 6
_SHORT.maxstring = _SHORT.maxother = MAX_VALUE_CHARS


def short_repr(value: Any) -> str:
    """``repr(value)`` bounded in work and length: error messages never render a whole
    mapping (an alias bomb would make that line gigabytes long)."""
    text = _SHORT.repr(value)
    return text if len(text) <= MAX_VALUE_CHARS else text[:MAX_VALUE_CHARS - 3] + '...'


class ConfigError(ValueError):
    """A configuration problem, naming file, key and value (value truncated)."""

    def __init__(self, file: str | Path, key: str, value: Any, reason: str):
        self.file, self.key, self.value, self.reason = str(file), key, value, reason
        super().__init__(f'{file}: key "{key}" = {short_repr(value)}: {reason}')


class WrongFileKindError(ConfigError):
    """A file of one kind (a campaign spec) given where another (a scenario) is expected."""

    def __init__(self, file: str | Path, kind: str, expected: str, hint: str):
        self.file, self.key, self.value = str(file), '<file>', kind
        self.reason = f'this is a {kind}, not a {expected}: {hint}'
        ValueError.__init__(self, f'{file}: {self.reason}')


class _Model(BaseModel):
    # allow_inf_nan=False: every float of every config model must be finite (a NaN
    # scan phase or an infinite FOV gave 0 points and rc 0).
    model_config = ConfigDict(extra='forbid', frozen=True, allow_inf_nan=False)


def _without_unset_new_keys(data: Any, keys: tuple[str, ...]) -> Any:
    """``data`` (a model's dump) without the ``keys`` that are None: keys added after files
    were fingerprinted (campaigns) dump as before when unused, so those files resume."""
    if isinstance(data, dict):
        for key in keys:
            if key in data and data[key] is None:
                del data[key]
    return data


MIN_FIELD_DEG = 1e-3
"""Narrowest flash array or flood field (deg, 3.6 arcsec): a flood of 1e-300 deg has a solid
angle that underflows to 0, and every pixel's power was NaN (divide by zero)."""
MIN_SCAN_RATE_HZ = 1e-3
"""Slowest scan motion (Hz, a Lissajous frequency or a prism's rate in rev/s, and the
difference of two prism rates): once in 1000 s, like MIN_FRAME_RATE_HZ. A rate of 1e-300 is
positive but leaves every shot of a frame in one direction."""
MIN_BEAM_DIVERGENCE_RAD = 1e-6
"""Narrowest beam (rad, full angle): a 905 nm beam through a 1 m aperture diffracts to ~1e-6
rad. At 1e-300 the footprint's area underflowed to 0: infinite irradiance, numpy warnings
and no point (every return above saturation)."""
MAX_APERTURE_M = 10.0
"""Widest receiver aperture (m; the largest telescopes' mirrors): 1e300 m overflowed the
aperture area (OverflowError out of the frame)."""

MAX_PEAK_POWER_W = 1.0e9
"""Strongest laser pulse (W, peak): a 5 J pulse of 5 ns. The strongest flown on a
spacecraft lidar reach ~1e7 W (ICESat's GLAS: 75 mJ in ~6 ns), a flash rendezvous lidar
~1e5-1e6 (flash_256.yaml: 2e5); 1e300 W was accepted and saturated every pixel (no
point, rc 0)."""


MAX_PHASE_RAD = 1.0e4
"""Largest scan phase (rad: a prism's, a Lissajous axis's or its per-laser step; calibrate
scan writes them in -pi..pi): a phase of 1e300 is finite but its float64 spacing is
~1e284 rad, so the angle it gives is arbitrary."""
Phase = Annotated[float, Field(ge=-MAX_PHASE_RAD, le=MAX_PHASE_RAD)]
MAX_SCAN_FREQ_HZ = 1.0e6
"""Fastest Lissajous axis (Hz; MEMS mirrors resonate up to tens of kHz): at 1e300 Hz the
phase 2 pi f t of every shot is arbitrary."""


PositiveFloat = Annotated[float, Field(gt=0.0)]
NonNegFloat = Annotated[float, Field(ge=0.0)]
ScanRate = Annotated[float, Field(ge=MIN_SCAN_RATE_HZ, le=MAX_SCAN_FREQ_HZ)]
Fraction = Annotated[float, Field(ge=0.0, le=1.0)]


# --------------------------------------------------------------------- sensor
class LaserOverride(_Model):
    """Per-laser Lissajous parameters (degrees, hertz, radians); unset = tile default."""

    center_az_deg: Annotated[float, Field(ge=-180.0, le=180.0)] | None = None
    center_el_deg: Annotated[float, Field(ge=-90.0, le=90.0)] | None = None
    amp_az_deg: Annotated[float, Field(ge=MIN_FIELD_DEG / 2, le=180.0)] | None = None
    amp_el_deg: Annotated[float, Field(ge=MIN_FIELD_DEG / 2, le=90.0)] | None = None
    freq_az_hz: ScanRate | None = None
    freq_el_hz: ScanRate | None = None
    phase_az_rad: Phase | None = None
    phase_el_rad: Phase | None = None


class LissajousArrayScan(_Model):
    """Tiled Lissajous-like scan (Cepton Vista P-60: 8 x 3 tiles, paper Sec. 3)."""

    type: Literal['lissajous_array']
    fov_az_deg: Annotated[float, Field(ge=MIN_FIELD_DEG, le=360.0)]
    fov_el_deg: Annotated[float, Field(ge=MIN_FIELD_DEG, le=180.0)]
    tiles_az: Annotated[int, Field(ge=1)]
    tiles_el: Annotated[int, Field(ge=1)]
    shots_per_laser: Annotated[int, Field(ge=1)]
    overlap: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        description='fraction of a tile half-width the curve overruns (at most into the '
                    "neighbours' centres: 1e300 sent shots to 1e300 deg)")
    freq_az_hz: ScanRate
    freq_el_hz: ScanRate
    phase_az_rad: Phase = 0.0
    phase_el_rad: Phase = 0.0
    phase_step_rad: Phase = Field(0.0, description='extra phase per laser index, decorrelates tiles')
    lasers: list[LaserOverride] | None = None

    @model_validator(mode='after')
    def _lasers_match_tiles(self):
        if self.lasers is not None and len(self.lasers) != self.tiles_az * self.tiles_el:
            raise ValueError(f'lasers has {len(self.lasers)} entries, expected '
                             f'tiles_az*tiles_el = {self.tiles_az * self.tiles_el}')
        if self.tiles_az * self.tiles_el > MAX_LASERS:
            raise ValueError(f'tiles_az*tiles_el = {self.tiles_az * self.tiles_el} lasers exceed '
                             f'the limit of {MAX_LASERS}')
        _check_shots(self.tiles_az * self.tiles_el * self.shots_per_laser)
        return self


def _check_shots(n: int) -> None:
    if n > MAX_SHOTS_PER_FRAME:
        raise ValueError(f'{n} shots per frame exceed the limit of {MAX_SHOTS_PER_FRAME}')


class RotatingScan(_Model):
    """Generic spinning multi-beam LiDAR: beams at fixed elevations, azimuth sweeps."""

    type: Literal['rotating']
    elevations_deg: list[Annotated[float, Field(ge=-90.0, le=90.0)]] = Field(
        min_length=1, max_length=MAX_LASERS)
    az_min_deg: float = -180.0
    az_max_deg: float = 180.0
    shots_per_beam: Annotated[int, Field(ge=1)]

    @model_validator(mode='after')
    def _az_order(self):
        if self.az_max_deg - self.az_min_deg < MIN_FIELD_DEG:
            raise ValueError(f'az_max_deg must exceed az_min_deg by at least {MIN_FIELD_DEG:g} deg '
                             f'({self.az_min_deg:g} .. {self.az_max_deg:g}: every beam would fire '
                             'in one direction)')
        if self.az_max_deg - self.az_min_deg > 360.0:
            raise ValueError('az_max_deg - az_min_deg exceeds 360 deg')
        _check_shots(len(self.elevations_deg) * self.shots_per_beam)
        return self


class FileScan(_Model):
    """Scan pattern read from a CSV/NPY of (t_s, az_deg, el_deg, laser) rows."""

    type: Literal['file']
    path: str


MAX_PRISM_RATE_HZ = 10_000.0
"""Fastest prism (rev/s, 600,000 rpm): faster, the prism angle at a wall-clock frame index
(~1e10) loses its precision in float64."""




class RisleyScan(_Model):
    """Two wedge prisms rotating at their own rates (a Risley pair; the Livox Mid-40's
    rosette, ``core/scan_risley.py``). One laser fires at ``shot_rate_hz``; each shot
    points where the two prisms' deviations, added to first order, send it."""

    type: Literal['risley']
    prism_rates_hz: tuple[Annotated[float, Field(ge=-MAX_PRISM_RATE_HZ, le=MAX_PRISM_RATE_HZ)],
                          Annotated[float, Field(ge=-MAX_PRISM_RATE_HZ, le=MAX_PRISM_RATE_HZ)]] = Field(
        description='rotation rate of each prism (rev/s); the sign is the direction')
    prism_deviation_deg: tuple[Annotated[float, Field(ge=MIN_FIELD_DEG)],
                               Annotated[float, Field(ge=MIN_FIELD_DEG)]] = Field(
        description='deviation of each thin wedge alone, (n - 1) x wedge angle (deg)')
    prism_phase_rad: tuple[Phase, Phase] = (0.0, 0.0)
    shot_rate_hz: PositiveFloat = Field(description='shots per second of the one laser')

    @model_validator(mode='after')
    def _rates(self):
        f1, f2 = self.prism_rates_hz
        if min(abs(f1), abs(f2), abs(f1 - f2)) < MIN_SCAN_RATE_HZ:
            raise ValueError(f'prism_rates_hz {list(self.prism_rates_hz)}: both prisms must '
                             f'turn, at different rates (each rate and their difference at least '
                             f'{MIN_SCAN_RATE_HZ:g} rev/s: otherwise the beam stands still or draws '
                             'one circle)')
        if sum(self.prism_deviation_deg) >= 90.0:
            raise ValueError('the prisms\' deviations must add to less than 90 deg')
        return self


class FlashScan(_Model):
    """A flash LiDAR's focal-plane array (``core/scan_flash.py``): rows x cols pixels
    behind a pinhole lens over fov_az_deg x fov_el_deg, all lit by one pulse per frame.
    Rows may be read out one after another (``row_readout_s`` apart, row 0 first)."""

    type: Literal['flash']
    rows: Annotated[int, Field(ge=1, le=MAX_LASERS)] = Field(
        description='pixel rows; a row is a laser id (ring), which every reader bounds by MAX_LASERS')
    cols: Annotated[int, Field(ge=1)]
    fov_az_deg: Annotated[float, Field(ge=MIN_FIELD_DEG, lt=180.0)]
    fov_el_deg: Annotated[float, Field(ge=MIN_FIELD_DEG, lt=180.0)]
    row_readout_s: NonNegFloat = Field(0.0, description='time between two rows\' exposures (s)')

    @model_validator(mode='after')
    def _size(self):
        _check_shots(self.rows * self.cols)
        return self


ScanConfig = Annotated[Union[LissajousArrayScan, RotatingScan, FileScan, RisleyScan, FlashScan],
                       Field(discriminator='type')]


class FloodConfig(_Model):
    """Flood illumination (a flash LiDAR): one pulse spread evenly over a rectangular
    field of field_az_deg x field_el_deg instead of a narrow beam per shot."""

    field_az_deg: Annotated[float, Field(ge=MIN_FIELD_DEG, lt=180.0)]
    field_el_deg: Annotated[float, Field(ge=MIN_FIELD_DEG, lt=180.0)]


class RangeErrorConfig(_Model):
    """The sensor's own published range error, the same on every material: replaces the
    materials' bias_m and sigma_m (the P-60's Table 2) for this sensor when a scenario is
    loaded (``with_sensor_range_error``)."""

    bias_m: Annotated[float, Field(ge=-100.0, le=100.0)] = Field(
        description='systematic range error, measured minus true (m)')
    sigma_m: Annotated[float, Field(ge=0.0, le=100.0)] = Field(
        description='range precision, 1 sigma (m)')


class OpticsConfig(_Model):
    """Transmitter/receiver parameters of paper Eqs. 1-3."""

    peak_power_w: Annotated[float, Field(gt=0.0, le=MAX_PEAK_POWER_W)]
    transmit_efficiency: Annotated[float, Field(gt=0.0, le=1.0)]
    receive_efficiency: Annotated[float, Field(gt=0.0, le=1.0)]
    beam_divergence_rad: Annotated[float, Field(ge=MIN_BEAM_DIVERGENCE_RAD, lt=np.pi)] = Field(
        description='full angle of the beam (rad)')
    aperture_diameter_m: Annotated[float, Field(gt=0.0, le=MAX_APERTURE_M)]
    flood: FloodConfig | None = Field(
        None, description='flood illumination of a flash array (None: one beam per shot)')

    @model_serializer(mode='wrap')
    def _dump(self, handler):
        return _without_unset_new_keys(handler(self), ('flood',))


class ReturnsConfig(_Model):
    """Which of a shot's returns the receiver reports (``core/returns.py``).

    The default (one return, ``first``) is the paper's single-return sensor. ``mode``:
    the ``max_returns`` nearest (first), farthest (last) or strongest returns, or every
    detected return (all). Returns closer than ``min_separation_m`` (m) to the one before
    them in the same shot merge into it (one pulse).
    """

    max_returns: Annotated[int, Field(ge=1, le=8)] = 1
    mode: Literal['first', 'strongest', 'last', 'all'] = 'first'
    min_separation_m: NonNegFloat = 0.3

    @property
    def single(self) -> bool:
        """The paper's receiver: one return per shot, the first."""
        return self.max_returns == 1 and self.mode == 'first'


MAX_RANGE_M = 1.0e6
"""Longest range gate (m): a target starts within 100 km on every axis; a gate of 1e300 m
gave every one of a flash frame's 65,536 pixels a sunlit false return, at ranges up
to 1e8 m (median 25 km)."""


class DetectionConfig(_Model):
    """Detector limits: returns outside [threshold, saturation) are omitted (paper Sec. 7)."""

    threshold_power_w: PositiveFloat
    saturation_power_w: PositiveFloat
    min_range_m: NonNegFloat = 0.0
    max_range_m: Annotated[float, Field(gt=0.0, le=MAX_RANGE_M)] = 300.0
    returns: ReturnsConfig = ReturnsConfig()

    @model_validator(mode='after')
    def _order(self):
        if self.saturation_power_w <= self.threshold_power_w:
            raise ValueError('saturation_power_w must exceed threshold_power_w')
        if self.max_range_m <= self.min_range_m:
            raise ValueError('max_range_m must exceed min_range_m')
        return self


HC_NM_A_PER_W = 1239.84198
"""h c / q in nm A/W: a detector of quantum efficiency 1 at wavelength lambda (nm) gives
lambda / 1239.84 A/W, its largest possible responsivity."""


class ReceiverConfig(_Model):
    """Receiver radiometry and noise: what sunlight does to the detector (docs/sunlight.md).

    Not in the paper and not public for the P-60: the defaults are plausible 905 nm
    values (Si APD, uncooled diode laser), chosen so that the sensor's detection
    threshold sits at 5.5 sigma of the dark noise, the usual design rule for a low
    false-alarm rate. Bounds are physical where physics gives one (a responsivity within
    the quantum limit, an excess noise factor within the gain, a field of view within a
    hemisphere, a filter narrower than the wavelength) and otherwise far beyond any real
    receiver, where the noise arithmetic stays finite (a bandwidth of 1e-300 Hz divided by
    zero, a responsivity of 1e-300 A/W or an amplifier noise of 1e300 overflowed).
    """

    wavelength_nm: Annotated[float, Field(ge=200.0, le=20_000.0)] = 905.0
    bandpass_nm: PositiveFloat = Field(40.0, description='optical band-pass filter width (nm)')
    ifov_sr: Annotated[float, Field(gt=0.0, lt=2 * np.pi)] = Field(
        1.9e-5, description='receiver field of view per shot (sr)')
    detector: Literal['linear', 'photon_counting'] = 'linear'
    # linear-mode APD (Rice threshold-crossing rate)
    responsivity_a_per_w: Annotated[float, Field(ge=1e-3)] = Field(
        0.5, description='unity-gain responsivity (A/W)')
    apd_gain: Annotated[float, Field(ge=1.0, le=1e4)] = 100.0
    excess_noise_factor: Annotated[float, Field(ge=1.0)] = 5.0
    bandwidth_hz: Annotated[float, Field(ge=1e3, le=1e12)] = 2.5e8
    amplifier_noise_a_per_rthz: Annotated[float, Field(ge=0.0, le=1e-6)] = Field(
        2.18e-11, description='amplifier input current noise density (A/sqrt(Hz))')
    dark_current_a: Annotated[float, Field(ge=0.0, le=1e-3)] = Field(
        1e-10, description='bulk (multiplied) dark current, primary (A)')
    # photon counting (Poisson)
    photon_detection_efficiency: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1
    dark_count_rate_hz: Annotated[float, Field(ge=0.0, le=1e10)] = 1000.0
    coincidence_photons: Annotated[int, Field(ge=1)] = 1
    coincidence_window_s: PositiveFloat = 1e-9
    # saturation and stray light
    blinding_power_w: PositiveFloat = Field(
        5e-7, description='background power (W) that saturates the front end: no return')
    stray_light_pst_at_1deg: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        1e-4, description='point-source transmittance of the receiver optics 1 deg off axis (-)')

    @model_validator(mode='after')
    def _physical(self):
        limit = self.wavelength_nm / HC_NM_A_PER_W
        if self.responsivity_a_per_w > limit:
            raise ValueError(f'responsivity_a_per_w {self.responsivity_a_per_w:g} exceeds the quantum '
                             f'limit at {self.wavelength_nm:g} nm ({limit:.4g} A/W: one electron a photon)')
        if self.excess_noise_factor > self.apd_gain:
            raise ValueError(f'excess_noise_factor {self.excess_noise_factor:g} exceeds apd_gain '
                             f'{self.apd_gain:g} (McIntyre: F <= M for any ionisation ratio)')
        if self.bandpass_nm > self.wavelength_nm:
            raise ValueError(f'bandpass_nm {self.bandpass_nm:g} is wider than the wavelength '
                             f'{self.wavelength_nm:g} nm (the background is spectral irradiance x band)')
        return self


MIN_FRAME_RATE_HZ = 1e-3
"""Slower than one frame in 1000 s is no lidar (1e-9 Hz overflowed the int32 stamps)."""
MAX_FRAME_RATE_HZ = 1e5


class SensorConfig(_Model):
    name: str
    frame_rate_hz: Annotated[float, Field(ge=MIN_FRAME_RATE_HZ, le=MAX_FRAME_RATE_HZ)]
    scan: ScanConfig
    optics: OpticsConfig
    detection: DetectionConfig
    receiver: ReceiverConfig = ReceiverConfig()
    range_error: RangeErrorConfig | None = Field(
        None, description="the sensor's own range error (None: the materials' bias and sigma)")

    @model_serializer(mode='wrap')
    def _dump(self, handler):
        return _without_unset_new_keys(handler(self), ('range_error',))

    @field_validator('scan')
    @classmethod
    def _scan_fits_frame(cls, scan, info):
        rate = info.data.get('frame_rate_hz')
        if rate is None:
            return scan
        period = 1.0 / rate
        if isinstance(scan, RisleyScan):
            n = np.floor(scan.shot_rate_hz * period + 1e-9)
            if n < 1:
                raise ValueError(f'shot_rate_hz {scan.shot_rate_hz:g} fires no shot in a frame of '
                                 f'{period:g} s')
            if n > MAX_SHOTS_PER_FRAME:
                raise ValueError(f'shot_rate_hz {scan.shot_rate_hz:g} fires {n:g} shots a frame of '
                                 f'{period:g} s: they exceed the limit of {MAX_SHOTS_PER_FRAME}')
        if isinstance(scan, FlashScan) and scan.row_readout_s * (scan.rows - 1) >= period:
            raise ValueError(f'row_readout_s x (rows - 1) = {scan.row_readout_s * (scan.rows - 1):g} s '
                             f'does not fit the frame period {period:g} s')
        return scan

    @field_validator('optics')
    @classmethod
    def _flood_for_flash(cls, optics, info):
        scan = info.data.get('scan')
        if isinstance(scan, FlashScan) and optics.flood is None:
            raise ValueError('a flash scan needs optics.flood (the illuminated field): its pixels '
                             'share one pulse')
        if scan is not None and not isinstance(scan, FlashScan) and optics.flood is not None:
            raise ValueError('optics.flood is for a flash scan (type: flash): a scanning sensor '
                             'fires a beam per shot')
        return optics

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self.frame_rate_hz


def with_frame_rate(sensor: SensorConfig, rate_hz: float, source: str | Path) -> SensorConfig:
    """``sensor`` at another frame rate, validated like the file (a copy with ``update``
    would skip the checks); ConfigError names ``source``, key ``rate_hz`` and the value."""
    try:
        return SensorConfig.model_validate({**sensor.model_dump(), 'frame_rate_hz': rate_hz})
    except ValidationError as exc:
        raise ConfigError(source, 'rate_hz', rate_hz, exc.errors()[0]['msg']) from None


# ------------------------------------------------------------------ materials
MAX_RANGE_ERROR_M = 100.0
"""Largest per-material range bias or sigma (m): the paper's are millimetres; a bias of
1e300 m published infinite points."""


class MaterialConfig(_Model):
    """Modified Phong parameters (paper Eq. 5) and range error (paper Table 2)."""

    name: str = Field(min_length=1)
    kd: Fraction = Field(description='diffuse reflectivity')
    ks: Fraction = Field(description='specular reflectivity')
    n: NonNegFloat = Field(description='specular exponent')
    bias_m: Annotated[float, Field(ge=-MAX_RANGE_ERROR_M, le=MAX_RANGE_ERROR_M)] = Field(
        description='range bias, measured minus true (m)')
    sigma_m: Annotated[float, Field(ge=0.0, le=MAX_RANGE_ERROR_M)] = Field(
        description='range random error, 1 sigma (m)')

    @model_validator(mode='after')
    def _energy(self):
        if self.kd + self.ks > 1.0 + 1e-9:
            raise ValueError(f'kd + ks = {self.kd + self.ks:g} > 1 violates energy conservation')
        return self


class MaterialsConfig(_Model):
    materials: list[MaterialConfig] = Field(min_length=1)

    @field_validator('materials')
    @classmethod
    def _unique(cls, v):
        names = [m.name for m in v]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f'duplicate material names {sorted(dup)}')
        if len(v) > 255:
            raise ValueError('at most 255 materials fit the uint8 material field')
        return v

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.materials]

    def index(self, name: str) -> int:
        return self.names.index(name)

    def column(self, attr: str) -> np.ndarray:
        """One parameter for all materials as a float array indexed by material id."""
        return np.array([getattr(m, attr) for m in self.materials], dtype=float)


# ------------------------------------------------------------------- scenario
MAX_POSITION_M = 1.0e5
"""A target position component beyond 100 km (m) is no rendezvous (a 1e300 m start
overflowed in the trajectory with a message naming neither file nor key)."""
MIN_POSITION_M = 1.0e-3
MAX_APPROACH_SPEED_MPS = 1.0e4
MAX_TUMBLE_RATE_DPS = 3600.0
Position = Annotated[float, Field(ge=-MAX_POSITION_M, le=MAX_POSITION_M)]


class PoseConfig(_Model):
    """Target body pose in the lidar frame: p_lidar = R(q) p_body + position."""

    position_m: tuple[Position, Position, Position]
    quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    @field_validator('position_m')
    @classmethod
    def _off_the_sensor(cls, p):
        if not float(np.linalg.norm(p)) >= MIN_POSITION_M:
            raise ValueError(f'the target must start at least {MIN_POSITION_M:g} m from the '
                             'sensor (its line of sight is the approach direction)')
        return p

    @field_validator('quat_xyzw')
    @classmethod
    def _unit(cls, q):
        norm = float(np.linalg.norm(q))
        if not abs(norm - 1.0) <= QUAT_NORM_TOL:
            raise ValueError(f'quaternion norm {norm:g} is not within {QUAT_NORM_TOL:g} of 1')
        return tuple(float(x) / norm for x in q)


class MotionConfig(_Model):
    """Relative motion: approach along the line of sight plus a constant tumble."""

    approach_speed_mps: float = Field(0.0, ge=-MAX_APPROACH_SPEED_MPS, le=MAX_APPROACH_SPEED_MPS,
                                      description='closing speed toward the sensor (m/s)')
    tumble_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    tumble_rate_dps: float = Field(0.0, ge=-MAX_TUMBLE_RATE_DPS, le=MAX_TUMBLE_RATE_DPS,
                                   description='tumble rate about tumble_axis, lidar frame (deg/s)')

    @field_validator('tumble_axis')
    @classmethod
    def _nonzero(cls, a):
        # Scaled by its largest component first: the norm of (1e300, 1e300, 0) overflows.
        arr = np.asarray(a, float)
        top = float(np.max(np.abs(arr)))
        if not (np.isfinite(top) and top > 0.0) or not np.linalg.norm(arr / top) > 1e-9:
            raise ValueError('tumble_axis must be non-zero')
        return tuple(float(x) for x in arr / top)


def _unit_vector(v: tuple[float, float, float]) -> tuple[float, float, float]:
    """A direction normalised to unit length; zero, nearly zero or non-finite vectors are
    refused (finite vectors of any size are scaled first: core/vectors.py)."""
    try:
        unit = unit_vector(v)
    except ValueError as exc:
        raise ValueError(f'must be a non-zero finite vector: {exc}') from None
    return tuple(float(x) for x in unit)


class EarthConfig(_Model):
    """The Earth: a diffuse second source lighting the target and the background behind it."""

    direction: tuple[float, float, float] = Field(
        description='toward the Earth centre, lidar frame (normalised)')
    angular_radius_deg: Annotated[float, Field(gt=0.0, lt=90.0)] = Field(
        70.2, description='apparent radius of the Earth disk (deg); 70.2 = 400 km altitude')
    albedo: Fraction = 0.3

    @field_validator('direction')
    @classmethod
    def _unit(cls, v):
        return _unit_vector(v)


MAX_SPECTRAL_IRRADIANCE_W_M2_NM = 1.0e5
"""Brightest sunlight (W m^-2 nm^-1): on the photosphere itself, 0.92 x 215^2 ~ 4e4 at 905 nm
(1 AU is 215 solar radii); a sky radiance is bounded by the sun's own, 0.92 / 6.8e-5 sr
~ 1.4e4 W m^-2 sr^-1 nm^-1. 1e300 was accepted and blinded the receiver."""


class SunConfig(_Model):
    """The scenario's sunlight (docs/sunlight.md). ``direction``: toward the sun, lidar frame."""

    direction: tuple[float, float, float] = Field(
        description='unit vector toward the sun, lidar frame (normalised)')
    spectral_irradiance_w_m2_nm: Annotated[float, Field(
        gt=0.0, le=MAX_SPECTRAL_IRRADIANCE_W_M2_NM)] = Field(
        0.92, description='solar spectral irradiance at the laser wavelength (W m^-2 nm^-1); '
                          '0.92 = ASTM E490 AM0 at 905 nm, 1 AU')
    orbit_rate_dps: float = Field(0.0, ge=-MAX_TUMBLE_RATE_DPS, le=MAX_TUMBLE_RATE_DPS,
                                  description='the sun turns about orbit_axis at this rate '
                                              '(deg/s; offline runs; 0.065 = a 92 min orbit); at '
                                              '1e300 its direction was arbitrary after 0.1 s')
    orbit_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    earth: EarthConfig | None = None
    deep_space_radiance_w_m2_sr_nm: Annotated[float, Field(
        ge=0.0, le=MAX_SPECTRAL_IRRADIANCE_W_M2_NM)] = Field(
        0.0, description='spectral radiance of empty sky (W m^-2 sr^-1 nm^-1)')

    @field_validator('direction', 'orbit_axis')
    @classmethod
    def _unit(cls, v):
        return _unit_vector(v)


class EffectConfig(_Model):
    """An extra physical effect from the catalogue (or module:Class) with its parameters."""

    name: str
    params: dict[str, Any] = Field(default_factory=dict)


def _mesh_materials_shape(value: Any) -> Any:
    """A mesh_materials value is a name, or a map of names to names: said so with the
    offending entry (pydantic's union error named "mesh_materials.str" and asked for a
    string when a map's value was 3)."""
    if value is None or isinstance(value, str):
        return value
    if not isinstance(value, dict):
        raise ValueError('must be one config material name (a whole STL) or a map of the mesh\'s '
                         f'names to config material names ({type(value).__name__} given)')
    for key, name in value.items():
        if not isinstance(key, str) or not isinstance(name, str):
            raise ValueError(f'entry {key!r}: {name!r}: both the mesh\'s name and the config '
                             'material must be strings (quote a name YAML reads as a number)')
    return value


MeshMaterials = Annotated[str | dict[str, str] | None, BeforeValidator(_mesh_materials_shape)]
"""A mesh's names -> config materials, or one material for the whole mesh (core/mesh_files.py)."""


class _MeshMaterialsOnly(_Model):
    mesh_materials: MeshMaterials


def mesh_materials_from_text(text: str, source: str | Path) -> str | dict[str, str]:
    """A mesh_materials value written as YAML text (the node's ``mesh_materials``
    parameter: ``ALUMINIUM`` or ``{bus_mli: MLI, solar_cells: SOLAR_ARRAY}``), checked as
    a scenario's is; ConfigError naming ``source`` and the key."""
    try:
        value = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        raise ConfigError(source, 'mesh_materials', text, f'not valid YAML: {_first_line(exc)}') from None
    check_yaml_size(value, source)
    if value is None:
        raise ConfigError(source, 'mesh_materials', text, 'empty: give one config material or a '
                                                          'map {mesh name: material, ...}')
    return parse(_MeshMaterialsOnly, {'mesh_materials': value}, source).mesh_materials


class ScenarioConfig(_Model):
    seed: Annotated[int, Field(ge=0, lt=2 ** 63)] = Field(
        description='seed of every random draw (numpy takes none below 0)')
    mesh: str
    sensor: str
    materials: str
    frame_id: str = 'lidar'
    initial_pose: PoseConfig
    motion: MotionConfig = MotionConfig()
    sun: SunConfig | None = None
    effects: list[EffectConfig] = Field(default_factory=list)
    mesh_materials: MeshMaterials = Field(
        None, description="the mesh's material/node names -> config materials, or one config "
                          "material for the whole mesh (an STL); None: the mesh's names are the "
                          "config's (core/mesh_files.py)")

    @model_serializer(mode='wrap')
    def _dump(self, handler):
        return _without_unset_new_keys(handler(self), ('mesh_materials',))


# -------------------------------------------------------------------- loading
def _format_loc(loc: tuple) -> str:
    return '.'.join(str(p) for p in loc if not (isinstance(p, str) and p in
                                                 ('lissajous_array', 'rotating', 'file',
                                                                'risley', 'flash')))


def _lookup(data: Any, loc: tuple) -> Any:
    for part in loc:
        try:
            data = data[part]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def _models_in(tp: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation can hold (through Optional, Union, list, Annotated)."""
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return [tp]
    return [m for arg in typing.get_args(tp) for m in _models_in(arg)]


def _fields_at(model: type[BaseModel], loc: tuple) -> set[str]:
    """Field names of the (sub)model that ``loc`` points into: the keys a mapping there may
    have. Union members are chosen by their ``type`` tag where the location names one."""
    types: list[Any] = [model]
    for part in loc:
        nxt: list[Any] = []
        for tp in types:
            if isinstance(part, int):
                nxt.append(tp)  # a list index: the element type is unwrapped below
                continue
            if typing.get_origin(tp) is dict:
                nxt.append(typing.get_args(tp)[1])
                continue
            for m in _models_in(tp):
                if part in m.model_fields:
                    nxt.append(m.model_fields[part].annotation)
                elif 'type' in m.model_fields and part in typing.get_args(
                        m.model_fields['type'].annotation):
                    nxt.append(m)
        types = nxt
    return {f for tp in types for m in _models_in(tp) for f in m.model_fields}


def _did_you_mean(model: type[BaseModel], loc: tuple, data: Any) -> str:
    """' did you mean "seed"?' for an unknown key close to a known one ('' otherwise)."""
    parent = _lookup(data, loc[:-1])
    present = set(parent) if isinstance(parent, dict) else set()
    known = _fields_at(model, loc[:-1])
    # Keys still missing first: "sed" next to a missing "seed" is almost surely a typo.
    for pool in (known - present, known):
        close = difflib.get_close_matches(str(loc[-1]), sorted(pool), n=1, cutoff=0.6)
        if close:
            return f'; did you mean "{close[0]}"?'
    return ''


def parse(model: type[_Model], data: Any, file: str | Path) -> Any:
    """Validate a plain dict against ``model``; raise ConfigError naming file/key/value.

    Of several problems the first unknown key is reported (a typo also leaves its
    intended key missing), with the closest known key as a suggestion.
    """
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        err = next((e for e in errors if e['type'] == 'extra_forbidden'), errors[0])
        loc = tuple(err['loc'])
        key = _format_loc(loc) or '<root>'
        if err['type'] == 'extra_forbidden':
            reason = 'unknown key' + _did_you_mean(model, loc, data)
        elif err['type'] == 'missing':
            reason = 'missing key'
        else:
            reason = err['msg']
        value = err.get('input', _lookup(data, loc)) if err['type'] != 'missing' else None
        more = len(exc.errors()) - 1
        if more:
            reason += f' (and {more} more problem{"s" if more > 1 else ""})'
        raise ConfigError(file, key, value, reason) from None


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader, refusing a key written twice in one mapping (PyYAML keeps the
    last: a mesh_materials map naming a part twice silently took the second material).
    Keys a merge (``<<``) brings in may still be overridden, as YAML says."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == 'tag:yaml.org,2002:merge':
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    if key in seen:
                        raise yaml.constructor.ConstructorError(
                            'while constructing a mapping', node.start_mark,
                            f'found the key {key!r} twice', key_node.start_mark)
                    seen.add(key)
                except TypeError:      # an unhashable key: the base class says so
                    pass
        return super().construct_mapping(node, deep)


def read_yaml(path: str | Path, mapping: bool = False) -> Any:
    """One YAML document, its size bounded (``MAX_YAML_NODES`` with aliases expanded);
    ``mapping``: it must be a mapping (a text file that is not YAML parses as one string,
    which the error then does not print)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, '<file>', str(path), 'file not found')
    try:
        with path.open() as fh:
            data = yaml.load(fh, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        raise ConfigError(path, '<yaml>', None, f'not valid YAML: {_first_line(exc)}') from None
    except UnicodeDecodeError:
        raise ConfigError(path, '<yaml>', None, 'not a text file') from None
    check_yaml_size(data, path)
    if mapping and not isinstance(data, dict):
        raise ConfigError(path, '<root>', type(data).__name__,
                          'expected a YAML mapping of keys to values: is this the right file?')
    return data


def _first_line(exc: Exception) -> str:
    text = ' '.join(str(exc).split())
    return text if len(text) <= 300 else text[:297] + '...'


def check_yaml_size(data: Any, source: str | Path, limit: int = MAX_YAML_NODES) -> None:
    """Refuse a document with more than ``limit`` values once aliases are expanded.

    Validation walks every alias as a copy, so a 1.4 kB alias bomb costs gigabytes;
    the walk here stops as soon as the count passes the limit."""
    count, stack = 0, [data]
    while stack:
        item = stack.pop()
        count += 1
        if count > limit:
            raise ConfigError(source, '<yaml>', None,
                              f'more than {limit} values with aliases expanded (an alias bomb?)')
        if isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)


# What each kind of YAML file must have at its top, and what takes it: a file of one kind
# given where another is expected is named for what it is.
FILE_KINDS: dict[str, tuple[frozenset[str], str]] = {
    'campaign spec': (frozenset({'runs', 'dispersions'}), 'use lidar-sim campaign {file}'),
    'scenario': (frozenset({'mesh', 'sensor', 'materials'}),
                 'use lidar-sim simulate {file}, or name it in a campaign spec\'s "scenario:" key'),
    'sensor file': (frozenset({'scan', 'optics', 'detection'}),
                    'name it in a scenario\'s "sensor:" key, or pass it to '
                    'lidar-sim calibrate scan --sensor'),
    'materials file': (frozenset({'materials'}), 'name it in a scenario\'s "materials:" key'),
}


def file_kind(data: Any) -> str | None:
    """Which kind of configuration ``data`` (a loaded YAML mapping) is, None if unknown."""
    if not isinstance(data, dict):
        return None
    keys = set(data)
    for kind, (required, _) in FILE_KINDS.items():
        if required <= keys and not (kind == 'materials file' and 'mesh' in keys):
            return kind
    return None


def check_file_kind(data: Any, expected: str, file: str | Path) -> None:
    """WrongFileKindError if ``data`` is recognisably another kind of file than ``expected``."""
    kind = file_kind(data)
    if kind is not None and kind != expected:
        hint = FILE_KINDS[kind][1].format(file=file)
        if kind == 'scenario' and expected == 'sensor file':
            hint = f'its sensor file is {data["sensor"]!r} (the "sensor:" key): pass that'
        raise WrongFileKindError(file, kind, expected, hint)


def load_sensor(path: str | Path) -> SensorConfig:
    data = read_yaml(path, mapping=True)
    check_file_kind(data, 'sensor file', path)
    return parse(SensorConfig, data, path)


def load_materials(path: str | Path) -> MaterialsConfig:
    data = read_yaml(path, mapping=True)
    check_file_kind(data, 'materials file', path)
    return parse(MaterialsConfig, data, path)


def resolve(path: str, base: Path) -> Path:
    """Resolve a config-relative path; bare names fall back to the package share dir."""
    p = Path(path).expanduser()
    if p.is_absolute():
        return p
    for root in (base, share_dir() / 'config', share_dir() / 'meshes', share_dir()):
        if (root / p).exists():
            return (root / p).resolve()
    return (base / p).resolve()


def with_sensor_range_error(materials: MaterialsConfig, sensor: SensorConfig) -> MaterialsConfig:
    """The materials with the sensor's own range error (``sensor.range_error``) in place of
    their bias_m and sigma_m (the P-60's Table 2), or unchanged when it has none. Applied
    once, where a scenario is loaded: the simulator, the comparison and the calibrations
    all read the errors from the materials."""
    err = sensor.range_error
    if err is None:
        return materials
    return MaterialsConfig(materials=[m.model_copy(update={'bias_m': err.bias_m, 'sigma_m': err.sigma_m})
                                      for m in materials.materials])
