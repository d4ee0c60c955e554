"""calibrate scan on a Risley sensor (calibrate/scan_risley.py): the prism rates of a
recording, found among the periodogram's aliases, written as a sensor that reloads."""
import numpy as np
import pytest

from lidar_sim_ros.calibrate.scan_pattern import run_scan
from lidar_sim_ros.calibrate.scan_risley import fit_prisms
from lidar_sim_ros.core.config import load_sensor
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.offline import simulate_to_bag
from conftest import CONFIG


def test_fit_prisms_closed_form_with_gaps():
    """z(t) = a1 e^{2 pi i f1 t} + a2 e^{2 pi i f2 t} seen only where it crosses a band
    (the target's gaps): the rates and amplitudes come back, not an alias."""
    f, a = np.array([37.25, -23.5]), np.array([0.1 * np.exp(0.4j), 0.08 * np.exp(-2.0j)])
    t = np.arange(0, 0.6, 2e-5)
    z = np.exp(2j * np.pi * np.outer(t, f)) @ a
    seen = (z.real > -0.02) & (z.real < 0.09) & (z.imag > -0.05)       # a patch of the field
    rates, amp = fit_prisms(t[seen], z[seen])
    order = np.argsort(-np.abs(amp))
    np.testing.assert_allclose(rates[order], f, atol=1e-7)
    np.testing.assert_allclose(amp[order], a, atol=1e-9)


def test_mid40_recording_gives_back_its_prism_rates(tmp_path):
    sc = load_scenario(CONFIG / 'scenario_mid40.yaml')
    run = simulate_to_bag(sc, tmp_path / 'run', frames=3, start_s=0.3, figures=False)
    # Start from wrong rates: the fit does not need them.
    start = tmp_path / 'start.yaml'
    start.write_text((CONFIG / 'livox_mid40.yaml').read_text()
                     .replace('prism_rates_hz: [121.56666666666666, -77.73333333333333]',
                              'prism_rates_hz: [100.0, -50.0]'))
    cal = run_scan(run.bag_path, tmp_path / 'fitted.yaml', start, tmp_path / 'fit.png')
    truth = load_sensor(CONFIG / 'livox_mid40.yaml').scan
    fitted = load_sensor(cal.out).scan
    assert sorted(fitted.prism_rates_hz) == pytest.approx(sorted(truth.prism_rates_hz), abs=1e-4)
    assert fitted.prism_deviation_deg == pytest.approx((9.6, 9.6), abs=1e-4)
    assert fitted.shot_rate_hz == pytest.approx(100000.0, rel=1e-5)
    assert cal.rms_deg < 1e-3 and cal.prior_error_deg.mean() > 1.0
    assert (tmp_path / 'fit.png').stat().st_size > 0
    assert '7294.00 rpm' in cal.report and '-4664.00 rpm' in cal.report


def hours_samples():
    """3,000 Mid-40 shots of each of frames 0-2 at their own times, and of frame 3 10^4 s
    after the first."""
    from lidar_sim_ros.calibrate.scan_samples import ScanSamples
    from lidar_sim_ros.core.scan_risley import risley_frame
    sensor = load_sensor(CONFIG / 'livox_mid40.yaml')
    t, d, frame = [], [], []
    for k in range(4):
        shots, directions = risley_frame(sensor.scan, sensor.frame_period_s, k)
        t.append(shots.t_s[:3000]), d.append(directions[:3000]), frame.append(np.full(3000, k))
    t, d = np.concatenate(t), np.concatenate(d)
    return ScanSamples(t, np.zeros_like(t), np.zeros_like(t), d, None, np.concatenate(frame),
                       None, 'hours.bag', np.array([0.0, 0.1, 0.2, 1e4]))


def test_a_recording_spanning_hours_is_fitted_on_its_first_stretch(monkeypatch):
    """The periodogram's grid grows with the time the clouds span, not with the points:
    two 2,000-point clouds 10^4 s apart asked for 32 GiB (100 s apart took 949 MB, 14 s).
    The fit now reads the first MAX_FIT_SPAN_S of the recording and says so."""
    from lidar_sim_ros.calibrate import scan_risley
    sensor = load_sensor(CONFIG / 'livox_mid40.yaml')
    monkeypatch.setattr(scan_risley, 'MAX_FIT_SPAN_S', 0.35)
    cal = scan_risley.calibrate_risley(hours_samples(), CONFIG / 'livox_mid40.yaml')
    assert any('the clouds span 10000 s; the prisms are fitted on the first 0.35 s (9000 of 12000 '
               'points)' in w for w in cal.warnings), cal.warnings
    assert len(cal.samples) == 9000
    assert sorted(cal.rates_hz) == pytest.approx(sorted(sensor.scan.prism_rates_hz), abs=1e-6)


def test_run_scan_on_a_recording_spanning_hours_writes_the_fit_of_its_first_stretch(
        tmp_path, monkeypatch):
    """Through lidar-sim calibrate scan's own function: the error of the written file is
    computed on the points fitted (the trimming first went into run_risley as well, where
    it raised NameError)."""
    from lidar_sim_ros.calibrate import scan_risley
    monkeypatch.setattr(scan_risley, 'MAX_FIT_SPAN_S', 0.35)
    samples = hours_samples()
    monkeypatch.setattr(scan_risley, 'read_scan_samples', lambda *a, **k: samples)
    cal = run_scan(tmp_path / 'hours.bag', tmp_path / 'fitted.yaml', CONFIG / 'livox_mid40.yaml')
    assert len(cal.samples) == len(cal.error_deg) == 9000 and cal.rms_deg < 1e-3
    assert any('the clouds span 10000 s' in w for w in cal.warnings)   # printed by the CLI


def test_prisms_the_search_cannot_reach_stop_instead_of_writing_an_alias():
    """Prisms at 1500 and -900 rev/s (the sensor config allows 10,000; the periodogram
    searches +-1000): the fit returned -900 and 294.7 rev/s, RMS 9.6 deg, no warning, and
    calibrate scan wrote that sensor (rc 0). A fit that leaves more than MAX_FIT_RMS_DEG
    now stops naming the rates, the error and the search range."""
    from lidar_sim_ros.calibrate.common import CalibrationInputError
    from lidar_sim_ros.calibrate.scan_risley import calibrate_risley
    from lidar_sim_ros.calibrate.scan_samples import ScanSamples
    from lidar_sim_ros.core.scan_risley import risley_frame
    sensor = load_sensor(CONFIG / 'livox_mid40.yaml')
    fast = sensor.scan.model_copy(update={'prism_rates_hz': (1500.0, -900.0)})
    rng = np.random.default_rng(0)
    t, d, frame = [], [], []
    for k in range(3):
        shots, directions = risley_frame(fast, sensor.frame_period_s, k)
        keep = np.sort(rng.choice(len(shots), 4000, replace=False))
        t.append(shots.t_s[keep]), d.append(directions[keep]), frame.append(np.full(4000, k))
    t, d = np.concatenate(t), np.concatenate(d)
    samples = ScanSamples(t, np.zeros_like(t), np.zeros_like(t), d, None, np.concatenate(frame),
                          None, 'fast.bag', np.array([0.0, 0.1, 0.2]))
    with pytest.raises(CalibrationInputError, match=r'fast.bag: the best prism pair found .* RMS '
                                                    r'[\d.]+ deg, more than 2 deg.*1000 rev/s'):
        calibrate_risley(samples, CONFIG / 'livox_mid40.yaml')
