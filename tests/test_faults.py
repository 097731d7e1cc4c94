"""Faults in the mission (docs/model.md §8.7): a wheel that fails off delivers no motor
torque from its fault tick on, the others absorb the command once the loop knows of it
(the pseudo-inverse over the available wheels), a star-tracker outage leaves the MEKF on
the gyro alone (its covariance growing as the gyro's random walks predict), a gyro bias
step enters the true bias, and a fault past the horizon changes nothing."""

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.components.actuators import Ideal
from so3jax.missions import faults as fault_list
from so3jax.missions import mission as missions
from so3jax.sim.loop import check_loop

FAULT, LATENCY, OUTAGE_END = 5.0, 3.0, 10.0  # [s]
STEP = [2e-4, -1e-4, 3e-4]  # gyro bias step [rad/s]
BASE = {"T": 20.0, "controllers": ["pd"], "record_every": 10, "momentum": {"kind": "none"},
        "initial": {"attitude": [0.01, -0.02, 0.015]},
        "disturbance": {"amplitude": 0.02, "noise_std": 0.005}}


def faulted(time=FAULT, end=OUTAGE_END, latency: float | None = LATENCY) -> dict:
    """The base mission with wheel 1 off, a star-tracker outage and a gyro bias step."""
    faults = [{"time": time, "wheel": 1, "mode": "off"},
              {"time": time, "end": end, "star_tracker": "outage"},
              {"time": time, "gyro": "bias step", "step": STEP}]
    fdir = {"detection": "never"} if latency is None else {"latency": latency}
    return {**BASE, "faults": faults, "fdir": fdir}


def fly(d: dict):
    m = missions.from_dict(d)
    controller, gains = m.controller("pd")
    result = sj.simulate(m.scenario(), controller, gains, m.seed, loop=m.loop(), record_every=m.record_every)
    return m, jax.tree.map(lambda x: None if x is None else np.asarray(x), result.history)


@pytest.fixture(scope="module")
def flights():
    """The nominal flight, and the faulted one with and without detection (one compilation for both)."""
    return {"nominal": fly(BASE), "detected": fly(faulted()), "unaware": fly(faulted(latency=None))}


def axes(m):
    return np.asarray(m.actuator["wheels"]["axes"], float).T  # G_s (3, N)


def compensation(m, h):
    """Omega_hat x h_w_hat (M, 3) of each tick (docs/model.md (8.11)), from the records."""
    G, J_s = axes(m), np.asarray(m.actuator["wheels"]["spin_inertia"], float)
    h_w = (G @ (J_s * (h.Omega_hat @ G + h.actuator)).T).T
    return np.cross(h.Omega_hat, h_w)


# --- wheels ----------------------------------------------------------------------------------------


def test_a_wheel_off_is_dropped_from_the_distribution_after_detection():
    """At a tick, before the fault: all four wheels share the command; after it, unaware:
    wheel 1 gets the nominal command and delivers 0; detected: u = -W G^T (G W G^T)^{-1} tau,
    the minimum-norm solution over wheels 2-4 (NumPy's pseudo-inverse)."""
    m = missions.from_dict(faulted())
    loop = m.loop(jnp.float64)
    G = axes(m)
    tau = jnp.asarray([0.03, -0.05, 0.02])
    zero = jnp.zeros(3)
    speeds = jnp.zeros(4)

    def u_at(t):
        wheels = loop.faults.actuator(loop.actuator, jnp.asarray(t))
        return np.asarray(wheels.command(speeds, tau, zero).u)

    nominal = -np.linalg.pinv(G) @ np.asarray(tau)
    np.testing.assert_allclose(u_at(FAULT - 0.1), nominal, rtol=1e-13, atol=1e-16)
    unaware = u_at(FAULT)
    assert unaware[0] == 0.0
    np.testing.assert_allclose(unaware[1:], nominal[1:], rtol=1e-13, atol=1e-16)
    detected = u_at(FAULT + LATENCY)
    assert detected[0] == 0.0
    np.testing.assert_allclose(detected[1:], -np.linalg.pinv(G[:, 1:]) @ np.asarray(tau), rtol=1e-12, atol=1e-16)
    np.testing.assert_allclose(-G @ detected, tau, rtol=1e-12, atol=1e-16)


def test_a_degraded_wheel_has_its_torque_limit_scaled():
    m = missions.from_dict({**BASE, "faults": [{"time": 2.0, "wheel": 3, "mode": "degraded", "factor": 0.25}]})
    loop = m.loop(jnp.float64)
    u_max = np.asarray(m.actuator["wheels"]["max_torque"], float)
    for t, scale in ((1.9, [1, 1, 1, 1]), (2.0, [1, 1, 0.25, 1])):
        wheels = loop.faults.actuator(loop.actuator, jnp.asarray(t))
        np.testing.assert_array_equal(np.asarray(wheels.max_torque), u_max * np.asarray(scale))
        u = np.asarray(wheels.command(jnp.zeros(4), jnp.asarray([2.0, 2.0, 2.0]), jnp.zeros(3)).u)
        assert np.all(np.abs(u) <= u_max * np.asarray(scale))


def test_a_wheel_off_delivers_no_motor_torque_from_its_fault_tick(flights):
    """Without a motor torque a frictionless wheel keeps its axial momentum
    J_s (g_1 . Omega + Omega_w,1) (docs/model.md (8.13)): constant from the fault's tick on."""
    for name in ("detected", "unaware"):
        m, h = flights[name]
        g1 = axes(m)[:, 0]
        axial = h.Omega @ g1 + h.actuator[:, 0]
        after = h.t >= FAULT
        np.testing.assert_allclose(axial[after], axial[after][0], rtol=0, atol=1e-12)
        assert np.ptp(axial[~after]) > 1e-6  # before, its motor drives it


def test_the_others_absorb_the_command_once_the_fault_is_detected(flights):
    """delivered = tau_cmd before the fault and after its detection (no limit binds);
    between, and throughout without detection, it lacks wheel 1's share:
    delivered - tau_cmd = g_1 u_1, u_1 the nominal distribution's."""
    for name in ("detected", "unaware"):
        m, h = flights[name]
        G = axes(m)
        u_max = float(np.max(m.actuator["wheels"]["max_torque"]))
        wanted = h.tau_cmd + compensation(m, h)
        u1 = (-np.linalg.pinv(G) @ wanted.T)[0]
        assert np.max(np.abs(-np.linalg.pinv(G[:, 1:]) @ wanted.T)) < 0.99 * u_max  # no limit binds
        scale = np.abs(h.tau_cmd).max()
        before = h.t < FAULT
        np.testing.assert_allclose(h.tau[before], h.tau_cmd[before], rtol=0, atol=1e-12 * scale)
        known = h.t >= (FAULT + LATENCY if name == "detected" else np.inf)
        np.testing.assert_allclose(h.tau[known], h.tau_cmd[known], rtol=0, atol=1e-12 * scale)
        lost = ~before & ~known
        assert lost.sum() >= 30
        np.testing.assert_allclose(h.tau[lost] - h.tau_cmd[lost], g1_share(G, u1[lost]), rtol=0,
                                   atol=1e-12 * scale)
        assert np.abs(u1[lost]).max() > 1e-4


def g1_share(G, u1):
    return u1[:, None] * G[:, 0][None, :]


# --- sensors ---------------------------------------------------------------------------------------


def test_an_outage_has_no_star_tracker_sample():
    m = missions.from_dict(faulted())
    faults = m.loop(jnp.float64).faults
    for t, out in ((FAULT - 0.1, False), (FAULT, True), (OUTAGE_END - 0.1, True), (OUTAGE_END, False)):
        assert bool(faults.outage(jnp.asarray(t))) is out


def test_the_covariance_grows_on_the_gyro_alone_during_an_outage(flights):
    """P_theta from the last update before the outage, t = t_j - t_0 later, as the gyro's random
    walks predict (docs/model.md (8.19)): A0 - t (B0 + B0^T) + t^2 C0 + (sigma_v^2 t + sigma_u^2 t^3 / 3) I
    in trace; then the samples after it shrink it back."""
    m, h = flights["detected"]
    mekf = m.estimator["mekf"]
    arw, rrw = (float(mekf[k] if mekf.get(k) is not None else m.sensors["gyro"][k]) for k in ("arw", "rrw"))
    P = h.covariance
    out = (h.t >= FAULT) & (h.t < OUTAGE_END)
    j0 = np.flatnonzero(out)[0] - 1
    A0, B0, C0 = P[j0, :3, :3], P[j0, :3, 3:], P[j0, 3:, 3:]
    t = h.t[out] - h.t[j0]
    predicted = (np.trace(A0) - 2 * t * np.trace(B0) + t**2 * np.trace(C0) + 3 * (arw**2 * t + rrw**2 * t**3 / 3))
    attitude = np.trace(P[:, :3, :3], axis1=1, axis2=2)
    np.testing.assert_allclose(attitude[out], predicted, rtol=1e-3)
    assert np.all(np.diff(attitude[out]) > 0)
    assert attitude[out][-1] > 5 * attitude[j0]
    after = np.flatnonzero(h.t >= OUTAGE_END)[0]
    assert attitude[after] < 0.7 * attitude[after - 1]  # one sample of sigma_st^2 = 9e-10 rad^2 per axis
    assert attitude[-1] < 1.5 * attitude[j0]  # back near its level before the outage


def test_a_gyro_bias_step_enters_the_true_bias_and_is_estimated_again(flights):
    _, nominal = flights["nominal"]
    _, h = flights["detected"]
    step = np.where((h.t >= FAULT)[:, None], np.asarray(STEP), 0.0)
    np.testing.assert_allclose(h.bias - nominal.bias, step, rtol=0, atol=1e-18)
    error = np.linalg.norm(h.bias_hat - h.bias, axis=1)
    assert error[np.flatnonzero(h.t >= OUTAGE_END)[0]] > 0.5 * np.linalg.norm(STEP)
    assert error[-1] < 0.5 * np.linalg.norm(STEP)


# --- a fault never reached -------------------------------------------------------------------------


@pytest.mark.optimized
def test_faults_past_the_horizon_change_nothing():
    """Every record bit for bit, but the filter's covariance: selecting the gyro reading
    (a bias step not yet acting) changes how XLA fuses the covariance arithmetic, which
    moves entries that are round-off (off-diagonal, ~1e-33) in their last bits."""
    _, nominal = fly(BASE)
    _, late = fly(faulted(time=1e6, end=2e6))
    for field in nominal._fields:
        a, b = getattr(nominal, field), getattr(late, field)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            if field == "covariance":
                np.testing.assert_allclose(x, y, rtol=0, atol=1e-18 * np.abs(x).max())
            else:
                np.testing.assert_array_equal(x, y, err_msg=field)


def test_a_mission_without_faults_describes_and_builds_as_before():
    m = missions.from_dict(BASE)
    assert "faults" not in m.describe() and "fdir" not in m.describe()
    assert m.loop().faults is None
    assert missions.load("missions/wheel_failure.toml").faults[0] == {"time": 800.0, "wheel": 1, "mode": "off",
                                                                       "factor": 0.0}


# --- bad input ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(("change", "message"), [
    ({"faults": [{"time": 1.0, "wheel": 5}]}, r"faults\[0\].wheel must be a wheel's index, 1 to 4"),
    ({"faults": [{"time": 1.0, "wheel": 0}]}, r"faults\[0\].wheel must be a wheel's index"),
    ({"faults": [{"time": 3.0, "end": 2.0, "star_tracker": "outage"}]}, r"faults\[0\].end = 2 s must come after"),
    ({"faults": [{"time": 3.0, "star_tracker": "outage"}]}, r"faults\[0\].end \[s\] is missing"),
    ({"faults": [{"time": 1.0, "star_tracker": "outage", "end": 2.0}], "sensors": {"star_tracker": False},
      "estimator": {"kind": "truth"}}, "the mission flies no star tracker"),
    ({"faults": [{"time": 1.0, "gyro": "bias step", "step": [0, 0, 1e-4]}], "sensors": {"gyro": False},
      "estimator": {"kind": "truth"}}, "the mission flies no gyro"),
    ({"faults": [{"time": 1.0, "wheel": 1}], "actuator": {"kind": "ideal"}}, "the mission flies no wheels"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "stuck", "factor": 0.5}]}, "a wheel stuck delivers no torque"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "friction", "factor": 2.0}]}, "no bearing friction to scale"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "friction"}], "actuator": {"kind": "wheels", "wheels": {
        "coulomb_friction": 1e-4}}}, r"faults\[0\]\.factor is missing"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "friction", "factor": 1.0}], "actuator": {"kind": "wheels",
        "wheels": {"coulomb_friction": 1e-4}}}, "scales the friction by nothing"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "friction", "factor": 100.0}], "actuator": {"kind": "wheels",
        "wheels": {"coulomb_friction": 5e-4}}}, "too steep for dt"),
    ({"actuator": {"kind": "wheels", "wheels": {"coulomb_friction": 1e-2}}}, "too steep for dt"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "melted"}]}, r"faults\[0\].mode"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "degraded", "factor": 1.0}]}, r"factor must be in \[0, 1\)"),
    ({"faults": [{"time": 1.0, "wheel": 1, "mode": "degraded"}]}, r"faults\[0\].factor is missing"),
    ({"faults": [{"time": -1.0, "wheel": 1}]}, r"faults\[0\].time"),
    ({"faults": [{"time": 1.0, "wheel": 1, "gyro": "bias step"}]}, "one target among"),
    ({"faults": [{"time": 1.0, "thruster": "+x"}]}, r"faults\[0\].thruster: the mission flies no thrusters "
                                                     r"\(momentum.kind = 'none'"),
    ({"faults": [{"time": 1.0, "wheel": 1, "speed": 3}]}, r"unknown key\(s\) speed"),
    ({"fdir": {"latency": -1.0}}, r"fdir.latency \[s\]"),
    ({"fdir": {"detection": "latency"}}, "needs fdir.latency"),
    ({"fdir": {"detection": "sometimes"}}, "fdir.detection"),
    ({"faults": [{"time": 1.0, "wheel": i} for i in (1, 2)], "fdir": {"latency": 1.0}},
     "no longer controllable about some axis"),
    ({"faults": [{"time": 1.0, "wheel": 1}], "control": {"mode": "continuous"}, "sensors": {}}, "sampled loop"),
])
def test_bad_faults_are_refused_in_one_line(change, message):
    d = {**BASE, **change}
    if change.get("sensors") == {}:
        d = {**d, "sensors": {"gyro": False, "star_tracker": False}, "estimator": {"kind": "truth"},
             "actuator": {"kind": "ideal"}}
    with pytest.raises(ValueError, match=message) as err:
        missions.from_dict(d)
    assert "\n" not in str(err.value)


def test_detection_never_turns_a_latency_off():
    assert missions.from_dict({**BASE, "fdir": {"latency": 1.0, "detection": "never"}}).fdir == {"detection": "never"}
    assert missions.from_dict({**BASE, "fdir": {"latency": 0.0}}).fdir == {"detection": "latency", "latency": 0.0}


def test_wheels_off_that_leave_an_axis_unaware_are_a_warning():
    d = {**BASE, "faults": [{"time": 1.0, "wheel": i} for i in (1, 3)]}
    with pytest.warns(fault_list.ControllabilityWarning, match="no longer controllable"):
        missions.from_dict(d)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        missions.from_dict({**BASE, "faults": [{"time": 1.0, "wheel": 1}]})


def test_the_loop_refuses_wheel_faults_without_wheels():
    loop = missions.from_dict(faulted()).loop()
    with pytest.raises(ValueError, match="a wheel fault needs wheels"):
        check_loop(dataclasses.replace(loop, actuator=Ideal()), {})


AFTER_FAULT = [{"index": "APE", "axis": "angle", "level": 0.9, "limit": 100.0, "phase": "after fault"},
               {"index": "RPE", "axis": "each", "level": 0.9, "limit": 100.0, "window": 2.0, "phase": "after fault"}]


def test_a_requirement_after_the_fault_reads_from_the_first_fault_to_the_end(flights):
    """phase = "after fault": the period [t_f, T), t_f the mission's first fault; its value is
    the index over that period written out (NumPy over the recorded errors)."""
    from so3jax.sim import pointing

    _, history = flights["detected"]
    m = missions.from_dict({**faulted(), "requirements": AFTER_FAULT})
    assert [r.after for r in m.requirements] == [FAULT, FAULT]
    signals = pointing.signals(history)
    bounds = pointing.phase_bounds_of(m.scenario())
    checked = pointing.check(m.requirements, signals.t, signals.performance, signals.knowledge, bounds)
    keep = (signals.t >= FAULT) & (signals.t < m.T)
    angles = np.sort(np.linalg.norm(signals.performance[keep], axis=1))
    ape = angles[int(np.ceil(0.9 * len(angles))) - 1] * pointing.ARCSEC
    np.testing.assert_allclose(checked[0]["value"], ape, rtol=1e-12)
    assert checked[0]["requirement"].endswith(f"after fault (from {FAULT:g} s): <= 100 arcsec")
    x = pointing.index_samples("RPE", signals.t, signals.performance[None], (FAULT, m.T), 2.0)
    np.testing.assert_allclose(checked[1]["value"], pointing.quantile(x[0, :, :3], 0.9).max() * pointing.ARCSEC,
                               rtol=1e-12)


def test_after_fault_needs_a_fault_and_a_fault_time_common_to_the_samples():
    from so3jax.missions import draw

    with pytest.raises(ValueError, match=r"requirements\[0\].phase: 'after fault' starts at the mission's first "
                                         r"fault: it needs a mission with \[\[faults\]\]"):
        missions.from_dict({**BASE, "requirements": AFTER_FAULT[:1]})
    m = missions.from_dict({**faulted(), "requirements": AFTER_FAULT[:1]})
    with pytest.raises(ValueError, match="faults.0.time is dispersed: each sample's starts elsewhere"):
        draw.parse({"faults": {"0": {"time": {"dist": "uniform", "low": 1.0, "high": 2.0}}}}, m)


# --- thrusters ---------------------------------------------------------------------------------------

# Holding an inertial attitude with the wheels' momentum h_w ~ (78, 13, 9) N m s above start: the
# -x, -y and -z thrusters fire throughout, no wheel limit binds, and nothing but the thrusters
# puts a torque on the body (no disturbance). -x fails off between two ticks.
THRUSTER_FAULT = 5.03  # [s]: acts from the tick at 5.1 s, detected from the tick at 8.1 s
PULSE = 0.1  # [N m]
THRUSTERS = {**BASE, "reference": {"kind": "inertial"}, "disturbance": {"amplitude": 0.0, "noise_std": 0.0},
             "actuator": {"wheels": {"initial_speed": [300.0, 100.0, -300.0, 0.0]}},
             "momentum": {"kind": "thrusters", "thrusters": {"torque": PULSE, "start": 20.0, "stop": 5.0,
                                                             "min_on_time": 0.5}}}


def thruster_off(time=THRUSTER_FAULT, latency: float | None = LATENCY) -> dict:
    fdir = {"detection": "never"} if latency is None else {"latency": latency}
    return {**THRUSTERS, "faults": [{"time": time, "thruster": "-x"}], "fdir": fdir}


@pytest.fixture(scope="module")
def thruster_flights():
    """The nominal flight and -x failed off, detected, unaware and past the horizon (one
    compilation for the three faulted)."""
    return {"nominal": fly(THRUSTERS), "detected": fly(thruster_off()), "unaware": fly(thruster_off(latency=None)),
            "late": fly(thruster_off(time=1e6))}


def fed_forward(h):
    """The pulses the wheels were commanded to absorb (M, 3) [N m]: tau_cmd - tau, the wheels
    delivering the command less the feedforward where no limit binds (docs/model.md §8.6)."""
    return h.tau_cmd - h.tau


def test_a_failed_thruster_gives_the_body_no_torque_from_its_fault_tick(thruster_flights):
    """The body's thruster torque (the held input the history records) has no -x pulse from
    the first tick at or after the fault on, the others fire on; and it is what the body gets:
    the total angular momentum R (J Omega + h_w) changes by its impulse alone, not by the
    pulses commanded (docs/model.md (8.20))."""
    for name in ("detected", "unaware"):
        m, h = thruster_flights[name]
        failed = h.t >= 5.1 - 1e-9
        assert np.sum(~failed) == 51 and np.all(h.managed[~failed] == -PULSE)  # every thruster fires before
        assert np.all(h.managed[failed, 0] == 0.0)
        assert np.all(h.managed[failed, 1:] == -PULSE)  # the others fire on
        G, J_s = axes(m), np.asarray(m.actuator["wheels"]["spin_inertia"], float)
        H = np.einsum("mij,mj->mi", h.R, np.einsum("mij,mj->mi", h.J, h.Omega) + (G @ (J_s * h.actuator).T).T)
        delivered = np.cumsum(np.einsum("mij,mj->mi", h.R, h.managed) * m.period, axis=0)
        commanded = np.cumsum(np.einsum("mij,mj->mi", h.R, fed_forward(h)) * m.period, axis=0)
        np.testing.assert_allclose(H[1:] - H[0], delivered[:-1], rtol=0, atol=1e-4)  # R turns within a period
        assert np.abs(commanded - delivered).max() > 0.25  # >= 3 s of 0.1 N m lost


def test_the_wheels_absorb_a_failed_thruster_s_pulses_until_it_is_detected(thruster_flights):
    """Before the detection the flight software fires -x and feeds its pulse forward to the
    wheels; from the first tick at or after it (fdir.latency later) never again: -x is not
    commanded and nothing is fed forward (docs/model.md (8.21)); unaware, it fires to the end."""
    for name, detected in (("detected", 8.1), ("unaware", np.inf)):
        _, h = thruster_flights[name]
        fed = fed_forward(h)
        failed = h.t >= 5.1 - 1e-9
        np.testing.assert_allclose(fed[~failed], h.managed[~failed], rtol=0, atol=1e-12)
        np.testing.assert_allclose(fed[:, 1:], h.managed[:, 1:], rtol=0, atol=1e-12)  # no wheel limit binds
        known = h.t >= detected - 1e-9
        np.testing.assert_allclose(fed[failed & ~known, 0], -PULSE, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fed[known, 0], 0.0, rtol=0, atol=1e-12)
        assert np.sum(failed & ~known) == (30 if name == "detected" else 149)


@pytest.mark.optimized  # bit for bit, as XLA's default pipeline builds both programs
def test_a_thruster_fault_past_the_horizon_changes_nothing(thruster_flights):
    _, nominal = thruster_flights["nominal"]
    _, late = thruster_flights["late"]
    for field in nominal._fields:
        for x, y in zip(jax.tree.leaves(getattr(nominal, field)), jax.tree.leaves(getattr(late, field)), strict=True):
            np.testing.assert_array_equal(x, y, err_msg=field)


def test_a_thruster_fault_builds_its_loop():
    m = missions.from_dict(thruster_off())
    assert m.faults == ({"time": THRUSTER_FAULT, "thruster": "-x"},)
    assert missions.from_dict({**thruster_off(), "faults": [{"time": 1.0, "thruster": "+z", "mode": "off"}]}).faults \
        == ({"time": 1.0, "thruster": "+z"},)
    faults = m.loop(jnp.float64).faults
    np.testing.assert_array_equal(np.asarray(faults.thruster_axis), [0.0])
    np.testing.assert_array_equal(np.asarray(faults.thruster_sign), [-1.0])
    np.testing.assert_array_equal(np.asarray(faults.thruster_detected), [THRUSTER_FAULT + LATENCY])
    failed = np.asarray(faults.failed_thrusters(jnp.asarray(5.1), faults.thruster_time))
    np.testing.assert_array_equal(failed, [[False] * 3, [True, False, False]])
    pulses = jnp.asarray([-PULSE, PULSE, -PULSE])
    np.testing.assert_array_equal(np.asarray(faults.delivered(pulses, jnp.asarray(5.0))), np.asarray(pulses))
    np.testing.assert_array_equal(np.asarray(faults.delivered(pulses, jnp.asarray(5.1))), [0.0, PULSE, -PULSE])
    loop = missions.from_dict(thruster_off()).loop()
    with pytest.raises(ValueError, match=r"^a thruster fault needs thrusters \(momentum.kind = 'thrusters'\); the "
                                         "loop's momentum manager is none$"):
        check_loop(dataclasses.replace(loop, momentum=None), {})


def test_a_sweep_disperses_a_thruster_fault_s_time():
    from so3jax.missions import draw

    m = missions.from_dict(thruster_off())
    leaves = draw.parse({"faults": {"0": {"time": {"dist": "uniform", "low": 1.0, "high": 2.0}}}}, m)
    assert "faults.0.time" in str(leaves)
    with pytest.raises(ValueError, match="a thruster fault disperses time, not 'factor'"):
        draw.parse({"faults": {"0": {"factor": 0.5}}}, m)


@pytest.mark.parametrize(("fault", "message"), [
    ({"thruster": "+w"}, r"faults\[0\].thruster must be one of \+x, -x, \+y, -y, \+z, -z"),
    ({"thruster": "x"}, r"faults\[0\].thruster must be one of"),
    ({"thruster": 1}, r"faults\[0\].thruster must be one of .*got 1$"),
    ({"thruster": "+x", "factor": 0.5}, r"faults\[0\]: factor not taken by a thruster fault \(it takes time, mode\)"),
    ({"thruster": "+x", "end": 9.0}, r"faults\[0\]: end not taken by a thruster fault"),
    ({"thruster": "+x", "mode": "degraded"}, r"faults\[0\].mode = 'degraded' is not modeled for a thruster"),
])
def test_bad_thruster_faults_are_refused_in_one_line(fault, message):
    with pytest.raises(ValueError, match=message) as err:
        missions.from_dict({**THRUSTERS, "faults": [{"time": 1.0, **fault}]})
    assert "\n" not in str(err.value)


def test_time_at_the_torque_limit_reads_a_degraded_wheel_s_own_limit():
    """A wheel degraded from t = 0 flies as the mission whose wheel has that limit; its time
    at the torque limit is that mission's (to a tick), where the nominal limit would never
    bind; a wheel off never binds."""
    u_max = np.asarray(missions.from_dict(BASE).actuator["wheels"]["max_torque"], float) * np.ones(4)
    f, slew = 0.01, {**BASE, "initial": {"attitude": [0.3, -0.2, 0.25]}}  # a slew: the commands are large
    degraded = missions.from_dict({**slew, "faults": [{"time": 0.0, "wheel": 3, "mode": "degraded", "factor": f}]})
    weak = missions.from_dict({**slew, "actuator": {"wheels": {"max_torque": (u_max * [1, 1, f, 1]).tolist()}}})
    times = []
    for m in (degraded, weak):
        controller, gains = m.controller("pd")
        times.append(float(sj.simulate(m.scenario(), controller, gains, m.seed, loop=m.loop()).flight
                           .time_at_torque_limit))
    assert times[1] > 1.0 and abs(times[0] - times[1]) <= degraded.period_steps * degraded.dt * (1 + 1e-9)
    loop = missions.from_dict(faulted()).loop(jnp.float64)
    judged = loop.faults.judged(loop.actuator, jnp.asarray(FAULT))
    assert np.asarray(judged.max_torque)[0] == np.inf and np.all(np.isfinite(np.asarray(judged.max_torque)[1:]))
