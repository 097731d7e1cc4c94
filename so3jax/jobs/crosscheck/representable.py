"""What Basilisk's modules fly as so3jax does (exactly, or with navigation errors of the
same model): a one-line ValueError naming the first mission feature ``so3jax crosscheck
basilisk`` cannot represent, before anything is built or compiled
(docs/commands/crosscheck.md lists them)."""

from __future__ import annotations

import numpy as np

CONTROLLERS = ("mrp_feedback",)  # so3jax's law -> Basilisk's module: mrpFeedback
ACTUATORS = ("ideal", "wheels")  # extForceTorque; reactionWheelStateEffector with rwMotorTorque
NAVIGATION = ("nav_attitude", "nav_rate")  # simpleNav's error walks (so3jax.components.navigation)


def _refuse(feature: str, remedy: str):
    raise ValueError(f"Basilisk cannot fly {feature} here: {remedy}")


def _whole_ns(seconds: float) -> bool:
    """Basilisk's clock counts whole nanoseconds."""
    ns = seconds * 1e9
    return abs(ns - round(ns)) <= 1e-6 * max(1.0, ns)


def check(mission) -> None:
    """One-line ValueError where ``mission`` holds a feature Basilisk's modules do not fly
    as so3jax does; nothing returned otherwise."""
    m = mission
    others = [name for name in m.controllers if name not in CONTROLLERS]
    if others:
        _refuse(f"controller {', '.join(others)}", "it flies mrp_feedback (its mrpFeedback module): "
                "--set 'controllers=[\"mrp_feedback\"]'")
    if m.period_steps is None:
        _refuse("continuous control (control.mode = \"continuous\")",
                "its flight software ticks: control.mode = \"sampled\" with a control.period")
    for what, seconds in (("dt", m.dt), ("control.period", m.period)):
        if not _whole_ns(seconds):
            _refuse(f"{what} = {seconds:g} s", "its clock counts whole nanoseconds")
    _inertia(m)
    kind = m.reference["kind"]
    if kind == "lvlh" and not m.n > 0:
        _refuse("reference.kind = \"lvlh\" at orbit.n = 0", "an orbit: orbit.n > 0 (hillPoint needs a radius)")
    if kind not in ("inertial", "lvlh") and not (kind == "paper" and m.n == 0):
        _refuse(f"reference.kind = \"{kind}\"", "an inertial attitude (reference.kind = \"inertial\", "
                "its inertial3D module), the orbit frame (reference.kind = \"lvlh\", its hillPoint module "
                "on a propagated orbit) or the paper's at orbit.n = 0")
    if m.disturbance["amplitude"] != 0 or m.disturbance["noise_std"] != 0:
        _refuse("the disturbance torque", "disturbance.amplitude = 0 and disturbance.noise_std = 0")
    if m.environment:
        names = ", ".join(f"environment.{name}" for name in m.environment)
        _refuse(f"environment torques ({names})", "leave [environment] out")
    if getattr(m, "flexible", False):
        _flexible(m)
    if m.momentum["kind"] != "none":
        _refuse(f"momentum management (momentum.kind = \"{m.momentum['kind']}\")", "momentum.kind = \"none\"")
    _faults(m)
    _navigation(m)
    kind = m.actuator["kind"]
    if kind not in ACTUATORS:
        _refuse(f"actuator.kind = \"{kind}\"", "actuator.kind = \"ideal\" (extForceTorque) or \"wheels\"")
    if kind == "wheels":
        _wheels(m.actuator["wheels"], m.options)


def navigation_errors(mission) -> bool:
    """Whether simpleNav draws errors (the mission flies nav_attitude or nav_rate)."""
    return any(name in mission.sensors for name in NAVIGATION)


def _navigation(m) -> None:
    """simpleNav: the true state (estimator truth, no sensors), or its error walks (the
    nav_attitude and nav_rate sensors read by estimator raw)."""
    others = [name for name in m.sensors if name not in NAVIGATION]
    remedy = ("simpleNav gives the true state (estimator.kind = \"truth\", no sensors) or its error walks "
              "(sensors nav_attitude and nav_rate, estimator.kind = \"raw\")")
    if others:
        _refuse(f"sensors ({', '.join(others)})", remedy)
    kind = m.estimator["kind"]
    if kind not in ("truth", "raw") or (kind == "truth") != (not m.sensors):
        _refuse(f"estimator.kind = \"{kind}\"" + (" with sensors" if kind == "truth" else ""), remedy)


def _flexible(m) -> None:
    """Hinged panels and slosh particles (docs/model.md §8.9) as hingedRigidBodyStateEffector
    and linearSpringMassDamper (their springs and dampers per phase set between runs), in
    inertial pointing (hillPoint reads the hub's point B, which moves about the centre of mass
    with them)."""
    if m.reference["kind"] == "lvlh":
        _refuse("the orbit frame (reference.kind = \"lvlh\") with [[appendages]] or [[slosh]]",
                "hillPoint reads the orbit of the hub's point B, which the panels and particles move about the "
                "centre of mass: an inertial reference (reference.kind = \"inertial\")")


def _faults(m) -> None:
    """Wheels failed off or degraded (their limit scaled at so3jax's tick, the wheel dropped
    from rwMotorTorque's distribution once detected), or their friction scaled (the effector's
    fCoulomb and cViscous from the tick: :func:`so3jax.jobs.crosscheck.basilisk.wheel_faults`);
    a wheel stuck the effector cannot hold;
    simpleNav has neither a star tracker to lose nor a gyro bias to step."""
    for fault in m.faults:
        if "star_tracker" in fault:
            _refuse(f"a star-tracker outage (faults: star_tracker = \"outage\" from {fault['time']:g} s)",
                    "simpleNav draws no star tracker: leave the outage out (wheel faults it flies)")
        if "gyro" in fault:
            _refuse(f"a gyro bias step (faults: gyro = \"bias step\" at {fault['time']:g} s)",
                    "simpleNav draws no gyro bias: leave the step out (wheel faults it flies)")
        if fault.get("mode") == "stuck":
            _refuse(f"a wheel stuck at its speed (faults: wheel = {fault['wheel']}, mode = \"stuck\")",
                    "reactionWheelStateEffector has no locked rotor: a wheel off, degraded or with its friction "
                    "scaled it flies")


def _inertia(m) -> None:
    """A constant inertia, or steps at the plant's step boundaries: Basilisk's hub holds one
    inertia per step, set between runs (a blend's J' Omega term it does not have)."""
    kind = m.inertia["kind"]
    remedy = "a constant inertia ([inertia] J = ...) or inertia.kind = \"events\" with time_constants 0 (steps)"
    if kind == "paper" and m.constant_inertia:
        return
    if kind != "events":
        _refuse(f"the inertia profile inertia.kind = {'paper (deployment and docking)' if kind == 'paper' else kind}",
                remedy)
    values = m.inertia["events"]
    if np.any(np.asarray(values["time_constants"]) != 0):
        _refuse("an inertia event's blend (time_constants > 0)", remedy)
    for t in np.asarray(values["times"], float):
        steps = t / m.dt
        if not _whole_ns(t) or abs(steps - round(steps)) > 1e-9 * max(1.0, steps):
            _refuse(f"an inertia step at {t:g} s",
                    f"its hub changes inertia between steps: a multiple of dt = {m.dt:g} s")


def _wheels(values: dict, options: dict) -> None:
    """The wheels as reactionWheelStateEffector flies them, mrpFeedback's law for the compensation."""
    if values.get("motor_torque") is not None:
        _refuse("actuator.wheels.motor_torque", "leave it out: the controller commands the wheels")
    if np.any(np.asarray(values.get("misalignment", 0.0)) != 0):
        _refuse("actuator.wheels.misalignment", "leave it out: the wheels spin about the axes the software knows")
    if np.any(np.asarray(values.get("spin_inertia_error", 0.0)) != 0):
        _refuse("actuator.wheels.spin_inertia_error", "0: the wheels have the spin inertia the software knows")
    law_type = options.get("mrp_feedback", {}).get("law_type", 0)
    if values["momentum_compensation"] and law_type == 0:
        _refuse("the wheels' momentum compensation with law_type 0",
                "its mrpFeedback puts the wheels' momentum in the law: actuator.wheels.momentum_compensation = false "
                "(or controller.mrp_feedback.law_type = 1, which is the compensation)")
