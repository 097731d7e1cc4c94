"""What ``so3jax identify`` refuses, and how: telemetry that does not determine the inertia
(no wheels, no motion, a body turned by its disturbance alone), files that are not
telemetry, and options that the record cannot hold; each a one-line ValueError before any
fit, with no numpy warning on the way. The manoeuvres are integrated here in numpy (no
compilation): the docked spacecraft (the paper's J2) with the flight mission's four pyramid
wheels, its gyro and star tracker noise-like at 1e-5.
"""

import numpy as np
import pytest

from so3jax import commands as cli
from so3jax.dynamics.paper import PAPER_J2
from so3jax.jobs.identify import fit, inertia, regression, simulation, telemetry
from so3jax.jobs.identify import report as reports

pytestmark = pytest.mark.filterwarnings("error")  # no numpy warning reaches the user

J_TRUE = np.asarray(PAPER_J2)
AXES = np.array([[0.8165408118857462, 0.0, -0.8165408118857462, 0.0],
                 [0.0, 0.8165408118857462, 0.0, -0.8165408118857462],
                 [0.5772877120855479] * 4])  # (3, 4): the flight mission's pyramid, one wheel per column
SPIN = 0.16  # kg m^2, each wheel's spin inertia
PERIOD = 0.1  # s between samples


def one_line(err: pytest.ExceptionInfo) -> str:
    message = str(err.value)
    assert "\n" not in message, message
    return message


def _quaternion_product(p, q):
    w1, v1, w2, v2 = p[0], p[1:], q[0], q[1:]
    return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])


def manoeuvre(T=120.0, amplitude=(0.35, 0.35, 0.05), disturbance=(0.0, 0.0, 0.0), rate=(0.001, -0.01, 0.002),
              seed=0, growth=0.0) -> dict:
    """Telemetry (the file's fields) of the docked spacecraft driven for T [s] by a square-wave
    body torque [N m] through its wheels (periods 100, 140, 60 s) and a constant body-fixed
    disturbance [N m], from ``rate`` [rad/s] with the wheels at rest: RK4 at 0.05 s on the
    attitude quaternion, the body's momentum L = J Omega + h and the wheels' spin momenta
    m = J_s (Omega_w + g . Omega) (so Omega = (J - W)^-1 (L - G m), W the wheels' spin inertia).
    growth: J(t) = (1 + growth t / T) J2, a body whose inertia grows linearly (L' = -Omega x L
    + d holds for any J(t): the momentum is what the torques change)."""
    W = SPIN * AXES @ AXES.T

    def inverse(t):
        return np.linalg.inv((1.0 + growth * t / T) * J_TRUE - W)

    motors = np.linalg.pinv(AXES)  # the wheels' torques that put tau on the body: -G u = tau
    periods = np.array([100.0, 140.0, 60.0])

    def field(t, x):
        q, L, m = x[:4], x[4:7], x[7:]
        Omega = inverse(t) @ (L - AXES @ m)
        tau = np.asarray(amplitude) * np.sign(np.sin(2 * np.pi * t / periods))
        dq = 0.5 * _quaternion_product(q, np.concatenate([[0.0], Omega]))
        return np.concatenate([dq, -np.cross(Omega, L) + disturbance, -(motors @ tau)])

    x = np.concatenate([[1.0, 0.0, 0.0, 0.0], J_TRUE @ np.asarray(rate), SPIN * AXES.T @ np.asarray(rate)])
    dt, steps = 0.5 * PERIOD, 2
    rows = []
    for k in range(int(round(T / PERIOD)) + 1):
        rows.append(x.copy())
        for j in range(steps):
            t = k * PERIOD + j * dt
            k1 = field(t, x)
            k2 = field(t + dt / 2, x + dt / 2 * k1)
            k3 = field(t + dt / 2, x + dt / 2 * k2)
            k4 = field(t + dt, x + dt * k3)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            x[:4] /= np.linalg.norm(x[:4])
    rows = np.array(rows)
    q, L, m = rows[:, :4], rows[:, 4:7], rows[:, 7:]
    t = PERIOD * np.arange(len(q))
    Omega = np.einsum("nij,nj->ni", np.stack([inverse(tk) for tk in t]), L - m @ AXES.T)
    rng = np.random.default_rng(seed)
    small = 0.5e-5 * rng.standard_normal((len(q), 3))  # rad: the star tracker's rotation vector, half angle
    noisy_q = np.array([_quaternion_product(a, np.concatenate([[1.0], b])) for a, b in zip(q, small)])
    return {"t": t, "gyro": Omega + 1e-5 * rng.standard_normal(Omega.shape),
            "attitude": noisy_q / np.linalg.norm(noisy_q, axis=1, keepdims=True),
            "wheel_speed": m / SPIN - Omega @ AXES, "wheel_axes": AXES, "spin_inertia": np.full(4, SPIN)}


@pytest.fixture(scope="module")
def driven():
    return manoeuvre()


def without_wheels(data):
    return {k: v for k, v in data.items() if k not in ("wheel_speed", "wheel_axes", "spin_inertia")}


# --- the data must determine J ------------------------------------------------------------


def test_a_driven_manoeuvre_determines_j(driven):
    """The reference: the check passes, and the linear estimate's spread is far below the refusal."""
    tm = telemetry.check(driven)
    regression.check(tm)
    simulation.check(tm)
    X, Xh, y, _ = regression.system(tm, True, 1, 5.0)
    beta = regression.determined(X, Xh, y, tm.wheel_inertia)
    J = np.asarray(inertia.from_entries(beta[:6]))
    assert np.max(np.abs(np.linalg.eigvalsh(J) / np.linalg.eigvalsh(J_TRUE) - 1)) < 0.02


def test_telemetry_without_wheels_is_refused(driven):
    """The momentum equation is homogeneous in J, J b and the disturbance without a momentum
    exchange: J = 0 fits it exactly (the refused fit reported J = 2e-306 I, 1 sigma 0)."""
    tm = telemetry.check(without_wheels(driven))
    for check in (regression.check, simulation.check):
        with pytest.raises(ValueError, match="no momentum exchanged with wheels") as err:
            check(tm)
        one_line(err)


def test_a_motionless_record_is_refused(driven):
    """A constant gyro and attitude, wheels at a constant speed: no momentum is exchanged
    (the refused fit reported J = 7e-43 I)."""
    n = len(driven["t"])
    still = {**driven, "gyro": np.tile([1e-4, 2e-4, -1e-4], (n, 1)), "attitude": np.tile([1.0, 0, 0, 0], (n, 1)),
             "wheel_speed": np.tile([10.0, -5.0, 3.0, 1.0], (n, 1))}
    for check in (regression.check, simulation.check):
        with pytest.raises(ValueError, match="no momentum exchanged with wheels") as err:
            check(telemetry.check(still))
        one_line(err)


def test_a_body_turned_by_its_disturbance_alone_is_refused():
    """No motor torque: the wheels' relative speeds only follow the body, and the wheels' own
    spin inertia with no disturbance fits the data as well as the truth (the refused fit
    reported J = 0.21 I, 1 sigma 0.01, for a 3945 kg m^2 spacecraft)."""
    tm = telemetry.check(manoeuvre(amplitude=(0.0, 0.0, 0.0), disturbance=(0.05, -0.03, 0.02)))
    assert np.ptp(tm.gyro, axis=0).min() > 1e-4  # it turns
    for check in (regression.check, simulation.check):
        with pytest.raises(ValueError, match="does not determine the inertia") as err:
            check(tm)
        one_line(err)


def test_spread_against_the_body_without_its_wheels():
    W = SPIN * AXES @ AXES.T
    assert fit.spread(J_TRUE, 20.0, W) == pytest.approx(20.0 / (np.linalg.eigvalsh(J_TRUE - W)[0]))
    assert fit.spread(W, 0.01, W) == np.inf  # the wheels alone: nothing of the rest
    assert fit.spread(np.zeros((3, 3)), 0.0, np.zeros((3, 3))) == np.inf
    assert fit.worst_std(np.diag([4.0, 1.0, 0.0, 0.0, 9.0, 0.0])) == 3.0


def test_a_poorly_determined_fit_says_so():
    """fit.estimate adds a warning above fit.POORLY_DETERMINED, and the report carries it
    (identification.json, J_hat.toml's header)."""
    solution = fit.Solution(np.zeros(6), 0.0, np.eye(6), 3, True)
    p = inertia.to_params(J_TRUE)
    quiet = fit.estimate(p, 1e-12 * np.eye(6), False, -1, solution, np.zeros((3, 3)), residual_rms=1.0)
    assert "warning" not in quiet
    loud = fit.estimate(p, np.eye(6), False, -1, solution, np.zeros((3, 3)), residual_rms=1.0)
    assert fit.spread(loud["J"], fit.worst_std(loud["theta_cov"]), 0.0) > fit.POORLY_DETERMINED
    assert loud["warning"].startswith("J is poorly determined") and "\n" not in loud["warning"]
    fit.add_warning(loud, "another")
    assert loud["warning"].endswith("; another")
    summary = reports.summary(loud)
    assert summary["warning"] == loud["warning"]
    summary["config"] = {"method": "regression", "telemetry": "t.npz"}
    assert "# warning: J is poorly determined" in reports.j_hat_toml(loud["J"], summary)


def test_the_report_of_a_degenerate_estimate_prints():
    """Equal principal moments leave their axes undetermined (1 sigma inf, JSON null): the
    text table says n/a, with no traceback and no warning."""
    result = {"J": np.diag([2000.0, 2000.0, 3000.0]), "theta_cov": np.eye(6), "bias": None, "disturbance": None,
              "residual_rms": 1.0, "iterations": 3, "converged": True}
    summary = reports.summary(result)
    assert summary["principal_axes_std_deg"][:2] == [None, None]
    labels = ("units", "converged", "iterations", "J_entries")
    numbers = {k for k, v in summary.items() if k not in labels and v is not None}
    assert numbers <= set(summary["units"]) and summary["units"]["residual_rms"] == "N m s"  # each value's unit
    text = reports.format_report(summary)
    assert "+- n/a deg" in text and "2000.0000" in text


# --- files that are not telemetry -----------------------------------------------------------


def _write(path, data):
    np.savez(path, **data)
    return path


def test_zero_wheels_are_a_one_line_error(driven, tmp_path):
    n = len(driven["t"])
    zero = {**driven, "wheel_speed": np.zeros((n, 0)), "wheel_axes": np.zeros((3, 0)), "spin_inertia": np.zeros(0)}
    with pytest.raises(ValueError, match=r"wheel_speed has shape \(1201, 0\), no wheel"):
        telemetry.check(zero)
    path = _write(tmp_path / "zero.npz", {k: v for k, v in zero.items() if k not in ("wheel_axes", "spin_inertia")})
    with pytest.raises(ValueError, match="no wheel") as err:
        telemetry.load(path, (AXES, SPIN))  # the mission's wheels do not help
    assert str(path) in one_line(err)


def test_wheel_geometry_must_be_numeric(driven):
    with pytest.raises(ValueError, match="wheel_axes must be numeric"):
        telemetry.check({**driven, "wheel_axes": np.array(["x", "y", "z"])})


@pytest.mark.parametrize("case", ["npy", "npy named npz", "empty npz", "zero bytes", "truncated", "corrupt"])
def test_files_that_are_not_telemetry_are_one_line_errors(case, driven, tmp_path):
    good = _write(tmp_path / "good.npz", driven).read_bytes()
    path = tmp_path / ("t.npy" if case == "npy" else "t.npz")
    if case in ("npy", "npy named npz"):
        with open(path, "wb") as f:
            np.save(f, driven["gyro"])
    elif case == "empty npz":
        np.savez(path)
    else:
        path.write_bytes({"zero bytes": b"", "truncated": good[: len(good) // 2],
                          "corrupt": good[:2000] + b"\xff" * 64 + good[2064:]}[case])
    with pytest.raises(ValueError) as err:
        telemetry.load(path)
    message = one_line(err)
    assert message.startswith(f"{path}: "), message
    assert ("missing t, gyro, attitude" if case == "empty npz" else "expected a telemetry .npz file") in message


# --- options the record cannot hold ---------------------------------------------------------


@pytest.mark.parametrize("interval", [1e-6, 0.15])
def test_an_interval_shorter_than_two_samples_is_refused(driven, interval):
    tm = telemetry.check(driven)
    with pytest.raises(ValueError, match=f"--interval {interval:g} s is shorter than two star-tracker samples"):
        regression.check(tm, interval=interval)
    regression.check_interval(tm.t, tm.valid, 2 * PERIOD)  # two samples: enough


def test_times_scaled_up_are_refused_not_waited_for(driven):
    """t * 1e12: each 5 s block would hold one sample, the 10 s windows a fraction of one."""
    tm = telemetry.check({**driven, "t": driven["t"] * 1e12})
    with pytest.raises(ValueError, match="shorter than two star-tracker samples"):
        regression.check(tm)
    with pytest.raises(ValueError, match="shorter than two sample intervals"):
        simulation.check(tm)


def test_blocks_of_a_record_with_a_long_gap_are_found_at_once():
    """Blocks are the runs of a label, not every label up to the last: a gap costs nothing."""
    t = np.concatenate([np.arange(100) * PERIOD, 1e15 + np.arange(100) * PERIOD])
    groups = regression.blocks(t, np.ones(len(t), bool), 5.0)
    assert [len(g) for g in groups] == [50, 50, 50, 50]


@pytest.mark.parametrize("window, match", [(1e-6, "shorter than two sample intervals"), (0.15, "shorter than two"),
                                           (0.3, "cuts the record into 300 windows; at most"),
                                           (1e300, "holds 0 window")])
def test_windows_the_record_cannot_hold_are_refused(driven, window, match, monkeypatch):
    monkeypatch.setattr(simulation, "MAX_WINDOWS", 200)
    tm = telemetry.check(driven)
    with pytest.raises(ValueError, match=match):
        simulation.check(tm, window=window)
    assert simulation.windows(tm, 10.0, True, 3)[:2] == (101, 11)


# --- the constant-inertia hypothesis --------------------------------------------------------


@pytest.fixture(scope="module")
def growing():
    """The manoeuvre of a body whose inertia grows by 30 % over its 120 s."""
    return manoeuvre(growth=0.3)


def test_the_constant_inertia_test_keeps_a_constant_one_and_rejects_a_growing_one(driven, growing):
    """The score test of a change of J between the record's halves (docs/model.md §17.7) at
    0.1 %: the constant body's statistic is 2.0 (p = 0.92; seeds 0-5: 1.0-7.6, p >= 0.27),
    the body growing by 30 % over the record's 120 s gives 45 (p = 5e-8; by 10 %: 34)."""
    kept = regression.constancy(telemetry.check(driven))
    assert kept["tested"] and kept["dof"] == 6 and kept["significance"] == 1e-3
    assert kept["p_value"] > 0.1 and not kept["rejected"], kept
    rejected = regression.constancy(telemetry.check(growing))
    assert rejected["p_value"] < 1e-6 and rejected["rejected"], rejected
    assert rejected["split_s"] == pytest.approx(60.0, abs=5.0)
    # a record too short for two halves of the unknowns' block pairs is not tested
    short = regression.constancy(telemetry.check(manoeuvre(T=40.0)))
    assert short == {"tested": False, "reason": "the record gives 7 intervals of 5 s; two halves need 12 for 15 "
                                                "unknowns"}
    result = {"J": J_TRUE, "theta_cov": np.eye(6), "bias": None, "disturbance": None, "residual_rms": 1.0,
              "iterations": 3, "converged": True, "constancy": short}
    assert ("constant inertia (J on the record's two halves): not tested: the record gives 7 intervals"
            in reports.format_report(reports.summary(result)))


def test_the_report_says_when_the_inertia_is_not_constant(driven, growing, cli_env, capsys):
    """identification.json and the table carry the test; a rejection is a one-line warning,
    in the report and on stderr."""
    import json

    for data, rejected in ((driven, False), (growing, True)):
        path = _write(cli_env / "telemetry.npz", data)
        out = cli_env / f"out-{rejected}"
        assert cli.main(["identify", str(path), "--out", str(out), "--no-figures"]) == 0
        std = capsys.readouterr()
        report = json.loads((out / "identification.json").read_text())
        assert report["constancy"]["rejected"] is rejected and report["constancy"]["dof"] == 6
        verdict = "REJECTED at 0.001" if rejected else "not rejected at 0.001"
        assert "constant inertia (J on the record's two halves): score statistic" in std.out and verdict in std.out
        warned = [line for line in std.err.splitlines() if "does not fit one constant inertia" in line]
        assert len(warned) == int(rejected) and ("warning" in report) is rejected
        if rejected:
            assert ("the telemetry does not fit one constant inertia: a change of J between the record's halves "
                    "fits it beyond its noise (score statistic ") in report["warning"] and "\n" not in report["warning"]
            header = (out / "J_hat.toml").read_text().splitlines()
            warning = next(line for line in header if line.startswith("# warning"))
            assert "does not fit one constant inertia" in warning


# --- the command: exit 2, one line, nothing written -----------------------------------------


@pytest.mark.parametrize("options, wheels, message", [
    ([], False, "no momentum exchanged with wheels"),
    (["--method", "simulation", "--initial-inertia", "3000"], False, "no momentum exchanged with wheels"),
    (["--interval", "1e-6"], True, "--interval 1e-06 s is shorter than two star-tracker samples"),
])
def test_the_command_refuses_before_writing(options, wheels, message, driven, cli_env, capsys):
    path = _write(cli_env / "telemetry.npz", driven if wheels else without_wheels(driven))
    out = cli_env / "out"
    code = cli.main(["identify", str(path), "--out", str(out), *options])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("so3jax identify: error: ") and message in err, err
    assert not out.exists()
