"""Vehicle parts on their own: multibody model, Hertz contact, irregularities, presets, bad input."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from clm_core.errors import InputError, ParameterError, PresetError
from clm_core.params import load_model
from clm_core.vehicle.contact import hertz_constant, hertz_force, solve_contact, static_compression
from clm_core.vehicle.irregularity import (
    DippedJoint,
    Irregularity,
    JointStep,
    Profile,
    WheelFlat,
    band_variance,
    load_profile_csv,
    local_stiffness_change,
    parse_defect,
    psd,
    random_profile,
)
from clm_core.vehicle.multibody import GRAVITY, CarSpec, VehicleNewmark, VehicleType, build_train
from clm_core.vehicle.presets import list_vehicle_presets, load_vehicle, parse_vehicle_data, save_vehicle_file

COACH = load_vehicle("intercity").vehicles["coach"]


# ------------------------------------------------------------------ multibody


def test_static_wheel_loads_are_half_the_axle_loads() -> None:
    tr = build_train([COACH])
    P = tr.static_wheel_loads()
    assert P.shape == (4,)
    # symmetric vehicle: equal wheel loads, summing to half the vehicle weight (one rail)
    np.testing.assert_allclose(P, COACH.total_mass * GRAVITY / 8, rtol=1e-12)
    assert tr.weight_per_rail == pytest.approx(COACH.total_mass * GRAVITY / 2, rel=1e-12)


def test_lever_rule_with_offset_centre_of_gravity() -> None:
    veh = replace(COACH, cg_offset=2.0)  # body CG 2 m behind the mid-point of the bogies
    P = build_train([veh]).static_wheel_loads()
    lc = 0.5 * veh.bogie_spacing
    body_front = 0.5 * veh.body_mass * GRAVITY * (lc - 2.0) / (2 * lc)  # per rail
    body_rear = 0.5 * veh.body_mass * GRAVITY * (lc + 2.0) / (2 * lc)
    unsprung = 0.5 * (veh.bogie_mass + 2 * veh.wheelset_mass) * GRAVITY
    np.testing.assert_allclose(P[:2].sum(), body_front + unsprung, rtol=1e-10)
    np.testing.assert_allclose(P[2:].sum(), body_rear + unsprung, rtol=1e-10)


def test_articulated_trainset_shares_bogies() -> None:
    vf = load_vehicle("thalys")
    tr = vf.train()
    assert len(vf.composition) == 10
    assert tr.n_wheels == 26  # Bo'Bo' + 9 Jacobs/end bogies + Bo'Bo'
    assert tr.bogie_dofs.shape[0] == 13
    assert tr.weight_per_rail * 2 / GRAVITY == pytest.approx(384.06e3, rel=1e-3)
    np.testing.assert_allclose(tr.static_wheel_loads().sum(), tr.weight_per_rail, rtol=1e-10)
    # axle offsets: power car 0, 3, 14, 17 m; the train spans 200.18 m minus the end overhangs
    np.testing.assert_allclose(tr.wheel_offset[:4], [0, 3, 14, 17], atol=1e-12)
    assert tr.wheel_offset[-1] == pytest.approx(200.18 - 2 * (4.075 - 1.5), abs=1e-9)
    # reversed trailing power car mirrors the leading one
    P = tr.static_wheel_loads()
    np.testing.assert_allclose(P[-4:], P[:4][::-1], rtol=1e-10)


def test_newmark_conserves_energy_without_damping() -> None:
    veh = replace(COACH, primary_damping=0.0, secondary_damping=0.0)
    tr = build_train([veh])
    P0 = tr.static_wheel_loads()
    us = tr.static_state(np.zeros(4))
    integ = VehicleNewmark(tr, 1e-3)
    u = us.copy()
    u[tr.body_dofs[0, 0]] += 0.01  # body displaced 10 mm
    integ.set_state(u, None, P0)
    e0 = tr.energy(integ.u, integ.v, us)
    for _ in range(2000):
        z = integ.predict()
        # wheels held at their static position: the force that keeps z = 0 (P = z_free / H)
        P = np.linalg.solve(integ.H, z)
        integ.commit(P)
    assert abs(tr.energy(integ.u, integ.v, us) - e0) < 1e-9 * e0
    np.testing.assert_allclose(integ.u[tr.wheel_dof], 0.0, atol=1e-12)


def test_invalid_vehicle_parameters_are_refused() -> None:
    with pytest.raises(ParameterError, match="body_mass = -1.*must be > 0"):
        replace(COACH, body_mass=-1.0)
    with pytest.raises(ParameterError, match="wheelset_mass = nan.*finite"):
        replace(COACH, wheelset_mass=float("nan"))
    with pytest.raises(ParameterError, match="primary_damping.*>= 0"):
        replace(COACH, primary_damping=-5.0)
    with pytest.raises(ParameterError, match="axle_spacing"):
        replace(COACH, axle_spacing=30.0)
    with pytest.raises(ParameterError, match="cg_offset"):
        replace(COACH, cg_offset=12.0)
    with pytest.raises(ParameterError, match="shares_front_bogie"):
        build_train([CarSpec(COACH, shares_front_bogie=True)])
    with pytest.raises(ParameterError, match="at least one vehicle"):
        build_train([])


# ------------------------------------------------------------------ contact


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"wheel_radius": 0.0}, r"^wheel_radius = 0 m: must be > 0$"),
        ({"wheel_radius": 0.46, "E": math.nan}, r"^E = nan: must be finite"),
        ({"wheel_radius": 0.46, "rail_head_radius": -0.3}, r"^rail_head_radius = -0.3 m: must be > 0$"),
    ],
)
def test_hertz_constant_refuses_bad_radii_and_modulus(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        hertz_constant(**kwargs)


def test_hertz_constant_magnitude() -> None:
    ch = hertz_constant(0.46)  # UIC60 head radius 0.3 m
    assert 0.8e11 < ch < 1.2e11
    assert hertz_constant(0.46, method="zhai") == pytest.approx(ch, rel=0.3)
    # static compression under a 83 kN wheel load: about 0.1 mm
    d = static_compression(np.array([83e3]), ch)[0]
    assert 5e-5 < d < 1.5e-4
    np.testing.assert_allclose(hertz_force(np.array([d]), ch), [83e3], rtol=1e-12)
    with pytest.raises(ParameterError, match="wheel_radius"):
        hertz_constant(-0.46)
    with pytest.raises(ParameterError, match="method"):
        hertz_constant(0.46, method="bogus")


def test_newton_contact_single_wheel_matches_root() -> None:
    ch, A = 1e11, 1e-9  # 1e-9 m/N compliance
    for d0 in (1e-4, 3e-4, 2e-6):
        delta, P, it = solve_contact(np.array([d0]), np.array([[A]]), np.array([ch]), np.array([0.0]))
        ref = brentq(lambda d, d0=d0: d - d0 + A * ch * max(d, 0.0) ** 1.5, -1.0, 1.0, xtol=1e-18)
        assert delta[0] == pytest.approx(ref, rel=1e-9, abs=1e-16)
        assert P[0] == pytest.approx(ch * ref**1.5, rel=1e-8)
        assert it < 30


def test_newton_contact_coupled_wheels_and_loss() -> None:
    rng = np.random.default_rng(3)
    B = rng.normal(size=(4, 4))
    A = 1e-9 * (B @ B.T + 4 * np.eye(4))  # SPD compliance
    d0 = np.array([2e-4, -1e-4, 1e-4, 3e-4])
    ch = np.full(4, 9e10)
    delta, P, _ = solve_contact(d0, A, ch, np.zeros(4))
    np.testing.assert_allclose(delta, d0 - A @ P, atol=1e-14)
    assert np.all(P >= 0)
    np.testing.assert_allclose(P, hertz_force(delta, ch), rtol=1e-12)
    assert P[1] == 0.0 and delta[1] < 0  # that wheel is lifted off
    with pytest.raises(InputError, match="did not converge"):
        solve_contact(np.array([np.nan]), np.array([[1e-9]]), np.array([1e11]), np.array([0.0]))


# ------------------------------------------------------------------ irregularities


def test_psd_formulas() -> None:
    om = np.array([0.5, 1.0, 2.0])
    Av, Oc = 0.2095e-4, 0.8245
    np.testing.assert_allclose(psd("fra5", om), 0.25 * Av * Oc**2 / (om**2 * (om**2 + Oc**2)), rtol=1e-14)
    Av, Oc, Or = 4.032e-7, 0.8246, 0.0206
    np.testing.assert_allclose(psd("german-low", om), Av * Oc**2 / ((om**2 + Or**2) * (om**2 + Oc**2)), rtol=1e-14)
    # FRA class 6 is the smoothest, class 1 the roughest
    s = [psd(f"fra{k}", np.array([1.0]))[0] for k in range(1, 7)]
    assert all(a > b for a, b in itertools.pairwise(s))
    assert psd("german-high", om)[0] > psd("german-low", om)[0]
    with pytest.raises(ParameterError, match="unknown"):
        psd("fra7", om)


@pytest.mark.parametrize("spectrum", ["fra5", "german-low"])
def test_random_profile_variance_band_and_seed(spectrum: str) -> None:
    band = (1.0, 50.0)
    prof = random_profile(spectrum, -10.0, 400.0, seed=1, band=band)
    assert prof.x[0] == -10.0 and prof.x[-1] >= 390.0
    # variance of the synthesis = Riemann sum of the PSD over the band; the
    # 400 m sample holds most of one 819 m period, hence 10 %
    assert prof.rms() ** 2 == pytest.approx(band_variance(spectrum, band), rel=0.10)
    # same seed, same profile; another seed, another one
    np.testing.assert_array_equal(prof.r, random_profile(spectrum, -10.0, 400.0, seed=1, band=band).r)
    assert not np.allclose(prof.r, random_profile(spectrum, -10.0, 400.0, seed=2, band=band).r)
    # no content outside the band: wavelengths < 1 m
    dx = prof.x[1] - prof.x[0]
    spec = np.abs(np.fft.rfft(prof.r * np.hanning(prof.r.size))) ** 2
    k = np.fft.rfftfreq(prof.r.size, dx)  # 1/m
    assert spec[k > 2.0].sum() < 1e-6 * spec.sum()


def test_profile_csv_sign_and_errors(tmp_path: Path) -> None:
    f = tmp_path / "prof.csv"
    f.write_text("# measured\nposition_m,elevation_m\n0,0\n1,0.001\n2,-0.002\n")
    prof = load_profile_csv(f)
    np.testing.assert_allclose(prof.r, [0.0, -0.001, 0.002])  # r = -elevation (down positive)
    assert prof(np.array([1.5]))[0] == pytest.approx(0.0005)
    with pytest.raises(InputError, match="covers"):
        prof(np.array([5.0]))
    bad = tmp_path / "bad.csv"
    bad.write_text("0,0\n2,0\n1,0\n")
    with pytest.raises(InputError, match="increase strictly"):
        load_profile_csv(bad)
    bad.write_text("0,0\n1,nan\n")
    with pytest.raises(InputError, match="non-finite"):
        load_profile_csv(bad)
    with pytest.raises(InputError, match="not found"):
        load_profile_csv(tmp_path / "missing.csv")


def test_isolated_defects_geometry() -> None:
    dj = DippedJoint(x=10.0, depth=0.004, half_length=0.8)
    assert dj.total_angle == pytest.approx(0.01)
    np.testing.assert_allclose(dj(np.array([9.0, 9.6, 10.0, 10.4, 11.0])), [0, 0.002, 0.004, 0.002, 0])
    # step up of 1 mm met by a 0.46 m wheel over sqrt(2 R h) before the joint
    st = JointStep(x=5.0, height=0.001)
    u0 = math.sqrt(2 * 0.46 * 0.001)
    r = st(np.array([5.0 - u0 - 1e-3, 5.0 - u0 / 2, 5.0, 6.0]), 0.46)
    assert r[0] == 0.0 and -0.001 < r[1] < 0.0 and r[2] == pytest.approx(-0.001) and r[3] == pytest.approx(-0.001)
    down = JointStep(x=5.0, height=-0.001)(np.array([4.0, 5.0 + u0 / 2, 7.0]), 0.46)
    assert down[0] == 0.0 and 0 < down[1] < 0.001 and down[2] == pytest.approx(0.001)
    # wheel flat: periodic with the circumference, depth L^2 / (16 R) for a rounded flat
    fl = WheelFlat(wheel=0, x=3.0, length=0.06)
    R = 0.46
    c = 2 * math.pi * R
    d = fl.drop(np.array([3.0, 3.0 + c, 3.0 - c, 3.0 + 0.03, 3.5]), R)
    np.testing.assert_allclose(d[:3], 0.06**2 / (16 * R), rtol=1e-12)
    assert d[3] == pytest.approx(0.0, abs=1e-15) and d[4] == 0.0
    fresh = WheelFlat(wheel=0, x=0.0, length=0.06, shape="fresh").drop(np.array([0.0]), R)
    assert fresh[0] == pytest.approx(R - math.sqrt(R**2 - 0.03**2))
    irr = Irregularity(defects=(dj,), flats=(fl,))
    X = np.array([[10.0, 3.0], [3.0, 10.0]])
    out = irr.wheel_irregularity(X, X[0], np.array([R, R]))
    assert out[0, 0] == pytest.approx(0.004) and out[0, 1] == 0.0  # flat is on wheel 0 only
    assert out[1, 0] == pytest.approx(0.06**2 / (16 * R)) and out[1, 1] == pytest.approx(0.004)


def test_parse_defect_forms_and_errors() -> None:
    d = parse_defect("dipped-joint:x=50,angle=0.01,half_length=0.5")
    assert isinstance(d, DippedJoint) and d.depth == pytest.approx(0.0025)
    assert isinstance(parse_defect("joint-step:x=1,height=-0.001"), JointStep)
    f = parse_defect("wheel-flat:wheel=2,x=20,length=0.05,shape=fresh")
    assert isinstance(f, WheelFlat) and f.wheel == 2
    s = parse_defect("stiffness:from=30,to=36,kb=20e6")
    assert s == {"from": 30.0, "to": 36.0, "kb": 20e6}
    for bad, msg in [
        ("dipped-joint:x=1", "missing depth"),
        ("dipped-joint:x=1,depth=nan", "finite"),
        ("dipped-joint:x=1,depth=-0.001", "must be > 0"),
        ("crack:x=1", "unknown"),
        ("joint-step:x=1,height=0.001,foo=2", "unknown key"),
        ("stiffness:from=1,to=2", "at least one"),
    ]:
        with pytest.raises(ParameterError, match=msg):
            parse_defect(bad)


def test_local_stiffness_change_builds_override() -> None:
    params = load_model("mevergnies", "mevergnies", "clm")
    p2 = local_stiffness_change(params, 3.0, 4.9, values={"kb": 20e6}, factors={"kp": 0.5})
    ov = p2.overrides[-1]
    assert ov.sleepers == (5, 6, 7, 8)  # x = 3.0, 3.6, 4.2, 4.8 m
    assert ov.values == {"kb": 20e6, "kp": 60e6}
    with pytest.raises(ParameterError, match="no sleeper"):
        local_stiffness_change(params, 3.1, 3.2, values={"kb": 1e6})
    with pytest.raises(ParameterError, match="unknown parameter"):
        local_stiffness_change(params, 0, 1, values={"kq": 1.0})


# ------------------------------------------------------------------ presets and files


def test_presets_load() -> None:
    names = list_vehicle_presets()
    assert {"thalys", "intercity", "tram"} <= set(names)
    for n in names:
        tr = load_vehicle(n).train()
        assert np.all(tr.static_wheel_loads() > 0)
        f = tr.natural_frequencies()
        assert 0.5 < f.min() < 2.0  # car body bounce/pitch ~ 1 Hz


def test_user_vehicle_file_round_trip(tmp_path: Path) -> None:
    vf = load_vehicle("thalys")
    path = tmp_path / "my-train.yaml"
    save_vehicle_file(vf, path)
    back = load_vehicle(str(path))
    assert back.vehicles == dict(vf.vehicles)
    assert back.composition == vf.composition
    np.testing.assert_allclose(back.train(3).static_wheel_loads(), vf.train(3).static_wheel_loads())


def test_bad_vehicle_input(tmp_path: Path) -> None:
    with pytest.raises(PresetError, match="unknown vehicle preset 'maglev'.*thalys"):
        load_vehicle("maglev")
    with pytest.raises(PresetError, match="not found"):
        load_vehicle(str(tmp_path / "none.yaml"))
    base = {k: v for k, v in COACH.to_dict().items() if k != "name"}
    with pytest.raises(ParameterError, match="vehicle file.*'c': body_mass = -30000: must be > 0"):
        parse_vehicle_data({"vehicles": {"c": {**base, "body_mass": -3e4}}})
    with pytest.raises(ParameterError, match="bogie_mass = nan"):
        parse_vehicle_data({"vehicles": {"c": {**base, "bogie_mass": float("nan")}}})
    with pytest.raises(PresetError, match="unknown parameter.*'mass'"):
        parse_vehicle_data({"vehicles": {"c": {**base, "mass": 1.0}}})
    with pytest.raises(PresetError, match="missing parameter.*wheel_radius"):
        parse_vehicle_data({"vehicles": {"c": {k: v for k, v in base.items() if k != "wheel_radius"}}})
    with pytest.raises(PresetError, match="unknown vehicle 'x'"):
        parse_vehicle_data({"vehicles": {"c": base}, "train": ["c", "x"]})
    with pytest.raises(ParameterError, match="--cars 11"):
        load_vehicle("thalys").cars(11)
    p = tmp_path / "broken.yaml"
    p.write_text("vehicles: [1, 2\n")
    with pytest.raises(PresetError, match="not valid YAML"):
        load_vehicle(str(p))


def test_profile_refuses_nan() -> None:
    with pytest.raises(InputError, match="non-finite"):
        Profile(x=np.array([0.0, 1.0]), r=np.array([0.0, np.nan]))
    with pytest.raises(ParameterError, match="wavelength band"):
        random_profile("fra5", 0.0, 10.0, seed=0, band=(50.0, 1.0))


def test_vehicle_type_requires_name() -> None:
    with pytest.raises(ParameterError, match="name"):
        VehicleType(name="", **{k: v for k, v in COACH.to_dict().items() if k != "name"})
