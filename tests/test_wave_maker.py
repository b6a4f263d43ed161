"""sph validate wave_maker's pieces: the dispersion relation's wavenumber, the piston's transfer
function in its shallow and deep limits, the harmonic fit that reads a gauge's wave height and
phase through noise and a steeper crest, and the two-gauge split into incident and reflected waves. (The case itself runs in `sph validate wave_maker`: two
minutes quick.)"""
import math

import numpy as np
import pytest

from launch.validate import (CONFIGS, PistonWave, harmonic, incident_and_reflected, piston_height_per_stroke,
                             water_wavenumber)
from sphcore.scene import load_scene


@pytest.mark.fast
@pytest.mark.parametrize("depth, f", [(0.1, 1.4), (0.01, 0.2), (5.0, 2.0)])
def test_the_wavenumber_solves_the_dispersion_relation(depth, f):
    g, omega = 9.81, 2.0 * math.pi * f
    k = water_wavenumber(omega, depth, g)
    assert g * k * math.tanh(k * depth) == pytest.approx(omega ** 2, rel=1e-12)
    if k * depth < 0.1:  # shallow water: c = sqrt(g d)
        assert omega / k == pytest.approx(math.sqrt(g * depth), rel=0.01)
    if k * depth > 3.0:  # deep water: k = omega^2 / g
        assert k == pytest.approx(omega ** 2 / g, rel=0.01)


@pytest.mark.fast
def test_the_piston_transfer_function_has_its_limits():
    assert piston_height_per_stroke(0.01) == pytest.approx(0.01, rel=1e-3)  # shallow: H / S = kd
    assert piston_height_per_stroke(10.0) == pytest.approx(2.0, rel=1e-3)  # deep: H / S = 2
    assert piston_height_per_stroke(1.0229518) == pytest.approx(1.0027, abs=1e-4)  # the scene's kd
    ks = np.linspace(0.05, 5.0, 50)
    assert np.all(np.diff([piston_height_per_stroke(k) for k in ks]) > 0)


@pytest.mark.fast
def test_the_harmonic_fit_reads_height_and_phase_through_noise_and_a_second_harmonic():
    omega, t = 2.0 * math.pi * 1.4, np.arange(0.0, 4.0 / 1.4, 1e-3)
    rng = np.random.default_rng(7)
    eta = (0.02 + 0.0075 * np.cos(omega * t - 1.1) + 0.002 * np.cos(2 * omega * t - 0.3)
           + 0.001 * rng.standard_normal(t.size))
    amplitude, phase = harmonic(t, eta, omega)
    assert amplitude == pytest.approx(0.0075, rel=0.01)
    assert phase == pytest.approx(1.1, abs=0.01)
    # a wave running along +x reaches a gauge 0.2 m further on k 0.2 later in phase
    k = water_wavenumber(omega, 0.1, 9.81)
    _, here = harmonic(t, 0.0075 * np.cos(omega * t - 1.1), omega)
    _, later = harmonic(t, 0.0075 * np.cos(omega * t - 1.1 - k * 0.2), omega)
    assert (later - here) % (2 * math.pi) == pytest.approx(k * 0.2, abs=1e-9)


@pytest.mark.fast
def test_the_scene_is_the_case_the_theory_describes():
    scene = load_scene(CONFIGS / "wave_maker_2d.toml")
    piston = [p for p in scene.domain.planes if p.frequency > 0.0]
    assert len(piston) == 1 and piston[0].normal[0] == 1.0 and piston[0].phase == -90.0
    wave = PistonWave.of(scene)
    assert wave.depth == 0.1 and wave.stroke == pytest.approx(0.015)
    assert 0.9 < wave.k * wave.depth < 1.1  # intermediate depth, as the header says
    assert wave.height == pytest.approx(0.015 * piston_height_per_stroke(wave.k * wave.depth))
    assert 9.81 * wave.k * math.tanh(wave.k * wave.depth) == pytest.approx(wave.omega ** 2)
    assert [p.kind for p in scene.probes] == ["height", "height"]


@pytest.mark.fast
@pytest.mark.parametrize("reflected, lag", [(0.0, 0.0), (0.2, 0.7), (0.9, 2.5)])
def test_two_gauges_split_a_partial_standing_wave_into_its_incident_and_reflected_parts(reflected, lag):
    omega, t = 2.0 * math.pi * 1.4, np.arange(0.0, 4.0 / 1.4, 1e-3)
    k, gauges = water_wavenumber(omega, 0.1, 9.81), (0.3, 0.5)
    fits = [harmonic(t, 0.0075 * np.cos(omega * t - k * x) + 0.0075 * reflected * np.cos(omega * t + k * x + lag),
                     omega) for x in gauges]
    incident, back = incident_and_reflected(fits, gauges, k)
    assert incident == pytest.approx(0.0075, rel=1e-9)
    assert back == pytest.approx(0.0075 * reflected, abs=1e-12)


@pytest.mark.fast
def test_the_flume_ends_in_a_damping_zone_behind_both_gauges():
    scene = load_scene(CONFIGS / "wave_maker_2d.toml")
    (zone,) = scene.damping_zones
    wave = PistonWave.of(scene)
    assert zone.direction[0] == 1.0 and zone.max[0] == scene.domain.planes[1].point[0]  # up to the far wall
    assert zone.max[0] - zone.min[0] >= 2 * math.pi / wave.k  # at least a wavelength long
    assert all(p.at[0] < zone.min[0] for p in scene.probes)
