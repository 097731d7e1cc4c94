"""A mission flown by Basilisk's own modules: the spacecraft hub (its inertia set between
runs at each inertia step), reactionWheelStateEffector with rwMotorTorque (or
extForceTorque for an ideal actuator), simpleNav (without noise, or with the mission's
navigation errors), inertial3D (or, for the orbit frame, hillPoint on the hub's own orbit
under a point-mass Earth), attTrackingError and mrpFeedback. The dynamics task steps at
the mission's dt and runs before the flight-software task, which ticks at the control
period: a tick reads the state at its time and its command is held over the period, as in
so3jax's sampled loop. A wheel fault acts at so3jax's tick: the effector's motor torque
limit of that wheel scaled (a wheel failed off zeroes its command), its friction
coefficients scaled, and rwMotorTorque's availability message drops a wheel detected
failed. The wheels' bearing friction is the effector's Coulomb and viscous model with its
limit-cycle speed (Stribeck off). A mission's hinged panels and slosh particles
(``[[appendages]]``, ``[[slosh]]``: docs/model.md §8.9) are hingedRigidBodyStateEffector and
linearSpringMassDamper on the hub of the mission's mass, its inertia J(t) as for the rigid hub
(the wheels' spin inertia included: the balanced wheels' effector subtracts it, (8.26)).
Basilisk is imported here only (the ``basilisk`` extra)."""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from so3jax.components.actuators import FRICTION_KEYS
from so3jax.dynamics.orbit import MU_EARTH
from so3jax.missions import faults as fault_list
from so3jax.missions.build import panel_frame

INSTALL = 'pip install -e ".[basilisk]"'


# so3jax's orbit frame L (x along the velocity, y = -h^, z to nadir -r^: docs/model.md §4) in
# hillPoint's frame H (r^, h^ x r^, h^): v_L = LVLH_FROM_HILL v_H, the DCM [LH].
LVLH_FROM_HILL = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])


class Flown(NamedTuple):
    """Basilisk's run at each control tick t [s] (M,): R (M, 3, 3) body to inertial,
    Omega (M, 3) [rad/s], wheel_speed (M, N) [rad/s] relative to the body, torque (M, 3)
    mrpFeedback's command [N m], simpleNav's estimate R_hat (M, 3, 3) and Omega_hat (M, 3)
    [rad/s], the reference it tracked R_d (M, 3, 3) desired body to inertial (inertial3D's, or
    hillPoint's frame turned by attTrackingError's sigma_R0R); wall [s]: building and flying;
    with [[appendages]] and [[slosh]], hinge_angle (M, N) [rad] (hingedRigidBodyOutMsg's theta)
    and slosh_displacement (M, N_slosh) [m] (linearSpringMassDamper's rho state), else None."""

    t: np.ndarray
    R: np.ndarray
    Omega: np.ndarray
    wheel_speed: np.ndarray
    torque: np.ndarray
    R_hat: np.ndarray
    Omega_hat: np.ndarray
    R_d: np.ndarray
    wall: float
    hinge_angle: np.ndarray | None = None
    slosh_displacement: np.ndarray | None = None


def require():
    """Basilisk's modules, or a one-line ValueError saying how to install them."""
    try:
        from Basilisk.architecture import bskLogging, messaging
        from Basilisk.fswAlgorithms import attTrackingError, hillPoint, inertial3D, mrpFeedback, rwMotorTorque
        from Basilisk.simulation import (
            extForceTorque,
            hingedRigidBodyStateEffector,
            linearSpringMassDamper,
            reactionWheelStateEffector,
            simpleNav,
            spacecraft,
        )
        from Basilisk.utilities import SimulationBaseClass, macros, simIncludeGravBody, simIncludeRW
        from Basilisk.utilities.pythonVariableLogger import PythonVariableLogger
    except ImportError:
        raise ValueError(f"Basilisk is not installed: {INSTALL}") from None
    return dict(bskLogging=bskLogging, messaging=messaging, attTrackingError=attTrackingError, inertial3D=inertial3D,
                hillPoint=hillPoint, mrpFeedback=mrpFeedback, rwMotorTorque=rwMotorTorque,
                extForceTorque=extForceTorque,
                reactionWheelStateEffector=reactionWheelStateEffector, simpleNav=simpleNav,
                spacecraft=spacecraft, SimulationBaseClass=SimulationBaseClass, macros=macros,
                simIncludeRW=simIncludeRW, simIncludeGravBody=simIncludeGravBody,
                hingedRigidBodyStateEffector=hingedRigidBodyStateEffector,
                linearSpringMassDamper=linearSpringMassDamper, PythonVariableLogger=PythonVariableLogger)


def reference_attitude(mission) -> np.ndarray:
    """R_d's rotation vector [rad]: reference.inertial's, or 0 for the paper's at n = 0."""
    if mission.reference["kind"] == "inertial":
        return np.asarray(mission.reference["inertial"]["attitude"], float)
    return np.zeros(3)


def orbit_state(mission) -> tuple[np.ndarray, np.ndarray]:
    """The hub's position r0 [m] and velocity v0 [m/s] at t = 0 in so3jax's inertial frame N,
    the orbit frame at t = 0 (docs/model.md §4): r_N(0) = a [0, 0, -1], v_N(0) = n a [1, 0, 0],
    a = (MU_EARTH / n^2)^(1/3), so that hillPoint's frame at t = 0 is L(0) = I turned by
    LVLH_FROM_HILL, and follows L(t) on Basilisk's propagated circle."""
    n = float(mission.n)
    a = (MU_EARTH / (n * n)) ** (1.0 / 3.0)  # CircularOrbit.radius()
    return np.array([0.0, 0.0, -a]), np.array([n * a, 0.0, 0.0])


def hill_offset_mrp(mission) -> list:
    """attTrackingError's sigma_R0R for reference.lvlh: R0 = hillPoint's H, R = the desired
    body frame D. R_d(t) = L(t) exp(hat(offset)) gives [HD] = LVLH_FROM_HILL^T exp(hat(offset)),
    and Basilisk's sigma of a DCM [HD] is SciPy's MRP of its transpose [DH]."""
    from scipy.spatial.transform import Rotation  # SciPy where it is used: the command line starts without it

    offset = Rotation.from_rotvec(np.asarray(mission.reference["lvlh"]["offset"], float)).as_matrix()
    return [float(x) for x in Rotation.from_matrix(offset.T @ LVLH_FROM_HILL).as_mrp()]


def inertias(mission) -> tuple[np.ndarray, list]:
    """J(0) [kg m^2] and [(t [s], J after)] of each inertia step in (0, T): so3jax's profile
    (a step's target resolved), which :mod:`.representable` admitted as steps."""
    profile = mission.scenario("float64").inertia
    if mission.inertia["kind"] != "events":
        return np.asarray(mission.J0, float), []
    times, targets = np.asarray(profile.times, float), np.asarray(profile.targets, float)
    initial = np.asarray(profile(0.0, 0), float)
    return initial, [(t, J) for t, J in zip(times, targets) if 0.0 < t < mission.T]


class WheelFaults(NamedTuple):
    """The wheel faults as the control ticks see them: limits [(j, s (N,))], each control
    tick j from which the wheels' torque limits are u_max,i s_i (8.16), available
    [(j, a (N,))], each tick j from which the distribution uses the wheels with a_i = 1 (8.17),
    and friction [(j, k (N,))], each tick j from which wheel i's friction is scaled by k_i (8.23)."""

    limits: list
    available: list
    friction: list


def tick_time(mission, j: int) -> float:
    """t_j = (j m) dt [s], in float64 as so3jax's loop computes it (so3jax.sim.loop.time)."""
    return float(np.float64(j * mission.period_steps) * np.float64(mission.dt))


def first_tick(mission, time: float) -> int:
    """The first control tick j with t_j >= time: the tick from which a fault at ``time``
    acts in so3jax's loop (so3jax.components.faults.after), off the grid or on it."""
    j = max(0, math.ceil(time / mission.period))
    while j > 0 and tick_time(mission, j - 1) >= time:
        j -= 1
    while tick_time(mission, j) < time:
        j += 1
    return j


def wheel_faults(mission) -> WheelFaults:
    """The mission's wheel faults (docs/model.md §8.7) at the ticks flown (t_j < T) where
    something changes: a fault's first tick (its factor), and for a wheel failed off with
    fdir.detection = "latency", the first tick at or after its time plus the latency (the
    wheel dropped). s_i and a_i at each such tick as so3jax's Faults compute them."""
    faults = [f for f in mission.faults if "wheel" in f]
    if not faults:
        return WheelFaults([], [], [])
    n = len(mission.actuator["wheels"]["axes"])
    latency = mission.fdir.get("latency") if mission.fdir["detection"] == "latency" else None
    detected = [f["time"] + latency if fault_list.lost(f) and latency is not None else math.inf for f in faults]
    ticks = round(mission.T / mission.period)

    def product(t, modes):
        s = [1.0] * n
        for f in faults:
            s[f["wheel"] - 1] *= f["factor"] if t >= f["time"] and f["mode"] in modes else 1.0
        return np.asarray(s)

    def available(t):
        a = [1.0] * n
        for f, when in zip(faults, detected):
            a[f["wheel"] - 1] = 0.0 if t >= when else a[f["wheel"] - 1]
        return np.asarray(a)

    def changes(times, of):
        at = sorted({first_tick(mission, t) for t in times if not math.isinf(t)})
        return [(j, of(tick_time(mission, j))) for j in at if j < ticks]

    rubbing = [f["time"] for f in faults if f["mode"] == "friction"]
    return WheelFaults(changes([f["time"] for f in faults if f["mode"] != "friction"],
                               lambda t: product(t, ("off", "stuck", "degraded"))),
                       changes(detected, available), changes(rubbing, lambda t: product(t, ("friction",))))


def _column(v) -> list:
    return [[float(x)] for x in v]


def navigation_errors(mission) -> tuple[list, list]:
    """simpleNav's PMatrix (18 x 18) and walkBounds (18): the mission's nav_attitude (MRP,
    rows 6-8) and nav_rate (rows 9-11) walks (:mod:`so3jax.components.navigation`), zero
    for a sensor not flown."""
    P, bounds = np.zeros((18, 18)), np.zeros(18)
    for name, rows in (("nav_attitude", slice(6, 9)), ("nav_rate", slice(9, 12))):
        values = mission.sensors.get(name)
        if values is not None:
            P[rows, rows] = float(values["sigma"]) * np.eye(3)
            bounds[rows] = float(values["bound"])
    return P.tolist(), bounds.tolist()


def springs(mission) -> tuple[list, list]:
    """Each panel's, then each particle's (k, c) in the phase holding at step 0, and [(K,
    [(k, c)])] at the first step K of each later phase in (0, n_steps) where any is given per
    phase (so3jax's loop switches them at the phase's step: so3jax.sim.loop.phase)."""
    entries = (*mission.appendages, *mission.slosh)
    value = lambda e, f, p: float(np.asarray(e[f], float).reshape(-1)[p] if np.ndim(e[f]) else e[f])
    at = lambda p: [(value(e, "k", p), value(e, "c", p)) for e in entries]
    if not any(np.ndim(e[f]) for e in entries for f in ("k", "c")):
        return at(0), []
    scenario = mission.scenario("float64")
    starts = scenario.phase_steps
    phase = lambda k: sum(k >= K for K in starts)
    return at(phase(0)), [(K, at(phase(K))) for K in sorted(set(starts)) if 0 < K < scenario.n_steps]


def set_springs(panels: list, particles: list, values: list) -> None:
    """Each effector's spring k and damper c (values: springs()'s, panels first): read at
    each derivative, so from the next step on where set between runs."""
    for effector, (k, c) in zip((*panels, *particles), values):
        effector.k, effector.c = k, c


def appendages(bsk, mission, sc, sim) -> tuple[list, list]:
    """The mission's panels as hingedRigidBodyStateEffector and its slosh particles as
    linearSpringMassDamper on ``sc`` (in the dynamics task, after the hub: their messages hold
    the state at each time), at their initial angle and displacement, at rest: (panels,
    particles). A panel's hinge frame (h1, h2, h3) = (-direction, axis, h1 x h2), its centre
    of mass at hinge + distance direction (Basilisk's r_HB_B - d s1); a particle at location +
    rho direction (docs/flexible.md (F.1), (F.3))."""
    column = lambda v: [[float(x)] for x in np.asarray(v, float)]
    panels, particles = [], []
    for a in mission.appendages:
        panel = bsk["hingedRigidBodyStateEffector"].HingedRigidBodyStateEffector()
        panel.mass, panel.d = float(a["mass"]), float(a["distance"])
        panel.IPntS_S = np.asarray(a["inertia"], float).tolist()
        panel.r_HB_B, panel.dcm_HB = column(a["hinge"]), panel_frame(a["axis"], a["direction"]).tolist()
        panel.thetaInit, panel.thetaDotInit = float(a["angle"]), 0.0
        panels.append(panel)
    for p in mission.slosh:
        particle = bsk["linearSpringMassDamper"].LinearSpringMassDamper()
        particle.massInit = float(p["mass"])  # its mass is a state
        particle.r_PB_B, particle.pHat_B = column(p["location"]), column(p["direction"])
        particle.rhoInit, particle.rhoDotInit = float(p["displacement"]), 0.0
        particles.append(particle)
    set_springs(panels, particles, springs(mission)[0])
    for effector in (*panels, *particles):
        sc.addStateEffector(effector)
        sim.AddModelToTask("dynamicsTask", effector)
    return panels, particles


def fly(mission, name: str, seed: int | None = None) -> Flown:
    """Controller ``name`` (mrp_feedback) on ``mission`` (checked by
    :func:`so3jax.jobs.crosscheck.representable.check`), flown over T; seed: simpleNav's
    RNGSeed (default: the mission's)."""
    from scipy.spatial.transform import Rotation

    bsk = require()
    start = time.perf_counter()
    macros, messaging = bsk["macros"], bsk["messaging"]
    sim = bsk["SimulationBaseClass"].SimBaseClass()
    dynamics = sim.CreateNewProcess("dynamics", 20)  # the higher priority runs first at a shared time
    software = sim.CreateNewProcess("software", 10)
    dt_ns, period_ns = macros.sec2nano(mission.dt), macros.sec2nano(mission.period)
    dynamics.addTask(sim.CreateNewTask("dynamicsTask", dt_ns))
    software.addTask(sim.CreateNewTask("softwareTask", period_ns))

    J, steps = inertias(mission)
    wheels = mission.actuator["kind"] == "wheels"
    values = mission.actuator.get("wheels", {})
    sc = bsk["spacecraft"].Spacecraft()
    sc.ModelTag = "spacecraft"
    flexible = bool(getattr(mission, "flexible", False))
    # [kg]: translation flown only on an orbit (the hub's centre of mass at B: it does not turn a rigid body)
    sc.hub.mHub = float(mission.hub_mass) if flexible else 1.0
    lvlh = mission.reference["kind"] == "lvlh"
    if lvlh:  # the orbit frame: the hub on so3jax's circle, under a point-mass Earth at N's origin
        r0, v0 = orbit_state(mission)
        sc.hub.r_CN_NInit, sc.hub.v_CN_NInit = _column(r0), _column(v0)
        gravity = bsk["simIncludeGravBody"].gravBodyFactory()
        earth = gravity.createCustomGravObject("earth", mu=float(MU_EARTH))  # so3jax's mu, not createEarth()'s
        earth.isCentralBody = True
        gravity.addBodiesTo(sc)
    sc.hub.sigma_BNInit = _column(Rotation.from_rotvec(mission.initial["attitude"]).as_mrp())
    sc.hub.omega_BN_BInit = _column(mission.initial["rate"])
    sim.AddModelToTask("dynamicsTask", sc)
    panels, particles = appendages(bsk, mission, sc, sim) if flexible else ([], [])

    if wheels:
        axes = np.asarray(values["axes"], float)  # (N, 3) rows
        n = len(axes)
        per = {k: np.broadcast_to(np.asarray(values[k], float), (n,))
               for k in ("spin_inertia", "max_torque", "max_speed", "initial_speed", *FRICTION_KEYS)}
        factory, rws = bsk["simIncludeRW"].rwFactory(), []
        for i, g in enumerate(axes):
            rw = factory.create("custom", [float(x) for x in g], Js=float(per["spin_inertia"][i]),
                                u_max=float(per["max_torque"][i]), Omega_max=float(per["max_speed"][i]) / macros.RPM,
                                RWModel=messaging.BalancedWheels)
            rw.Omega = float(per["initial_speed"][i])  # [rad/s], not through the factory's rpm
            rw.Omega_max = float(per["max_speed"][i])
            rw.Jt = rw.Jg = 0.0  # a wheel's inertia about its spin axis only, as so3jax's
            rw.mass = 0.0  # the hub carries the whole inertia J, the wheels' spin inertia included
            rw.betaStatic = -1.0  # Coulomb and viscous friction, no Stribeck (docs/model.md (8.13a))
            rw.omegaLimitCycle = float(per["friction_speed"][i])
            rws.append(rw)  # the effector's own (shared): a fault sets its limits between runs
        effector = bsk["reactionWheelStateEffector"].ReactionWheelStateEffector()
        factory.addToSpacecraft("wheels", effector, sc)
        sim.AddModelToTask("dynamicsTask", effector, 2)
        wheel_config = factory.getConfigMessage()
    else:
        external = bsk["extForceTorque"].ExtForceTorque()
        sc.addDynamicEffector(external)
        sim.AddModelToTask("dynamicsTask", external, 2)
    sc.hub.IHubPntBc_B = J.tolist()

    logging = bsk["bskLogging"]
    level = logging.getDefaultLogLevel()
    logging.setDefaultLogLevel(logging.BSK_ERROR)  # its error model would warn at every tick of a bound under 3 sigma
    nav = bsk["simpleNav"].SimpleNav()  # at each tick, first: its error walks once per tick, as so3jax's
    logging.setDefaultLogLevel(level)
    nav.scStateInMsg.subscribeTo(sc.scStateOutMsg)
    nav.PMatrix, nav.walkBounds = navigation_errors(mission)
    nav.RNGSeed = int(mission.seed if seed is None else seed)
    sim.AddModelToTask("softwareTask", nav, 100)

    error = bsk["attTrackingError"].attTrackingError()
    if lvlh:
        reference = bsk["hillPoint"].hillPoint()
        reference.transNavInMsg.subscribeTo(nav.transOutMsg)
        earth_msg = messaging.EphemerisMsg().write(messaging.EphemerisMsgPayload())  # at rest at the origin
        reference.celBodyInMsg.subscribeTo(earth_msg)
        error.sigma_R0R = hill_offset_mrp(mission)
    else:
        reference = bsk["inertial3D"].inertial3D()
        reference.sigma_R0N = [float(x) for x in Rotation.from_rotvec(reference_attitude(mission)).as_mrp()]
    error.attNavInMsg.subscribeTo(nav.attOutMsg)
    error.attRefInMsg.subscribeTo(reference.attRefOutMsg)

    options, gains = mission.options[name], mission.gains[name]
    control = bsk["mrpFeedback"].mrpFeedback()
    control.K, control.P = float(gains.K), float(gains.P)
    control.Ki, control.integralLimit = float(gains.K_i), float(gains.integral_limit)
    control.controlLawType = int(options.get("law_type", 0))
    known = options.get("known_torque")
    control.knownTorquePntB_B = [0.0, 0.0, 0.0] if known is None else [float(x) for x in known]
    J_hat = np.eye(3) if options.get("J_hat") is None else np.asarray(options["J_hat"], float)
    vehicle = messaging.VehicleConfigMsgPayload()
    vehicle.ISCPntB_B = [float(x) for x in J_hat.ravel()]
    vehicle_msg = messaging.VehicleConfigMsg().write(vehicle)
    control.guidInMsg.subscribeTo(error.attGuidOutMsg)
    control.vehConfigInMsg.subscribeTo(vehicle_msg)
    for module in (reference, error, control):
        sim.AddModelToTask("softwareTask", module)

    events = []  # (time [ns], action): each action taken once the simulation has run up to its time
    if wheels:
        effector_in = effector.rwMotorCmdInMsg
        motors = bsk["rwMotorTorque"].rwMotorTorque()
        motors.controlAxes_B = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        motors.vehControlInMsg.subscribeTo(control.cmdTorqueOutMsg)
        motors.rwParamsInMsg.subscribeTo(wheel_config)
        faults = wheel_faults(mission)

        def limit(scale):  # the effector clips to +-u_max; u_min = inf zeroes any command (u_max <= 0: no limit)
            for rw, u_max, s in zip(rws, per["max_torque"], scale):
                rw.u_max, rw.u_min = (float(u_max) * s, 0.0) if s > 0 else (float(u_max), math.inf)

        for j, scale in faults.limits:  # the tick j's command is the first the effector clips so
            events.append((j * period_ns, lambda scale=scale: limit(scale)))

        def friction(scale):  # from the dynamics' next step on: so3jax's friction factor held from the tick
            for rw, f_c, c_v, k in zip(rws, per["coulomb_friction"], per["viscous_friction"], scale):
                rw.fCoulomb, rw.cViscous = float(k * f_c), float(k * c_v)

        friction(np.ones(n))
        for j, scale in faults.friction:
            events.append((j * period_ns, lambda scale=scale: friction(scale)))
        if faults.available:  # each Update of rwMotorTorque reads it: written before the tick j runs
            avail_msg = messaging.RWAvailabilityMsg()

            def avail(mask):
                payload = messaging.RWAvailabilityMsgPayload()
                payload.wheelAvailability = [messaging.AVAILABLE if a > 0 else messaging.UNAVAILABLE for a in mask]
                avail_msg.write(payload)

            avail(np.ones(n))
            motors.rwAvailInMsg.subscribeTo(avail_msg)
            for j, mask in faults.available:
                events.append((j * period_ns - dt_ns, lambda mask=mask: avail(mask)))
        effector_in.subscribeTo(motors.rwMotorTorqueOutMsg)
        sim.AddModelToTask("softwareTask", motors)
        control.rwParamsInMsg.subscribeTo(wheel_config)  # the wheels' momentum in the law
        control.rwSpeedsInMsg.subscribeTo(effector.rwSpeedOutMsg)
    else:
        external.cmdTorqueInMsg.subscribeTo(control.cmdTorqueOutMsg)

    state_log = sc.scStateOutMsg.recorder(period_ns)
    torque_log = control.cmdTorqueOutMsg.recorder(period_ns)
    nav_log = nav.attOutMsg.recorder(period_ns)
    reference_log = reference.attRefOutMsg.recorder(period_ns)
    logs = [state_log, torque_log, nav_log, reference_log]
    if wheels:
        speed_log = effector.rwSpeedOutMsg.recorder(period_ns)
        logs.append(speed_log)
    angle_logs = [panel.hingedRigidBodyOutMsg.recorder(period_ns) for panel in panels]
    logs += angle_logs
    if particles:  # a particle has no output message: its rho state read at each tick (registered at initialization)
        names = [p.nameOfRhoState for p in particles]
        rho = lambda _: [sc.dynManager.getStateObject(name).getState()[0][0] for name in names]
        rho_log = bsk["PythonVariableLogger"]({"rho": rho}, period_ns)
        logs.append(rho_log)
    for log in logs:
        sim.AddModelToTask("softwareTask", log)

    def step(t, J_after):  # the step ending at t flies the inertia before, the next one J_after
        sc.hub.IHubPntBc_B = J_after.tolist()
        sc.updateSCMassProps(float(t))  # from the next step on; the hub alone would keep the old one a step longer

    events += [(macros.sec2nano(t), lambda t=t, J_after=J_after: step(t, J_after)) for t, J_after in steps]
    if flexible:  # a spring per phase: from the phase's first step on, as its inertia step
        events += [(K * dt_ns, lambda values=values: set_springs(panels, particles, values))
                   for K, values in springs(mission)[1]]
    stop = macros.sec2nano(mission.T) - period_ns  # the ticks so3jax records: 0 .. T - period
    events.sort(key=lambda event: event[0])  # stable: an inertia step after a fault at the same time
    for _, action in (e for e in events if e[0] <= 0):  # a fault at tick 0: before anything runs
        action()
    sim.InitializeSimulation()
    for at in sorted({e[0] for e in events if 0 < e[0] <= stop}):
        sim.ConfigureStopTime(at)
        sim.ExecuteSimulation()
        for _, action in (e for e in events if e[0] == at):
            action()
    sim.ConfigureStopTime(stop)
    sim.ExecuteSimulation()

    t = np.asarray(state_log.times(), float) * macros.NANO2SEC
    sigma = np.asarray(state_log.sigma_BN, float)
    R = Rotation.from_mrp(sigma).as_matrix()  # body to inertial: the transpose of Basilisk's [BN]
    speeds = np.asarray(speed_log.wheelSpeeds, float)[:, :n] if wheels else np.zeros((len(t), 0))
    R_hat = Rotation.from_mrp(np.asarray(nav_log.sigma_BN, float)).as_matrix()
    R_d = Rotation.from_mrp(np.asarray(reference_log.sigma_RN, float)).as_matrix()  # R0 (the module's frame) to N
    if lvlh:  # D = H turned by sigma_R0R: [N D] = [N H][H D]
        R_d = R_d @ Rotation.from_mrp(error.sigma_R0R).as_matrix().T
    hinge = np.stack([np.asarray(log.theta, float) for log in angle_logs], axis=1) if flexible and panels else None
    slosh = np.asarray(rho_log.rho, float).reshape(len(t), len(particles)) if particles else None
    if flexible:
        hinge = np.zeros((len(t), 0)) if hinge is None else hinge
        slosh = np.zeros((len(t), 0)) if slosh is None else slosh
    return Flown(t, R, np.asarray(state_log.omega_BN_B, float), speeds, np.asarray(torque_log.torqueRequestBody, float),
                 R_hat, np.asarray(nav_log.omega_BN_B, float), R_d, time.perf_counter() - start, hinge, slosh)
