"""Telemetry for identification: what the spacecraft measured, one ``.npz`` file.

Arrays (SI units, body frame; N samples at the control ticks):

    t               (N,)    s, strictly increasing
    gyro            (N, 3)  rad/s, the gyro's reading omega_m (bias and noise included)
    attitude        (N, 4)  the star tracker's R_m as a unit quaternion [w, x, y, z]
                            (scalar first, body -> inertial)
    attitude_valid  (N,)    bool, optional: the ticks with a star-tracker sample (default all)
    wheel_speed     (N, n)  rad/s, optional: each wheel's speed relative to the body
                            (tachometers)
    wheel_axes      (3, n)  optional: unit spin axes as columns, body frame
    spin_inertia    (n,)    kg m^2, optional: each wheel's spin inertia
    gyro_output     ()      str, optional: "rate" (the default: the gyro samples the rate at t)
                            or "increment" (a rate-integrating gyro: its angle increment over
                            the interval ending at t, divided by the interval, docs/model.md
                            (8.2))
    gyro_interval   () or (N,)  s, optional, with "increment": the interval each reading covers
                            (default: the time since the previous row; the first row's as
                            long as the second's)

With ``wheel_speed``, the wheels' geometry comes from ``wheel_axes`` and ``spin_inertia``,
else from a mission's ``[actuator.wheels]``. Both identification methods model either gyro
(docs/model.md §17.1). Rows without a star-tracker sample still hold a unit quaternion
(any: it is not read).
``so3jax fly`` writes this file for every controller it flies
(``OUT/telemetry/NAME.npz``); real telemetry is converted to it.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components.sensors import GYRO_OUTPUTS
from so3jax.core import tables
from so3jax.results.io import save_npz

REQUIRED = ("t", "gyro", "attitude")
OPTIONAL = ("attitude_valid", "wheel_speed", "wheel_axes", "spin_inertia", "gyro_output", "gyro_interval")


class Telemetry(NamedTuple):
    t: np.ndarray  # (N,) s
    gyro: np.ndarray  # (N, 3) rad/s
    R: np.ndarray  # (N, 3, 3) star-tracker attitude, body -> inertial
    valid: np.ndarray  # (N,) bool: a star-tracker sample
    # (N, 3) N m s: G_s J_s Omega_w, the wheels' momentum at rest in the body (zeros without)
    wheel_momentum: np.ndarray
    gyro_output: str = "rate"  # "rate": Omega(t) + b; "increment": the mean rate over the interval ending at t
    gyro_interval: np.ndarray | None = None  # (N,) s: the interval each increment reading covers
    # (3, 3) kg m^2: sum_i J_s,i g_i g_i^T, the wheels' spin inertia, part of J (zeros without wheels)
    wheel_inertia: np.ndarray = np.zeros((3, 3))


def quaternion_to_matrix(q) -> np.ndarray:
    """R (..., 3, 3) of unit quaternions q (..., 4) [w, x, y, z]."""
    w, x, y, z = np.moveaxis(np.asarray(q, float), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def matrix_to_quaternion(R) -> np.ndarray:
    """Unit quaternions (..., 4) [w, x, y, z], w >= 0, of rotations R (..., 3, 3)
    (Shepperd's method: divide by the largest of the four 4 q_i^2)."""
    R = np.asarray(R, float)
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    four = np.stack([1 + tr, 1 + 2 * m[:, 0, 0] - tr, 1 + 2 * m[:, 1, 1] - tr, 1 + 2 * m[:, 2, 2] - tr], -1)
    i = np.argmax(four, -1)
    s = np.sqrt(four[np.arange(len(m)), i])  # 2 |q_i|
    a = m[:, 2, 1] - m[:, 1, 2]  # 4 w x
    b = m[:, 0, 2] - m[:, 2, 0]  # 4 w y
    c = m[:, 1, 0] - m[:, 0, 1]  # 4 w z
    d = m[:, 0, 1] + m[:, 1, 0]  # 4 x y
    e = m[:, 0, 2] + m[:, 2, 0]  # 4 x z
    f = m[:, 1, 2] + m[:, 2, 1]  # 4 y z
    rows = {0: (s, a / s, b / s, c / s), 1: (a / s, s, d / s, e / s),
            2: (b / s, d / s, s, f / s), 3: (c / s, e / s, f / s, s)}
    q = np.zeros((len(m), 4))
    for k, values in rows.items():
        q[i == k] = 0.5 * np.stack(values, -1)[i == k]
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def _array(data, name, path, ndim, last=None, dtype=float):
    a = np.asarray(data[name])
    if a.dtype.kind not in ("f", "i", "u", "b"):
        raise ValueError(f"{path}: {name} must be numeric, got dtype {a.dtype}")
    a = a.astype(dtype)
    if a.ndim != ndim or (last is not None and a.shape[-1] != last):
        want = "(N,)" if ndim == 1 else f"(N, {last if last is not None else 'n'})"
        raise ValueError(f"{path}: {name} must have shape {want}, got {a.shape}")
    if dtype is float and not np.all(np.isfinite(a)):
        rows = np.unique(np.nonzero(~np.isfinite(a))[0])
        raise ValueError(f"{path}: {name} has {len(rows)} non-finite sample(s) (NaN or inf), "
                         f"the first at row {rows[0]}")
    return a


def _numbers(data, name, path) -> np.ndarray:
    """A numeric field of any shape as floats (its shape is checked where it is used)."""
    a = np.asarray(data[name])
    if a.dtype.kind not in ("f", "i", "u", "b"):
        raise ValueError(f"{path}: {name} must be numeric, got dtype {a.dtype}")
    return a.astype(float)


def load(path, wheels: tuple | None = None) -> Telemetry:
    """Read and check a telemetry file; every problem a one-line ValueError naming the file.
    wheels: (axes (3, n), spin_inertia (n,)) from a mission, used where the file has none."""
    path = Path(path)
    data = tables.read_npz(path, f"a telemetry .npz file (named arrays {', '.join(REQUIRED)}, ...)")
    return check(data, str(path), wheels)


def check(data: dict, path: str = "telemetry", wheels: tuple | None = None) -> Telemetry:
    """:class:`Telemetry` of a dict of arrays (the file's fields), checked."""
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ValueError(f"{path}: missing {', '.join(missing)} (a telemetry file has {', '.join(REQUIRED)}; "
                         f"optional: {', '.join(OPTIONAL)})")
    unknown = sorted(set(data) - set(REQUIRED) - set(OPTIONAL))
    if unknown:
        raise ValueError(f"{path}: unknown field(s) {', '.join(unknown)} (known: {', '.join(REQUIRED + OPTIONAL)})")
    output = data.get("gyro_output", np.asarray("rate"))
    if np.shape(output) != () or str(output) not in GYRO_OUTPUTS:
        raise ValueError(f"{path}: gyro_output must be one of {', '.join(GYRO_OUTPUTS)}, got {output!r}")
    t = _array(data, "t", path, 1)
    N = len(t)
    if N < 3:
        raise ValueError(f"{path}: t has {N} samples; identification needs at least 3")
    bad = np.nonzero(t[1:] <= t[:-1])[0]
    if len(bad):
        raise ValueError(f"{path}: t must be strictly increasing; t[{bad[0] + 1}] = {t[bad[0] + 1]!r} "
                         f"follows t[{bad[0]}] = {t[bad[0]]!r}")
    gyro = _array(data, "gyro", path, 2, 3)
    q = _array(data, "attitude", path, 2, 4)
    for name, a in (("gyro", gyro), ("attitude", q)):
        if len(a) != N:
            raise ValueError(f"{path}: {name} has {len(a)} samples, t has {N}")
    norm = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-6):
        row = int(np.argmax(np.abs(norm - 1.0)))
        raise ValueError(f"{path}: attitude must hold unit quaternions [w, x, y, z]; "
                         f"row {row} has norm {norm[row]:.9g}")
    valid = np.ones(N, bool)
    if "attitude_valid" in data:
        valid = _array(data, "attitude_valid", path, 1, dtype=bool)
        if len(valid) != N:
            raise ValueError(f"{path}: attitude_valid has {len(valid)} samples, t has {N}")
        if valid.sum() < 2:
            raise ValueError(f"{path}: attitude_valid marks {valid.sum()} star-tracker sample(s); "
                             "at least 2 are needed")
    h, wheel_inertia = np.zeros((N, 3)), np.zeros((3, 3))
    if "wheel_speed" in data:
        speed = _array(data, "wheel_speed", path, 2)
        if len(speed) != N:
            raise ValueError(f"{path}: wheel_speed has {len(speed)} samples, t has {N}")
        n = speed.shape[1]
        if n == 0:
            raise ValueError(f"{path}: wheel_speed has shape {speed.shape}, no wheel; a file without wheels "
                             "leaves wheel_speed out")
        if "wheel_axes" in data or "spin_inertia" in data:
            if "wheel_axes" not in data or "spin_inertia" not in data:
                raise ValueError(f"{path}: wheel_axes and spin_inertia come together")
            axes = _numbers(data, "wheel_axes", path)
            spin = _numbers(data, "spin_inertia", path)
        elif wheels is not None:
            axes, spin = (np.asarray(x, float) for x in wheels)
        else:
            raise ValueError(f"{path}: wheel_speed needs the wheels' geometry: wheel_axes and spin_inertia, "
                             "or a mission")
        spin = np.broadcast_to(spin, (axes.shape[1],)) if axes.ndim == 2 else spin
        if axes.shape != (3, n) or spin.shape != (n,):
            raise ValueError(f"{path}: {n} wheel speeds need wheel_axes (3, {n}) and spin_inertia ({n},), "
                             f"got {axes.shape} and {spin.shape}")
        if not (np.all(np.isfinite(axes)) and np.all(np.isfinite(spin)) and np.all(spin > 0)):
            raise ValueError(f"{path}: wheel_axes must be finite and spin_inertia finite and positive")
        if np.any(np.abs(np.linalg.norm(axes, axis=0) - 1.0) > 1e-6):
            raise ValueError(f"{path}: wheel_axes must be unit vectors (columns)")
        h = speed @ (axes * spin).T
        wheel_inertia = np.einsum("in,n,jn->ij", axes, spin, axes)
    interval = None
    if "gyro_interval" in data:
        if str(output) != "increment":
            raise ValueError(f"{path}: gyro_interval is read with gyro_output = 'increment' only")
        interval = _numbers(data, "gyro_interval", path)
        if interval.ndim == 0:
            interval = np.full(N, float(interval))
        if interval.shape != (N,) or not np.all(np.isfinite(interval) & (interval > 0)):
            raise ValueError(f"{path}: gyro_interval must be one positive number of seconds or one per sample ({N},)")
    elif str(output) == "increment":
        interval = np.concatenate([t[1:2] - t[:1], np.diff(t)])
    return Telemetry(t, gyro, quaternion_to_matrix(q), valid, h, str(output), interval, wheel_inertia)


def save(path, t, gyro, R, valid=None, wheel_speed=None, wheel_axes=None, spin_inertia=None) -> None:
    """Write a telemetry file (atomically) from arrays in the module's units; R (N, 3, 3)."""
    arrays = {"t": np.asarray(t, float), "gyro": np.asarray(gyro, float), "attitude": matrix_to_quaternion(R)}
    if valid is not None:
        arrays["attitude_valid"] = np.asarray(valid, bool)
    if wheel_speed is not None:
        arrays.update(wheel_speed=np.asarray(wheel_speed, float), wheel_axes=np.asarray(wheel_axes, float),
                      spin_inertia=np.broadcast_to(np.asarray(spin_inertia, float), (np.shape(wheel_axes)[1],)).copy())
    save_npz(Path(path), **arrays)


def recorded(mission) -> bool:
    """Whether a flight of the mission has telemetry: the sampled wiring, a gyro and a star tracker."""
    return mission.period is not None and "gyro" in mission.sensors and "star_tracker" in mission.sensors


def from_run(mission, history, seed) -> dict:
    """The telemetry arrays (the file's fields) of one simulated flight: the sensors' readings
    at the recorded ticks, the tachometers' wheel speeds and the wheels as the flight software
    knows them. The gyro's reading is the estimator's rate plus its bias estimate (the
    reading it was given, to round-off: omega_m = Omega_hat + b_hat, docs/model.md (8.7)); the
    star tracker's is regenerated from the recorded true attitude with the run's noise
    (docs/model.md §8.2's recipe: the draws the estimator saw). A rate-integrating gyro's
    readings cover one control period (``gyro_interval``), and tick 0, which has none, is
    left out. Needs the sampled wiring with a gyro and a star tracker, and a history
    recorded at ticks."""
    if not recorded(mission):
        raise ValueError("telemetry needs the sampled wiring with a gyro and a star tracker")
    tracker = mission.loop().sensors.attitude
    t = np.asarray(history.t, float)
    j = np.rint(t / mission.period).astype(np.int64)
    omega_m = np.asarray(history.Omega_hat, float) + np.asarray(history.bias_hat, float)
    R_m, valid = _star_tracker(tracker, jax.random.key(seed), jnp.asarray(mission.period),
                               jnp.asarray(np.asarray(history.R, float)), jnp.asarray(j, jnp.uint32))
    arrays = {"t": t, "gyro": omega_m, "attitude": matrix_to_quaternion(np.asarray(R_m)),
              "attitude_valid": np.asarray(valid, bool)}
    wheels = mission.actuator.get("wheels") if mission.actuator["kind"] == "wheels" else None
    if wheels is not None:
        arrays["wheel_speed"] = np.asarray(history.actuator, float)
    output = mission.sensors.get("gyro", {}).get("output", "rate")
    if output == "increment":
        arrays = {k: v[j > 0] for k, v in arrays.items()}
        arrays["gyro_interval"] = np.asarray(mission.period, float)
    arrays["gyro_output"] = np.asarray(output)
    if wheels is not None:
        axes = np.asarray(wheels["axes"], float).T  # the mission lists one axis per wheel
        arrays.update(wheel_axes=axes,
                      spin_inertia=np.broadcast_to(np.asarray(wheels["spin_inertia"], float), (axes.shape[1],)).copy())
    return arrays


@jax.jit
def _star_tracker(tracker, key, period, R, j):
    """The star tracker's readings (R_m (M, 3, 3), valid (M,)) at ticks j (M,) of the true R (M, 3, 3)."""
    def measure(R, j):
        _, (R_m, valid) = tracker.measure((), R, None, key, j, period)
        return R_m, valid

    return jax.vmap(measure)(R, j)
