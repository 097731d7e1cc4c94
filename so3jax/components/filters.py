"""Structural filters at the control tick (docs/model.md §8.8): a second-order section on
each axis of the commanded torque or of the estimated rate, the continuous filter
H(s) = (b2 s^2 + b1 s + b0) / (s^2 + 2 zeta_p omega s + omega^2) discretized at the control
period by Tustin's rule prewarped at omega (8.24)-(8.25). A mission's ``[filter]`` table
chooses one by ``kind``: ``none`` (the default), ``notch`` or ``lowpass``. Its frequency and
damping ratios may each be given per mission phase (a list of one value per phase, as a
flexible body's k and c): the loop flies phase p's section from the phase's first tick on
(:meth:`SecondOrder.at_phase`).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.base import Filter
from so3jax.core import checks, so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass, static_field

SIGNALS = ("torque", "rate")  # what it filters: the commanded torque, or the rate the controller reads


@pytree_dataclass
class SecondOrder(Filter):
    """H(s) = (s^2 + 2 zeta_z omega s + omega^2) / (s^2 + 2 zeta_p omega s + omega^2) (a notch,
    ``lowpass`` False) or omega^2 / (s^2 + 2 zeta_p omega s + omega^2) (``lowpass`` True), on each
    axis of ``signal``. frequency: omega / 2 pi [Hz]; zeta_zero, zeta_pole: the damping ratios
    of its zeros and poles; period: the control period Delta_c [s]. The state is the
    transposed direct form's two delays, (2, 3, *b). phases: 0, or P where frequency,
    zeta_zero and zeta_pole each carry a leading axis of one value per mission phase
    (P, *b): :meth:`at_phase` picks a phase's section, which the loop applies."""

    frequency: jax.Array
    zeta_zero: jax.Array
    zeta_pole: jax.Array
    period: float
    lowpass: bool = static_field(default=False)
    signal: str = static_field(default="torque")
    phases: int = static_field(default=0)

    def at_phase(self, phase) -> Section:
        """The section of phase ``phase`` (an index, possibly traced) where the parameters are
        given per phase: each phase's coefficients computed as the number's are, then phase's
        picked (so that equal values in every phase fly bit for bit as the number); the filter itself
        otherwise. The delays carry over: a phase's first tick changes the coefficients, not
        the state."""
        if not self.phases:
            return self
        dtype = jnp.result_type(self.frequency, float)
        pick = lambda x, i: jnp.asarray(x)[i]
        every = [SecondOrder(pick(self.frequency, i), pick(self.zeta_zero, i), pick(self.zeta_pole, i), self.period,
                             self.lowpass, self.signal).coefficients(dtype) for i in range(self.phases)]
        return Section(tuple(jnp.stack(c)[phase] for c in zip(*every)), self.signal)

    def coefficients(self, dtype):
        """(n0, n1, n2, d1, d2): y_j = n0 x_j + n1 x_{j-1} + n2 x_{j-2} - d1 y_{j-1} - d2 y_{j-2}
        (8.25), from H(s) with s = K (z - 1) / (z + 1), K = omega / tan(omega Delta_c / 2)."""
        omega = 2 * math.pi * jnp.asarray(self.frequency, dtype)
        K = omega / jnp.tan(omega * jnp.asarray(self.period, dtype) / 2)
        w2, K2 = omega * omega, K * K
        pole = 2 * jnp.asarray(self.zeta_pole, dtype) * omega * K
        a = (K2 + pole + w2, 2 * (w2 - K2), K2 - pole + w2)
        if self.lowpass:
            b = (w2, 2 * w2, w2)
        else:
            zero = 2 * jnp.asarray(self.zeta_zero, dtype) * omega * K
            b = (K2 + zero + w2, 2 * (w2 - K2), K2 - zero + w2)
        return b[0] / a[0], b[1] / a[0], b[2] / a[0], a[1] / a[0], a[2] / a[0]

    def init(self, batch_shape, dtype):
        return jnp.zeros((2, 3, *batch_shape), dtype)

    def apply(self, state, x):
        if self.phases:
            raise ValueError(f"a filter given per phase ({self.phases}) is applied through at_phase(p)")
        n0, n1, n2, d1, d2 = (so3.batch_like(c, 0, x) for c in self.coefficients(x.dtype))
        y = n0 * x + state[0]
        return jnp.stack([n1 * x - d1 * y + state[1], n2 * x - d2 * y]), y

    def check(self) -> None:
        """The frequency below the Nyquist frequency 1 / (2 Delta_c), where concrete."""
        frequency = checks.concrete(self.frequency, "filter.frequency [Hz]")
        if frequency is not None and np.any(np.asarray(frequency) >= 0.5 / self.period):
            raise ValueError(f"filter.frequency = {float(np.max(frequency)):g} Hz must be below the Nyquist frequency "
                             f"{0.5 / self.period:g} Hz of the control period {self.period:g} s")


@pytree_dataclass
class Section(Filter):
    """A second-order section of given coefficients (n0, n1, n2, d1, d2) (8.25): one phase's
    of a :class:`SecondOrder` given per phase (:meth:`SecondOrder.at_phase`)."""

    taps: tuple
    signal: str = static_field(default="torque")

    def coefficients(self, dtype):
        return tuple(jnp.asarray(c, dtype) for c in self.taps)

    init = SecondOrder.init
    apply = SecondOrder.apply
    phases = 0


# --- registrations (so3jax.components.registry): a mission's [filter.NAME] tables -------------------------

_SIGNAL = Param("signal", "torque", choices=SIGNALS,
                doc="torque: the commanded torque, between the controller and the actuator; rate: the estimated "
                    "rate the controller reads")
PER_PHASE = ((), (None,))  # a number, or a list of one value per mission phase
_FREQUENCY = Param("frequency", 1.0, "Hz", shapes=PER_PHASE, low=0.0, low_excluded=True,
                   doc="omega / 2 pi, below the Nyquist frequency; a list: one per mission phase")
TUNABLE = ("frequency", "zeta_zero", "zeta_pole")  # the parameters a campaign may tune (tune.filter)


def per_phase(values: dict) -> int:
    """P where a filter's parameters {name: value} give a list of P values (one per mission
    phase), else 0; a ValueError where two lists differ in length."""
    lengths = {int(np.shape(v)[0]) for k, v in values.items() if k in TUNABLE and np.ndim(v) >= 1}
    if len(lengths) > 1:
        raise ValueError(f"filter parameters given per phase must have one length, got {sorted(lengths)}")
    return lengths.pop() if lengths else 0


def _build(values: dict, ctx, lowpass: bool) -> SecondOrder:
    a = ctx.as_array
    zero = 1.0 if lowpass else values["zeta_zero"]
    parts = [a(values["frequency"]), a(zero), a(values["zeta_pole"])]
    phases = per_phase({"frequency": parts[0], "zeta_zero": parts[1], "zeta_pole": parts[2]})
    if phases:  # every parameter one value per phase (the others broadcast)
        parts = [x if jnp.ndim(x) >= 1 else jnp.broadcast_to(x, (phases,)) for x in parts]
    return SecondOrder(*parts, float(ctx.period), lowpass, values["signal"], phases)


components.register(components.ComponentSpec(
    kind="filter", name="none", component=Filter, params=(), build=lambda v, ctx: None,
    doc="no structural filter",
))
components.register(components.ComponentSpec(
    kind="filter", name="notch", component=SecondOrder,
    params=(_FREQUENCY,
            Param("zeta_zero", 0.02, "-", shapes=PER_PHASE, low=0.0,
                  doc="damping ratio of its zeros: the depth |H| = zeta_zero / zeta_pole at the frequency"),
            Param("zeta_pole", 0.5, "-", shapes=PER_PHASE, low=0.0, low_excluded=True,
                  doc="damping ratio of its poles: the width"),
            _SIGNAL),
    build=lambda v, ctx: _build(v, ctx, lowpass=False),
    doc="H(s) = (s^2 + 2 zeta_zero omega s + omega^2) / (s^2 + 2 zeta_pole omega s + omega^2) per axis "
        "(docs/model.md §8.8)",
))
components.register(components.ComponentSpec(
    kind="filter", name="lowpass", component=SecondOrder,
    params=(_FREQUENCY,
            Param("zeta_pole", 0.7071067811865476, "-", shapes=PER_PHASE, low=0.0, low_excluded=True,
                  doc="damping ratio of its poles"),
            _SIGNAL),
    build=lambda v, ctx: _build(v, ctx, lowpass=True),
    doc="H(s) = omega^2 / (s^2 + 2 zeta_pole omega s + omega^2) per axis (docs/model.md §8.8)",
))
