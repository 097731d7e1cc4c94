"""Stability margins of the sampled loop broken at the actuator input (so3jax.sim.margins): the
frequency response and margins against a closed form and python-control, the AD linearization
of the flight loop against finite differences, unstable loops reported as such, and the flight
PD's margins; the command; and the disk margin as a tuning constraint ([tune.constraints],
docs/model.md §19.3): the traced linearization against linearize, the traced disk margin against
disk_margin and against finite differences of itself, the penalty, bad constraint tables. One
flight loop is compiled for each path, at a short horizon, shared by the module's fixtures."""

import dataclasses
import json
import math
from pathlib import Path

import control
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import optimize

from so3jax.jobs import margins as margins_job
from so3jax.jobs import tune
from so3jax.jobs.tune import constraints
from so3jax.jobs.tune.config import constraint_times
from so3jax.missions import mission as missions
from so3jax.sim import margins as mg

ROOT = Path(__file__).resolve().parents[1]

# --- a single-axis rigid body, ZOH, PD delayed by one period (closed form) ---------------

J, H, KP, KD = 2.0, 0.1, 2.0, 3.0  # kg m^2, s, N m/rad, N m s/rad: omega_n = 1 rad/s, zeta = 0.75


def pd_delay(J=J, h=H, kp=KP, kd=KD, extra_delay=0):
    """J theta'' = u under a zero-order hold over h, u_j = d_j the command of the previous
    tick (d_{j+1} = w_j), y_j = -(kp theta_j + kd omega_j); ``extra_delay`` more periods of
    delay between w and d (a shift register). States (theta, omega, d, the register)."""
    n = 3 + extra_delay
    A = np.zeros((n, n))
    A[:2, :3] = [[1.0, h, h * h / (2 * J)], [0.0, 1.0, h / J]]
    for k in range(extra_delay):  # d <- r_1 <- r_2 <- ... <- w
        A[2 + k, 3 + k] = 1.0
    B = np.zeros((n, 1))
    B[-1, 0] = 1.0
    C = np.zeros((1, n))
    C[0, :2] = [-kp, -kd]
    return mg.Linearization(A, B, C, h)


def closed_form(omega, J=J, h=H, kp=KP, kd=KD):
    """L(e^{i omega h}) = z^-1 (kp G(z) + kd h / (J (z - 1))), G(z) = h^2 (z + 1) / (2 J (z - 1)^2)."""
    z = np.exp(1j * np.asarray(omega) * h)
    G = h * h * (z + 1) / (2 * J * (z - 1) ** 2)
    return (kp * G + kd * h / (J * (z - 1))) / z


def _scaled_input(lin, i, k):
    """lin with axis i's input scaled by k: the loop A + BC becomes A_i + k B_i C_i."""
    B = lin.B.copy()
    B[:, i] *= k
    return lin._replace(B=B)


def test_frequency_response_and_margins_match_the_closed_form():
    lin = pd_delay()
    omegas = mg.default_omegas(H)
    np.testing.assert_allclose(mg.frequency_response(lin, omegas)[:, 0, 0], closed_form(omegas), rtol=1e-9)

    # independently: |L| = 1 and Im L = 0 (L < 0) by brentq on the closed form
    w_gc = optimize.brentq(lambda w: abs(closed_form(w)) - 1.0, 0.1, 10.0, xtol=1e-14)
    pm = 180.0 + math.degrees(np.angle(closed_form(w_gc)))
    grid = np.linspace(1.0, math.pi / H * (1 - 1e-9), 20001)
    k = int(np.nonzero(np.diff(np.sign(closed_form(grid).imag)))[0][0])
    w_pc = optimize.brentq(lambda w: closed_form(w).imag, grid[k], grid[k + 1], xtol=1e-14)
    assert closed_form(w_pc).real < 0
    gm_db = -20 * math.log10(abs(closed_form(w_pc)))

    margins = mg.loop_at_a_time(lin)
    assert margins.stable and margins.spectral_radius < 1
    (axis,) = margins.axes
    assert axis.phase_margin_deg == pytest.approx(pm, rel=1e-6)
    assert axis.gain_crossover == pytest.approx(w_gc, rel=1e-6)
    assert axis.gain_margin_upper_db == pytest.approx(gm_db, rel=1e-6)
    assert axis.phase_crossover_upper == pytest.approx(w_pc, rel=1e-6)
    assert axis.gain_margin_lower_db == -math.inf  # a double integrator: stable for every gain factor in (0, k_upper)
    assert axis.delay_margin_s == pytest.approx(math.radians(pm) / w_gc, rel=1e-6)
    assert axis.delay_margin_periods == pytest.approx(axis.delay_margin_s / H, rel=1e-12)

    # what they mean: the loop goes unstable at the gain factor k_upper and at the delay margin
    k_upper = 10 ** (axis.gain_margin_upper_db / 20)
    assert mg.loop_at_a_time(_scaled_input(lin, 0, k_upper * (1 - 1e-6))).stable
    assert not mg.loop_at_a_time(_scaled_input(lin, 0, k_upper * (1 + 1e-6))).stable
    periods = math.floor(axis.delay_margin_periods)
    assert mg.loop_at_a_time(pd_delay(extra_delay=periods)).stable
    assert not mg.loop_at_a_time(pd_delay(extra_delay=periods + 1)).stable

    # balanced disk margin: 1 / max |S - 1/2| = 1 / max |1 - L| / (2 |1 + L|), the peak refined on the closed form
    peak = lambda w: -abs((1 - closed_form(w)) / (2 * (1 + closed_form(w))))
    fine = np.logspace(-2, math.log10(math.pi / H), 20001)
    k = int(np.argmin(peak(fine)))
    best = optimize.minimize_scalar(peak, bounds=(fine[k - 1], fine[k + 1]), method="bounded",
                                    options={"xatol": 1e-14})
    alpha = -1.0 / best.fun
    disk = mg.disk_margin(lin)
    assert disk.stable
    assert disk.axes[0].alpha == pytest.approx(alpha, rel=1e-6)
    assert disk.multiloop.alpha == pytest.approx(alpha, rel=1e-9)  # one loop: the same
    a = alpha / 2
    assert disk.axes[0].gain_margin_upper_db == pytest.approx(20 * math.log10((1 + a) / (1 - a)), rel=1e-12)
    assert disk.axes[0].gain_margin_lower_db == pytest.approx(20 * math.log10((1 - a) / (1 + a)), rel=1e-12)
    assert disk.axes[0].phase_margin_deg == pytest.approx(math.degrees(2 * math.atan(a)), rel=1e-12)


def _python_control(A, B, C, h, omegas):
    """python-control's margins of L = -C (zI - A)^-1 B: (upper GM, lower GM or 0, PM, w_pc upper, w_gc), by its
    FRD method on the exact state-space response over ``omegas`` (its polynomial method, through ss -> tf,
    misplaces the coupled example's crossover by 2e-4 and reports phase crossovers where L is not real)."""
    frd = control.frd(control.ss(A, B, -C, 0, dt=h), omegas)
    gm, pm, _, wpc, wgc, _ = control.stability_margins(frd, returnall=True, method="frd")
    upper = gm > 1
    worst = int(np.argmin(np.abs(pm)))
    return (gm[upper].min(), gm[~upper].max(initial=0.0), pm[worst], wpc[upper][np.argmin(gm[upper])], wgc[worst])


def _coupled_example():
    """Three PD-delay axes (different inertias and gains) coupled by a random input matrix."""
    parts = [pd_delay(J=j, kp=kp, kd=kd) for j, kp, kd in ((1.0, 1.0, 1.5), (2.0, 3.0, 3.0), (3.0, 2.0, 6.0))]
    A = np.zeros((9, 9))
    B, C = np.zeros((9, 3)), np.zeros((3, 9))
    for i, p in enumerate(parts):
        A[3 * i:3 * i + 3, 3 * i:3 * i + 3] = p.A
        B[3 * i:3 * i + 3, i] = p.B[:, 0]
        C[i, 3 * i:3 * i + 3] = p.C[0]
    mix = np.eye(3) + 0.15 * np.random.default_rng(3).standard_normal((3, 3))
    return mg.Linearization(A, B @ mix, C, H)


def _around(omegas, omega):
    """The grid with 2001 more points within 1 % of omega: python-control's disk margin is the grid's
    largest |S - 1/2|, ours the refined peak."""
    return np.union1d(omegas, np.linspace(0.99 * omega, 1.01 * omega, 2001))


def test_margins_match_python_control():
    omegas = np.logspace(-3, math.log10(math.pi / H * (1 - 1e-12)), 4001)
    for lin in (pd_delay(), _coupled_example()):
        assert np.abs(np.linalg.eigvals(lin.A + lin.B @ lin.C)).max() < 1
        margins, disks = mg.loop_at_a_time(lin), mg.disk_margin(lin)
        assert margins.stable and disks.stable
        q = lin.B.shape[1]
        for i, axis in enumerate(margins.axes):
            others = [o for o in range(q) if o != i]
            A_i = lin.A + lin.B[:, others] @ lin.C[others, :]
            B_i, C_i = lin.B[:, [i]], lin.C[[i], :]
            upper, lower, pm, w_pc, w_gc = _python_control(A_i, B_i, C_i, H, omegas)
            assert axis.gain_margin_upper_db == pytest.approx(20 * math.log10(upper), rel=1e-6)
            assert 10 ** (axis.gain_margin_lower_db / 20) == lower == 0.0  # no phase crossover with |L| > 1
            assert axis.phase_margin_deg == pytest.approx(pm, rel=1e-6)
            assert axis.phase_crossover_upper == pytest.approx(w_pc, rel=1e-6)
            assert axis.gain_crossover == pytest.approx(w_gc, rel=1e-6)
            # the SISO disk margin (python-control's: the grid's worst)
            grid = _around(omegas, disks.axes[i].frequency)
            alpha, _, _ = control.disk_margins(control.ss(A_i, B_i, -C_i, 0, dt=H), grid)
            assert disks.axes[i].alpha == pytest.approx(alpha, rel=1e-6)
        # multi-loop (python-control needs slycot's mu for MIMO): sigma_max of S - I/2, S = (I + L)^-1 from
        # python-control's frequency response of L
        grid = _around(omegas, disks.multiloop.frequency)
        L = np.moveaxis(control.ss(lin.A, lin.B, -lin.C, 0, dt=H).frequency_response(grid, squeeze=False).complex,
                        -1, 0)
        S = np.linalg.inv(np.eye(q) + L)
        alpha = 1.0 / np.linalg.norm(S - 0.5 * np.eye(q), ord=2, axis=(1, 2)).max()
        assert disks.multiloop.alpha == pytest.approx(alpha, rel=1e-6)
        assert disks.multiloop.alpha <= min(d.alpha for d in disks.axes) * (1 + 1e-12)  # sigma_max >= |diagonal|


def test_an_unstable_closed_loop_is_reported_unstable(flight):
    for lin in (pd_delay(kp=400.0), _scaled_input(pd_delay(), 0, 10.0), pd_delay(kp=-1.0)):
        assert np.abs(np.linalg.eigvals(lin.A + lin.B @ lin.C)).max() > 1
        margins, disks = mg.loop_at_a_time(lin), mg.disk_margin(lin)
        assert not margins.stable and margins.spectral_radius > 1 and margins.axes is None
        assert not disks.stable and disks.axes is None and disks.multiloop is None
        assert margins.to_dict()["axes"] is None and disks.to_dict()["multiloop"] is None
    # the flight loop with a negative attitude gain (the compiled program of the fixture: gains are traced)
    gains = flight.gains._replace(k_R=-flight.gains.k_R)
    lin = mg.linearize(flight.scenario, flight.loop, flight.controller, gains, flight.state, flight.j)
    margins = mg.loop_at_a_time(lin)
    assert not margins.stable and margins.axes is None and margins.spectral_radius > 1
    assert not mg.disk_margin(lin).stable


# --- the flight loop ---------------------------------------------------------------------


@dataclasses.dataclass
class Flight:
    scenario: object
    loop: object
    controller: object
    gains: object
    state: object
    j: int
    lin: mg.Linearization


@pytest.fixture(scope="module")
def flight():
    """The flight mission's PD (missions/flight.toml: gyro, star tracker, MEKF, four wheels,
    0.1 s period) linearized 1 s into its noise-free flight: the module's one compiled flight loop."""
    mission = missions.load(ROOT / "missions" / "flight.toml", ["T=1.0"])
    scenario, loop = mission.scenario("float64"), mission.loop("float64")
    controller, gains = mission.controller("pd")
    gains = type(gains)(*(jnp.asarray(g, jnp.float64) for g in gains))
    state = mg.nominal_state(scenario, loop, controller, gains, 1.0)
    j = mg.tick_index(scenario, loop, 1.0)
    lin = mg.linearize(scenario, loop, controller, gains, state, j)
    return Flight(scenario, loop, controller, gains, state, j, lin)


def test_noise_free_zeroes_the_sensors_noise_and_keeps_the_filters(flight):
    quiet = mg.noise_free(flight.loop)
    assert float(flight.loop.sensors.rate.arw) > 0 and float(flight.loop.sensors.attitude.sigma) > 0
    for value in (quiet.sensors.rate.arw, quiet.sensors.rate.rrw, quiet.sensors.attitude.sigma):
        assert float(value) == 0.0
    np.testing.assert_array_equal(quiet.sensors.rate.bias0, flight.loop.sensors.rate.bias0)
    assert quiet.estimator is flight.loop.estimator and float(quiet.estimator.sigma_st) > 0
    with pytest.raises(ValueError, match="whole number of control periods"):
        mg.tick_index(flight.scenario, flight.loop, 0.25)


def test_the_linearization_matches_finite_differences(flight):
    """A, B, C by forward-mode AD against central differences of the one-period map, on the columns of
    the true attitude and rate, the wheel speeds, the gyro's state and the filter's attitude and bias
    (not its covariance: entries of 1e-10 rad^2, beyond a finite difference's reach)."""
    lin = flight.lin
    phi, v, w = mg.one_period_map(flight.scenario, flight.loop, flight.controller, flight.gains, flight.state, flight.j)
    n = len(v)
    assert lin.A.shape == (n, n) and lin.B.shape == (n, 3) and lin.C.shape == (3, n) and len(lin.labels) == n
    assert not lin.at_limit and lin.period == pytest.approx(0.1)
    x_next, y = phi(v, w)
    np.testing.assert_array_equal(y, w)  # the nominal input is the nominal command
    rotations = [i for i, label in enumerate(lin.labels) if ":delta" in label]
    assert np.all(x_next[rotations] == 0)  # the end of the period's chart is centred on the nominal next state
    wanted = (".R:", ".Omega", ".actuator", ".sensors", ".estimator.R_hat", ".estimator.bias_hat")
    columns = [i for i, label in enumerate(lin.labels) if label.startswith(wanted)]
    assert len(columns) == 3 + 3 + 4 + 9 + 3 + 3  # R, Omega, 4 wheels, gyro (b_{j-1}, b_j, R_{j-1}), R_hat, b_hat

    step = 1e-6

    def central(dv=None, dw=None):
        dv = np.zeros(n) if dv is None else dv
        dw = np.zeros(3) if dw is None else dw
        (xp, yp), (xm, ym) = phi(v + dv, w + dw), phi(v - dv, w - dw)
        return (xp - xm) / (2 * step), (yp - ym) / (2 * step)

    for i in columns:
        dx, dy = central(dv=step * np.eye(n)[i])
        np.testing.assert_allclose(lin.A[:, i], dx, rtol=1e-5, atol=1e-5 * np.abs(dx).max(), err_msg=lin.labels[i])
        np.testing.assert_allclose(lin.C[:, i], dy, rtol=1e-5, atol=1e-5 * max(np.abs(dy).max(), 1e-300),
                                   err_msg=lin.labels[i])
    for i in range(3):
        dx, dy = central(dw=step * np.eye(3)[i])
        np.testing.assert_allclose(lin.B[:, i], dx, rtol=1e-5, atol=1e-5 * np.abs(dx).max())
        assert not np.any(dy)  # no feedthrough
    assert np.abs(lin.B[columns]).max() > 0 and np.abs(lin.C[:, columns]).max() > 0


def test_flight_pd_margins(flight):
    """The flight PD is stable with finite margins; the disk margins are consistent with
    their definitions; each axis's margin is where the closed loop's eigenvalues cross the
    unit circle; more rate gain (damping) gives more phase margin on every axis."""
    margins, disks = mg.loop_at_a_time(flight.lin), mg.disk_margin(flight.lin)
    assert margins.stable and disks.stable and 0.99 < margins.spectral_radius < 1
    assert margins.fixed_spectral_radius == pytest.approx(1.0, abs=1e-9)  # conserved: bias, momentum
    for axis, disk in zip(margins.axes, disks.axes):
        assert 30 < axis.phase_margin_deg < 90 and 0.01 < axis.gain_crossover < 0.2
        assert 20 < axis.gain_margin_upper_db < 80 and axis.gain_margin_lower_db < -6
        assert 0 < axis.delay_margin_s < math.inf
        assert 0 < disk.alpha < 2
        assert disk.phase_margin_deg <= axis.phase_margin_deg  # a disk guarantees less than the classical margins
        assert disk.gain_margin_upper_db <= axis.gain_margin_upper_db
        assert disk.gain_margin_lower_db >= axis.gain_margin_lower_db
        k_upper = 10 ** (axis.gain_margin_upper_db / 20)
        assert mg.loop_at_a_time(_scaled_input(flight.lin, axis.axis, k_upper * 0.999)).stable
        assert not mg.loop_at_a_time(_scaled_input(flight.lin, axis.axis, k_upper * 1.001)).stable
    assert disks.multiloop.alpha <= min(d.alpha for d in disks.axes)
    report = json.loads(json.dumps({"loop": margins.to_dict(), "disk": disks.to_dict()}, allow_nan=False))
    assert report["loop"]["stable"] is True and report["loop"]["at_limit"] is False
    assert [a["phase_margin_deg"] for a in report["loop"]["axes"]] == [a.phase_margin_deg for a in margins.axes]
    assert report["disk"]["multiloop"]["alpha"] == disks.multiloop.alpha

    phase_margins = []
    for scale in (0.5, 1.0, 1.25):  # at 1.5 a wheel's torque limit binds 1 s in (its channel then open)
        gains = flight.gains._replace(k_Omega=flight.gains.k_Omega * scale)
        state = mg.nominal_state(flight.scenario, flight.loop, flight.controller, gains, 1.0)
        lin = mg.linearize(flight.scenario, flight.loop, flight.controller, gains, state, flight.j)
        assert not lin.at_limit
        phase_margins.append([a.phase_margin_deg for a in mg.loop_at_a_time(lin).axes])
    np.testing.assert_allclose(phase_margins[1], [a.phase_margin_deg for a in margins.axes], rtol=1e-9)
    low, nominal, high = np.asarray(phase_margins)
    assert np.all(low + 5 < nominal) and np.all(nominal + 5 < high)


# --- the command -------------------------------------------------------------------------


def test_the_command_reports_the_margins_of_the_loop_it_linearizes(flight, tmp_path, capsys):
    """so3jax margins in process, on the fixture's mission and horizon (its compiled programs)."""
    from so3jax import commands as cli

    out = tmp_path / "m"
    argv = ["margins", str(ROOT / "missions" / "flight.toml"), "--T", "1", "--at", "0.5", "--controllers", "pd",
            "--no-figures", "--out", str(out)]
    assert cli.main(argv) == 0
    assert "pd, t = 0.5 s (capture)" in capsys.readouterr().out
    saved = json.loads((out / "margins.json").read_text())["pd"]["times"]
    state = mg.nominal_state(flight.scenario, flight.loop, flight.controller, flight.gains, 0.5)
    lin = mg.linearize(flight.scenario, flight.loop, flight.controller, flight.gains, state, 5)
    assert [row["t"] for row in saved] == [0.5]
    assert saved[0]["loop_at_a_time"] == json.loads(json.dumps(mg.loop_at_a_time(lin).to_dict()))
    assert saved[0]["disk"] == json.loads(json.dumps(mg.disk_margin(lin).to_dict()))
    import so3jax  # the library call computes the same (the same compiled programs)

    found = so3jax.margins(ROOT / "missions" / "flight.toml", "pd", 0.5, T=1.0)
    np.testing.assert_array_equal(found.linearization.A, lin.A)
    assert saved[0]["loop_at_a_time"] == json.loads(json.dumps(found.loop_at_a_time.to_dict()))
    assert saved[0]["disk"] == json.loads(json.dumps(found.disk.to_dict()))


def test_the_figures_bode_and_nichols(flight):
    """Per controller a Bode and a Nichols figure of the fixture's loop (no compile, nothing
    saved): on the Nichols chart the dots on -180 deg sit at minus the upper gain margins,
    the critical point and the +-6 dB / +-30 deg region are drawn, and the disk boundary
    spans the gains and phases its alpha covers."""
    figures = margins_job.figures({"pd": {1.0: flight.lin}})
    assert list(figures) == ["bode_pd.png", "nichols_pd.png"]
    nichols = figures["nichols_pd.png"].axes
    assert len(nichols) == 3
    margins = mg.loop_at_a_time(flight.lin)
    for ax, axis in zip(nichols, margins.axes):
        dots = [line for line in ax.get_lines() if line.get_marker() == "o"]
        assert len(dots) == 1 and np.all(dots[0].get_xdata() == -180.0)
        assert -axis.gain_margin_upper_db == pytest.approx(min(dots[0].get_ydata()), abs=0.05)
        curve = ax.get_lines()[0]
        phase = np.asarray(curve.get_xdata())
        assert np.all((phase[np.isfinite(phase)] >= -360.0) & (phase[np.isfinite(phase)] < 0.0))
        (region,) = ax.patches
        assert (region.get_x(), region.get_y(), region.get_width(), region.get_height()) == (-210.0, -6.0, 60.0, 12.0)
        assert any(line.get_label() == "critical point" and list(line.get_xydata()[0]) == [-180.0, 0.0]
                   for line in ax.get_lines())
    alpha = mg.alpha_of_db(6.0)
    phase, gain = margins_job.disk_boundary(alpha)
    assert gain.max() == pytest.approx(6.0, rel=1e-9) and gain.min() == pytest.approx(-6.0, rel=1e-9)
    assert np.abs(phase + 180.0).max() == pytest.approx(mg.Disk.of(alpha, 0.0).phase_margin_deg, rel=1e-4)


@pytest.mark.parametrize("extra, message", [
    (["--at", "0.55"], "t = 0.55 s is not a whole number of control periods (0.1 s)"),
    (["--at", "2.0"], "--at 2 s is outside the horizon [0, 1) s"),
    (["--at", "0.0"], "--at 0 s is before t = 0.1 s (tick 1), the first tick at which the loop is formed"),
    (["--set", "control.mode='continuous'", "--set", "sensors.gyro=false", "--set", "sensors.star_tracker=false",
      "--set", "estimator.kind='truth'"], "margins need a sampled loop"),
])
def test_bad_times_and_loops_are_one_line_errors_before_compiling(in_process, capsys, extra, message):
    from so3jax import commands as cli

    assert cli.main(["margins", "--T", "1", "--out", "o", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("so3jax margins: error: ") and message in err and "\n" not in err
    assert not (in_process / "o").exists()


def test_a_loop_without_an_integrating_sensor_is_formed_at_tick_0():
    """A gyro sampling the rate reads at tick 0 (a rate-integrating one first at tick 1): its
    loop's margins at t = 0 are asked like any other time's."""
    from so3jax.missions import mission as missions

    sampled = missions.load(None, ["T=1", "sensors.gyro.output='rate'"])
    assert mg.first_formed_tick(sampled.loop()) == 0 and margins_job.check_times(sampled, [0.0]) == (0.0,)
    assert mg.first_formed_tick(missions.load(None, ["T=1"]).loop()) == 1


# --- the disk margin as a tuning constraint -----------------------------------------------

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")


@dataclasses.dataclass
class Point:
    scenario: object
    loop: object
    controller: object
    params: object
    state: object
    j: int
    lin: mg.Linearization
    omegas: object
    run: object  # params -> ((alpha, alpha per axis, (A, B, C)), d alpha / d params)


@pytest.fixture(scope="module")
def point(flight):
    """The flight fixture's PD 1 s in, with the constraint's program (margin_and_jacobian) compiled once."""
    scenario, loop, controller, gains, state, j, lin = (flight.scenario, flight.loop, flight.controller, flight.gains,
                                                        flight.state, flight.j, flight.lin)
    omegas = jnp.asarray(mg.default_omegas(lin.period, constraints.OMEGAS))
    kinds = mg.state_kinds(state)
    run = lambda params: constraints.margin_and_jacobian(params, scenario, loop, controller, state,
                                                          jnp.asarray(j, jnp.int32), omegas, kinds)
    return Point(scenario, loop, controller, tune.to_params(gains), state, j, lin, omegas, run)


def test_the_traced_linearization_is_linearize_s(point):
    (_, _, (A, B, C)), _ = point.run(point.params)
    for traced, reference in ((A, point.lin.A), (B, point.lin.B), (C, point.lin.C)):
        assert traced.shape == reference.shape
        np.testing.assert_allclose(np.asarray(traced), reference, rtol=0, atol=1e-10 * np.abs(reference).max())
    assert np.abs(point.lin.C).max() > 100  # the gains' N m per rad and per rad/s: a scale the tolerance follows


def test_disk_alpha_is_disk_margin_s_to_the_grid_s_resolution(point):
    (alpha, axes, _), _ = point.run(point.params)
    lin, omegas = point.lin, np.asarray(point.omegas)
    # on the same grid, by NumPy's SVD of S - I/2: the same number
    z = np.exp(1j * omegas * lin.period)
    closed = lin.A + lin.B @ lin.C
    S = np.eye(3) + lin.C @ np.linalg.solve(z[:, None, None] * np.eye(len(closed)) - closed, lin.B.astype(complex))
    half = S - 0.5 * np.eye(3)
    assert float(alpha) == pytest.approx(1 / np.linalg.norm(half, 2, axis=(1, 2)).max(), rel=1e-10)
    np.testing.assert_allclose(np.asarray(axes), 1 / np.abs(np.diagonal(half, axis1=1, axis2=2)).max(axis=0),
                               rtol=1e-10)
    # disk_margin refines the peak between the grid's points (5.6 % apart in frequency): the
    # grid's alpha is at least its, by < 1 %
    disks = mg.disk_margin(lin)
    assert disks.stable and 0.3 < disks.multiloop.alpha < 1.5
    assert disks.multiloop.alpha * (1 - 1e-12) <= float(alpha) <= disks.multiloop.alpha * (1 + 1e-2)
    for traced, disk in zip(np.asarray(axes), disks.axes):
        assert disk.alpha * (1 - 1e-12) <= traced <= disk.alpha * (1 + 1e-2)


def test_the_margin_s_gradient_matches_finite_differences_of_itself(point):
    """d alpha / d log-gains in forward mode (the state held fixed, as the traced function
    holds it) against central differences of the traced alpha."""
    (alpha, _, _), jacobian = point.run(point.params)
    h = 1e-5
    for name in point.params._fields:
        p = getattr(point.params, name)
        up, down = (point.run(point.params._replace(**{name: p + s}))[0][0] for s in (h, -h))
        central = (float(up) - float(down)) / (2 * h)
        assert abs(central) > 1e-3  # each gain moves the margin
        assert float(getattr(jacobian, name)) == pytest.approx(central, rel=1e-6, abs=1e-9)


def test_the_penalty_is_zero_above_the_floor_and_positive_below(point):
    assert constraints.alpha_of_db(6.0) == pytest.approx(0.66456, abs=1e-5)
    assert constraints.db_of_alpha(constraints.alpha_of_db(6.0)) == pytest.approx(6.0, rel=1e-12)
    assert constraints.db_of_alpha(2.0) == math.inf
    (alpha, _, _), jacobian = point.run(point.params)
    alpha = float(alpha)  # the paper's PD 1 s in: +-5.5 dB
    below, above = constraints.alpha_of_db(6.0), constraints.alpha_of_db(3.0)
    assert above < alpha < below
    value, grad = constraints.penalty([alpha], [jacobian], above, 100.0)
    assert value == 0.0 and all(float(g) == 0.0 for g in grad)
    value, grad = constraints.penalty([alpha, alpha + 1.0], [jacobian, jacobian], below, 100.0)
    assert value == pytest.approx(100.0 * (below - alpha) ** 2 / below**2 / 2, rel=1e-12)
    for g, d in zip(grad, jacobian):  # only the point below the floor counts, for half of the mean
        assert float(g) == pytest.approx(-100.0 * (below - alpha) / below**2 * float(d), rel=1e-12)


FLIGHT = {"T": 1.0, "controllers": ["pd"],
          "tune": {"controller": "pd", "iterations": 1, "train": {"seeds": [0]}, "validation": {"seeds": [5]},
                   "cost": {"mode": "weighted"}, "constraints": {"disk_margin": {"min_db": 6.0, "at": [0.5]}}}}


def _campaign(mission=None, constraint=None, **tune_keys):
    table = {**FLIGHT, **(mission or {})}
    table["tune"] = {**FLIGHT["tune"], **tune_keys}
    if constraint is not None:
        table["tune"]["constraints"] = {"disk_margin": {**FLIGHT["tune"]["constraints"]["disk_margin"], **constraint}}
    return tune.parse_config(table, ".", missions.FLIGHT)


def test_a_constraint_parses_with_its_defaults_and_stays_out_of_campaigns_without_it():
    config = _campaign(constraint={"at": None})
    assert config.constraints.disk_margin == tune.DiskMarginConstraint(6.0, None, 100.0)
    assert constraint_times(config) == (0.9,)  # the horizon's last tick
    assert tune.tune_table(config)["constraints"] == {"disk_margin": {"min_db": 6.0, "at": None, "weight": 100.0}}
    plain = {k: v for k, v in FLIGHT["tune"].items() if k != "constraints"}
    plain = tune.parse_config({**FLIGHT, "tune": plain}, ".", missions.FLIGHT)
    assert plain.constraints is None and "constraints" not in tune.tune_table(plain)


def test_the_disk_margin_floor_reaches_the_design_goals_bound_and_the_command_refuses_beyond(in_process, capsys):
    """min_db up to goals.MAX_DB (alpha_req < 2); beyond, whatever 10^(min_db/20) gives, exit 2 on one line."""
    from so3jax import commands as cli
    from so3jax.jobs.tune.goals import MAX_DB

    assert _campaign(constraint={"min_db": MAX_DB}).constraints.disk_margin.min_db == MAX_DB
    campaign = str(Path(__file__).parents[1] / "tuning" / "pd_flight_margin.toml")
    argv = ["tune", campaign, "--set", "tune.constraints.disk_margin={min_db=1e6, at=[10.0]}", "--out", "o"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("so3jax tune: error: config key 'tune.constraints.disk_margin.min_db' must be a positive "
                          "finite number at most 60 dB")
    assert err.count("\n") == 1 and "Traceback" not in err and not (in_process / "o").exists()


@pytest.mark.parametrize(("mission", "constraint", "tune_keys", "message"), [
    ({"control": {"mode": "continuous"}, "sensors": {"gyro": False, "star_tracker": False},
      "estimator": {"kind": "truth"}}, None, {}, "'tune.constraints.disk_margin' needs a sampled loop"),
    (None, {"at": [0.55]}, {}, "t = 0.55 s is not a whole number of control periods (0.1 s)"),
    (None, {"at": [1.0]}, {}, "t = 1 s is outside the horizon [0, 1) s"),
    (None, {"at": [-0.1]}, {}, "outside the horizon"),
    (None, {"at": []}, {}, "'tune.constraints.disk_margin.at' must be a non-empty list of times"),
    (None, {"at": 0.5}, {}, "'tune.constraints.disk_margin.at' must be a non-empty list of times"),
    (None, {"min_db": 0.0}, {}, "'tune.constraints.disk_margin.min_db' must be a positive finite number"),
    (None, {"min_db": -6.0}, {}, "'tune.constraints.disk_margin.min_db' must be a positive finite number"),
    (None, {"min_db": 1e6}, {}, "'tune.constraints.disk_margin.min_db' must be a positive finite number at most "
                                "60 dB (alpha = 1.996: the disk margin alpha stays below 2), got 1000000.0"),
    (None, {"min_db": 60.01}, {}, "'tune.constraints.disk_margin.min_db' must be a positive finite number at most 60"),
    (None, {"weight": -1.0}, {}, "'tune.constraints.disk_margin.weight' must be a finite number in [0.0, inf]"),
    (None, {"floor": 6.0}, {}, "unknown config key 'tune.constraints.disk_margin.floor'"),
    (None, None, {"constraints": {"disk_margin": {"min_db": 6.0}, "phase_margin": {}}},
     "unknown config key 'tune.constraints.phase_margin'"),
    (None, None, {"constraints": {}}, "missing config key 'tune.constraints.disk_margin'"),
    (None, None, {"constraints": {"disk_margin": {"at": [0.5]}}},
     "missing config key 'tune.constraints.disk_margin.min_db'"),
    (None, None, {"method": "es"}, "cannot be combined with tune.method = \"es\""),
    (None, None, {"estimator": ["sigma_st"]}, "cannot be combined with tune.estimator"),
    (None, None, {"train": {"seeds": [0], "samples": 2}, "validation": {"seeds": [5], "samples": 2},
                  "dispersions": {"deployment": {"tau_J": {"dist": "uniform", "low": 200.0, "high": 400.0}}}},
     "cannot be combined with [tune.dispersions]"),
])
def test_bad_constraints_are_one_line_value_errors_before_compiling(monkeypatch, mission, constraint, tune_keys,
                                                                     message):
    def compiled(*args, **kwargs):
        raise AssertionError("reached compilation")

    for module, name in ((mg, "_fly"), (mg, "_period"), (constraints, "margin_and_jacobian")):
        monkeypatch.setattr(module, name, compiled)
    with pytest.raises(ValueError) as err:
        _campaign(mission, constraint, **tune_keys)
    assert message in str(err.value) and "\n" not in str(err.value)
