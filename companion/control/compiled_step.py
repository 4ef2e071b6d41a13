"""The compiled control step: :class:`CompiledStep` around the compiled twin of
:mod:`companion.control.control_step` (``companion.control._control_step``).

:class:`~companion.control.flight.FlightControl` runs its step (model terms, estimator,
tilt reference, eq. tau2 with the trim, setpoint mapping) in one compiled call per cycle
when the twin is built; the Python classes stay the reference the twin is tested against
(tests/test_compiled_step.py, to 1e-12 over whole offline runs).

What the step keeps between cycles, what is fixed and the outputs of the last cycle live
in one float64 buffer (:func:`control_step.work <companion.control.control_step.work>`):
``CompiledStep.state`` and ``CompiledStep.params`` are numpy arrays over its blocks, their
fields at the offsets of ``control_step.LAYOUT``. The estimator's delay line and the
battery's thrust scale (its voltage filter and hand-off of s) run in the step too. The
estimator, the excitation monitor, the tilt reference, the trim and the thrust scale the
flight app and the offline simulator hold are
subclasses of the Python ones whose state attributes read and write those arrays
(:class:`_Field`), so ``freeze``, ``reset``, ``tilt.reset``, ``trim.start`` and every read
of ``theta``, ``qhat``, ``skipped`` act on the compiled state, with the Python methods
unchanged.
"""

from __future__ import annotations

import math
from collections import Counter
from types import ModuleType
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from companion.control.attitude_feedforward import AttitudeLoopInverse
from companion.control.laws import DesiredState, HorizontalTrim, PassivityController
from companion.control.setpoints import AttitudeThrustSetpoint, ThrustModel
from companion.control.trajectory import TiltReference
from companion.estimation.estimator import (
    Estimate,
    Estimator,
    ExcitationMonitor,
    PaperEstimator,
    RlsEstimator,
    Skip,
)
from companion.estimation.inputs import EstimatorInputs, delay_cycles
from companion.estimation.thrust_supply import SupplyScale

__all__ = ["CompiledStep", "frozen_record", "skip_and_force"]

FloatArray = NDArray[np.float64]
_R = TypeVar("_R")
_SKIPS = tuple(Skip)
_SKIP_INDEX = {reason: i for i, reason in enumerate(_SKIPS)}
_NO_FORCE = np.full(8, math.nan)


def skip_and_force(applied_tau: FloatArray | Skip) -> tuple[int, FloatArray]:
    """The step's skip index (-1: none) and force (NaN if skipped)."""
    if isinstance(applied_tau, Skip):
        return _SKIP_INDEX[applied_tau], _NO_FORCE
    return -1, applied_tau


_new = object.__new__
_PLAIN_RECORDS: set[type] = set()
"""Classes :func:`frozen_record` has checked."""


def frozen_record(cls: type[_R], **fields: Any) -> _R:
    """An instance of the frozen dataclass ``cls`` with every field given, without its
    generated ``__init__`` (one ``object.__setattr__`` per field: about 1.5 us of a 10 us
    step for each of the outputs). TypeError for a class with a ``__post_init__`` or slots
    (it needs its ``__init__``) or if ``fields`` are not exactly its fields."""
    if cls not in _PLAIN_RECORDS:
        if hasattr(cls, "__post_init__") or hasattr(cls, "__slots__"):
            raise TypeError(f"{cls.__name__} needs its __init__")
        _PLAIN_RECORDS.add(cls)
    if fields.keys() != cls.__dataclass_fields__.keys():  # type: ignore[attr-defined]
        raise TypeError(f"{cls.__name__} needs the fields {list(cls.__dataclass_fields__)}")  # type: ignore[attr-defined]
    obj = _new(cls)
    obj.__dict__.update(fields)
    return obj


class _Field:
    """An attribute stored in a float64 buffer of the instance (``_params`` or
    ``_state``) at the offset of a field of ``control_step.LAYOUT``: a float, a bool, or
    (``shape`` given) an array, returned as a copy or (``view``) as a writable view; an
    ``optional`` float is None where the buffer holds NaN."""

    def __init__(
        self,
        buffer: str,
        field: str,
        kind: type = float,
        shape: tuple[int, ...] | None = None,
        view: bool = False,
        optional: bool = False,
    ) -> None:
        self.buffer = buffer
        self.field = field
        self.kind = kind
        self.shape = shape
        self.view = view
        self.optional = optional

    def _slot(self, obj: Any) -> tuple[FloatArray, int, int]:
        buf = getattr(obj, self.buffer)
        offset, size = obj._layout[self.field]
        return buf, offset, size

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        buf, offset, _ = self._slot(obj)
        if self.shape is None:
            value = buf[offset]
            return None if self.optional and math.isnan(value) else self.kind(value)
        n = math.prod(self.shape)
        values = buf[offset : offset + n].reshape(self.shape)
        return values if self.view else values.copy()

    def __set__(self, obj: Any, value: Any) -> None:
        buf, offset, _ = self._slot(obj)
        if self.shape is None:
            buf[offset] = math.nan if self.optional and value is None else float(value)
        else:
            n = math.prod(self.shape)
            buf[offset : offset + n] = np.asarray(value, dtype=np.float64).reshape(n)


class _QhatField:
    """The paper observer's qhat on the used rows, or None before its first step."""

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        valid, _ = obj._layout["State.qhat_valid"]
        if obj._state[valid] == 0.0:
            return None
        offset, _ = obj._layout["State.qhat"]
        return obj._state[offset : offset + len(obj.rows)].copy()

    def __set__(self, obj: Any, value: FloatArray | None) -> None:
        valid, _ = obj._layout["State.qhat_valid"]
        obj._state[valid] = 0.0 if value is None else 1.0
        if value is not None:
            offset, _ = obj._layout["State.qhat"]
            obj._state[offset : offset + len(obj.rows)] = value


class _SkippedField:
    """Skipped steps by reason, as the Counter the Python estimators keep."""

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        offset, _ = obj._layout["State.skipped"]
        counts = obj._state[offset : offset + len(_SKIPS)].tolist()
        return Counter({r: int(n) for r, n in zip(_SKIPS, counts, strict=True) if n})

    def __set__(self, obj: Any, value: Counter[Skip]) -> None:
        offset, _ = obj._layout["State.skipped"]
        obj._state[offset : offset + len(_SKIPS)] = [float(value[r]) for r in _SKIPS]


class _Backed:
    """Mixin: the instance's state attributes live in ``_state`` / ``_params``."""

    _layout: dict[str, tuple[int, int]]
    _state: FloatArray
    _params: FloatArray

    def _bind(self, step: CompiledStep) -> None:
        self._layout = step.layout
        self._state = step.state
        self._params = step.params


class _CompiledMonitor(_Backed, ExcitationMonitor):
    """The excitation monitor whose windows and information matrix the compiled step
    updates."""

    info = _Field("_state", "State.info", shape=(3, 3))
    excitation = _Field("_state", "State.excitation")
    spread = _Field("_state", "State.spread")

    def reset(self) -> None:
        s, lay = self._state, self._layout
        for name in ("info", "excitation", "samples", "ring_len", "ring_head"):
            offset, size = lay[f"State.{name}"]
            s[offset : offset + size] = 0.0
        for name in ("spread", "since_sample"):
            s[lay[f"State.{name}"][0]] = math.inf

    def update(self, dt: float, y_theta: FloatArray, m2: float, lc: float) -> tuple[float, float]:
        """Not available: the compiled step updates this monitor (run the Python step with
        ``FlightControl(..., compiled=False)``)."""
        raise TypeError("the compiled control step updates this monitor")


class _EstimatorFields:
    """State attributes shared by both estimators."""

    theta = _Field("_state", "State.theta", shape=(3,))
    frozen = _Field("_state", "State.frozen", kind=bool)
    thrust_scale = _Field("_state", "State.thrust_scale")
    scale_held = _Field("_state", "State.scale_held", kind=bool)
    calibrating = _Field("_state", "State.calibrating", kind=bool)
    compensation_scale = _Field("_state", "State.s_comp")
    skipped = _SkippedField()


class _CompiledPaperEstimator(_Backed, _EstimatorFields, PaperEstimator):
    qhat = _QhatField()


class _CompiledRlsEstimator(_Backed, _EstimatorFields, RlsEstimator):
    p = _Field("_state", "State.p", shape=(3, 3))
    p_s = _Field("_state", "State.p_s", shape=(3,))
    var_s = _Field("_state", "State.var_s")


class _CompiledTilt(_Backed, TiltReference):
    """The tilt reference whose angle, rate and acceleration the compiled step advances."""

    x = _Field("_state", "State.tilt_x", shape=(2,), view=True)
    v = _Field("_state", "State.tilt_v", shape=(2,), view=True)
    a = _Field("_state", "State.tilt_a", shape=(2,), view=True)
    w = _Field("_params", "Params.tilt_w")


class _CompiledTrim(_Backed, HorizontalTrim):
    """The horizontal trim whose force the compiled step integrates."""

    force_n = _Field("_state", "State.trim_force", shape=(2,))
    gain = _Field("_params", "Params.trim_gain")
    limit = _Field("_params", "Params.trim_limit")


class _CompiledAttitudeInverse(_Backed, AttitudeLoopInverse):
    """The tilt loop inverse whose integrator copy the compiled step advances."""

    torque_n_m = _Field("_state", "State.ff_torque_f", shape=(2,))
    integral = _Field("_state", "State.ff_int", shape=(2,))

    def offset(self, dt_s: float, torque_n_m: FloatArray) -> FloatArray:
        """Not available: the compiled step computes the offset."""
        raise TypeError("the compiled control step computes the attitude offset")


class _CompiledSupply(_Backed, SupplyScale):
    """The battery's thrust scale whose voltage filter and hand-off of s to the estimator
    the compiled step runs; its fit, its calibration samples and its read-outs stay here."""

    exponent = _Field("_params", "Params.supply_exponent")
    filter_s = _Field("_params", "Params.supply_filter_s")
    _measured = _Field("_state", "State.supply_measured", optional=True)
    voltage_v = _Field("_state", "State.supply_v", optional=True)
    level = _Field("_state", "State.supply_level", optional=True)
    calibration_v = _Field("_state", "State.supply_cal_v", optional=True)

    def before(self, dt: float, estimator: Estimator) -> None:
        """Before a step: fit k if a calibration just ended (the step filters the voltage
        and hands the estimator s)."""
        if estimator.scale is not None and not estimator.calibrating and self._samples:
            self.fit()


_ESTIMATOR_STATE = (
    *("theta", "frozen", "thrust_scale", "scale_held", "calibrating", "compensation_scale"),
    "skipped",
)
_STATE_ATTRIBUTES = {
    _CompiledPaperEstimator: (*_ESTIMATOR_STATE, "qhat"),
    _CompiledRlsEstimator: (*_ESTIMATOR_STATE, "p", "p_s", "var_s"),
    _CompiledMonitor: ("info", "excitation", "spread"),
    _CompiledTilt: ("w", "x", "v", "a"),
    _CompiledTrim: ("gain", "limit", "force_n"),
    _CompiledAttitudeInverse: ("torque_n_m", "integral"),
    _CompiledSupply: ("exponent", "filter_s", "_measured", "voltage_v", "level", "calibration_v"),
}
"""Per class, the attributes moved into the buffers."""
_DROPPED = ("_m2", "_lc", "_since_sample", "_samples")
"""The Python monitor's windows and counters: the compiled step keeps its own."""


def _backed(obj: Any, cls: type[Any], step: CompiledStep) -> Any:
    """A ``cls`` instance with ``obj``'s attributes, its state moved into the buffers."""
    new = object.__new__(cls)
    attributes = dict(obj.__dict__)
    new._bind(step)
    for name in _STATE_ATTRIBUTES[cls]:
        if name in attributes:
            setattr(new, name, attributes.pop(name))
    for name in _DROPPED if cls is _CompiledMonitor else ():
        attributes.pop(name, None)
    new.__dict__.update(attributes)
    return new


class CompiledStep:
    """Parameters and state of the compiled step for one control law, estimator, tilt reference,
    trim and thrust model, taken over from the Python objects given (which are not used
    afterwards: use :attr:`estimator`, :attr:`tilt` and :attr:`trim`).

    Supports :class:`PassivityController` (adaptive or fixed theta) with
    :class:`PaperEstimator` or :class:`RlsEstimator`, with or without the thrust scale;
    :meth:`supports` says whether a combination is covered.
    """

    def __init__(
        self,
        module: ModuleType,
        model_params: FloatArray,
        estimator: Estimator,
        controller: PassivityController,
        lambda_: FloatArray,
        tilt: TiltReference,
        trim: HorizontalTrim,
        thrust: ThrustModel,
        tilt_max_rad: float,
        compensate_thrust: bool = False,
        measured_rows: tuple[int, ...] = (),
        attitude_inverse: AttitudeLoopInverse | None = None,
        estimator_delay_s: float = 0.0,
        supply: SupplyScale | None = None,
    ) -> None:
        if not self.supports(controller, estimator):
            raise TypeError("the compiled step runs eq. tau2 with the paper or RLS estimator")
        assert isinstance(estimator, PaperEstimator | RlsEstimator)
        self._module = module
        self.layout: dict[str, tuple[int, int]] = dict(module.LAYOUT)
        monitor = estimator.monitor
        self._window = window = monitor._window_samples
        self._work = module.work(window)
        self.estimator_delay_s = estimator_delay_s
        """The estimator's delay behind the controller [s]: the step keeps the delay line
        (:mod:`companion.estimation.inputs`), its length set by the first cycle's period."""
        self.params, self.state, self._out = module.blocks(self._work)
        at = {name[4:]: offset for name, (offset, _) in self.layout.items() if name[:4] == "Out."}
        self._scalars = tuple(
            at[name]
            for name in (
                "roll", "pitch", "yaw", "thrust", "thrust_rel", "tilt_sat", "thrust_sat",
                "excitation", "spread", "confident", "frozen", "scale",
            )
        )  # fmt: skip
        """Offsets in the outputs' block of the setpoint's and the estimate's numbers."""
        self._vectors = tuple(
            slice(at[name], at[name] + size)
            for name, size in (
                ("tau", 8), ("theta", 3), ("theta_used", 3), ("ref_q", 8), ("ref_qd", 8),
                ("ref_qdd", 8), ("q_ned", 4),
            )
        )  # fmt: skip
        """Slices of the outputs' block: tau, theta, theta used, the reference q, q_dot,
        q_ddot, the setpoint's quaternion body FRD -> world NED."""
        n = len(estimator.rows)
        par: dict[str, Any] = {
            "model": model_params,
            "rls": isinstance(estimator, RlsEstimator),
            "has_scale": estimator.scale is not None,
            "n_rows": n,
            "rows": np.pad(estimator.rows.astype(float), (0, 8 - n)),
            "yaw_index": -1,
            "fixed": controller.fixed_theta is not None,
            "k": controller.k,
            "k_lam": controller.k_lam,
            "lam_xy": np.asarray(lambda_, dtype=float)[:2],
            "m2_min": estimator.bounds.m2_min_kg,
            "m2_max": estimator.bounds.m2_max_kg,
            "l2": estimator.bounds.link2_length_m,
            "window_s": monitor.window_s,
            "sample_period_s": monitor.sample_period_s,
            "excitation_min": monitor.excitation_min,
            "spread_max": monitor.spread_max,
            "window_samples": window,
            "weight": np.pad(monitor.weight.reshape(-1), (0, 3 * (8 - n))),
            "tilt_max": tilt_max_rad,
            "compensate": compensate_thrust,
            "measured": np.isin(np.arange(8), measured_rows),
        }
        if controller._fixed_xi is not None:
            par["fixed_xi"] = controller._fixed_xi
        if attitude_inverse is not None:
            par.update(
                ff_on=True,
                ff_att_p=attitude_inverse.attitude_p,
                ff_rate_p=attitude_inverse.rate_p,
                ff_rate_i=attitude_inverse.rate_i,
                ff_int_lim=attitude_inverse.integrator_limit,
                ff_torque=attitude_inverse.torque_per_normalized_n_m,
                ff_max=attitude_inverse.max_offset_rad,
                ff_tf=attitude_inverse.torque_filter_s,
            )
        scale = estimator.scale
        if scale is not None:
            par.update(
                s_initial=scale.initial,
                s_low=scale.low,
                s_high=scale.high,
                s_gamma=scale.gamma,
                s_drift2=scale.drift_std_per_sqrt_s**2,
                s_var_max=scale.initial_std**2,
            )
        if isinstance(estimator, PaperEstimator):
            par.update(
                gamma=estimator.gamma,
                c_star=np.pad(estimator.c_star, (0, 8 - n)),
                k_star=np.pad(estimator.k_star, (0, 8 - n)),
                qhat_dot0=np.pad(estimator.qhat_dot0, (0, 8 - n)),
                yaw_index=-1 if estimator.yaw is None else estimator.yaw,
            )
        else:
            par.update(
                forgetting=estimator.forgetting,
                p_trace_max=estimator.p_trace_max,
                p0=estimator.p0,
                r_forgotten=np.pad(np.diag(estimator._r_forgotten), (0, 8 - n)),
                com_from_joints=estimator.com_from_joints,
            )
        for name, value in par.items():
            offset, size = self.layout[f"Params.{name}"]
            self.params[offset : offset + size] = np.asarray(value, dtype=float).reshape(size)
        spread, since = self.layout["State.spread"][0], self.layout["State.since_sample"][0]
        self.state[spread] = self.state[since] = math.inf
        cls = _CompiledPaperEstimator if isinstance(estimator, PaperEstimator) else None
        self.estimator: Estimator = _backed(estimator, cls or _CompiledRlsEstimator, self)
        self.estimator.monitor = _backed(monitor, _CompiledMonitor, self)
        self.tilt: TiltReference = _backed(tilt, _CompiledTilt, self)
        self.trim: HorizontalTrim = _backed(trim, _CompiledTrim, self)
        self.attitude_inverse: AttitudeLoopInverse | None = (
            None
            if attitude_inverse is None
            else _backed(attitude_inverse, _CompiledAttitudeInverse, self)
        )
        self.supply: SupplyScale | None = None
        """The battery's thrust scale around the step, or None."""
        if supply is not None:
            self._set(self.params, "Params.supply_on", 1.0)
            self.supply = _backed(supply, _CompiledSupply, self)
        self._bound: list[_Backed] = [
            obj
            for obj in (self.estimator, self.estimator.monitor, self.tilt, self.trim)
            + (() if self.attitude_inverse is None else (self.attitude_inverse,))
            + (() if self.supply is None else (self.supply,))
            if isinstance(obj, _Backed)
        ]
        """The objects whose state attributes read and write the buffer."""
        self.thrust = thrust
        self.tilt_max_rad = tilt_max_rad

    @staticmethod
    def supports(controller: object, estimator: object) -> bool:
        """True for eq. tau2 (adaptive or fixed theta) with the paper or RLS estimator."""
        return isinstance(controller, PassivityController) and isinstance(
            estimator, PaperEstimator | RlsEstimator
        )

    def _set(self, buffer: FloatArray, name: str, value: float) -> None:
        buffer[self.layout[name][0]] = value

    def _start_delay_line(self, n: int) -> None:
        """A buffer with a delay line of n cycles after the windows, the values so far
        copied into it and every backed object bound to it."""
        old = self._work[0]
        self._work = self._module.work(self._window, n)
        self._work[0][: len(old)] = old
        self.params, self.state, self._out = self._module.blocks(self._work)
        self._set(self.params, "Params.delay_n", n)
        for obj in self._bound:
            obj._bind(self)

    def restart_delay_line(self) -> None:
        """Forget the delay line's cycles: the estimator skips the cycles it refills."""
        self._set(self.state, "State.delay_count", 0.0)

    @property
    def thrust(self) -> ThrustModel:
        """The thrust model the mapping uses (the flight app sets its floor)."""
        return self._thrust

    @thrust.setter
    def thrust(self, model: ThrustModel) -> None:
        self._thrust = model
        self._set(self.params, "Params.thrust_max", model.max_thrust_n)
        self._set(self.params, "Params.thrust_min_rel", model.min_relative)

    @property
    def tilt_max_rad(self) -> float:
        """Tilt limit of eq. phid [rad]."""
        return float(self.params[self.layout["Params.tilt_max"][0]])

    @tilt_max_rad.setter
    def tilt_max_rad(self, value: float) -> None:
        self._set(self.params, "Params.tilt_max", value)

    @property
    def trim_active(self) -> bool:
        """The trim integrates only while this is set."""
        return bool(self.state[self.layout["State.trim_active"][0]])

    @trim_active.setter
    def trim_active(self, value: bool) -> None:
        self._set(self.state, "State.trim_active", 1.0 if value else 0.0)

    def step(
        self,
        dt_s: float,
        q: FloatArray,
        q_dot: FloatArray,
        q_ddot: FloatArray,
        desired: DesiredState,
        applied_tau: FloatArray | Skip,
        estimator_inputs: EstimatorInputs | None = None,
    ) -> tuple[FloatArray, AttitudeThrustSetpoint, Estimate, FloatArray, DesiredState]:
        """One cycle: (tau, setpoint, estimate, theta used, desired with the tilt
        reference), as :meth:`FlightControl.step <companion.control.flight.FlightControl.step>`;
        the estimator runs on ``estimator_inputs`` (q, q_dot, q_ddot, applied force) if
        given, else on the delay line's (:attr:`estimator_delay_s`) or this cycle's."""
        if estimator_inputs is None and self.estimator_delay_s > 0.0:
            if self.params[self.layout["Params.delay_n"][0]] == 0.0:
                self._start_delay_line(delay_cycles(self.estimator_delay_s, dt_s))
        skip, tau = skip_and_force(applied_tau)
        args: tuple[Any, ...] = (q, q_dot, q_ddot, desired.q, desired.q_dot, desired.q_ddot, tau)
        extra: tuple[Any, ...] = ()
        if estimator_inputs is not None:
            est_skip, est_tau = skip_and_force(estimator_inputs[3])
            extra = (*estimator_inputs[:3], est_tau, est_skip)
        try:
            self._module.step(self._work, dt_s, skip, *args, *extra)
        except (BufferError, TypeError, ValueError):
            # Not C-contiguous float64 arrays (the buffer protocol says so with ValueError):
            # convert and call again, which raises if they are not 8 values each. Every
            # check precedes any change of the state.
            arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in args]
            if extra:
                extra = (*[np.ascontiguousarray(a, dtype=np.float64) for a in extra[:4]], extra[4])
            self._module.step(self._work, float(dt_s), skip, *arrays, *extra)
        out = self._out.copy()
        v = out.tolist()
        roll, pitch, yaw, thrust, rel, tilt_sat, thrust_sat, exc, spread, conf, frozen, scale = (
            self._scalars
        )
        at_tau, at_theta, at_used, at_q, at_qd, at_qdd, at_q_ned = self._vectors
        q_ned = v[at_q_ned]
        setpoint = frozen_record(
            AttitudeThrustSetpoint,
            roll_rad=v[roll],
            pitch_rad=v[pitch],
            yaw_rad=v[yaw],
            thrust_n=v[thrust],
            thrust_relative=v[rel],
            tilt_saturated=v[tilt_sat] == 1.0,
            thrust_saturated=v[thrust_sat] == 1.0,
            q_ned_frd=tuple(q_ned) if q_ned[0] == q_ned[0] else None,
        )
        estimate = frozen_record(
            Estimate,
            theta=out[at_theta],
            excitation=v[exc],
            spread=v[spread],
            confident=v[conf] == 1.0,
            frozen=v[frozen] == 1.0,
            thrust_scale=v[scale],
        )
        reference = frozen_record(DesiredState, q=out[at_q], q_dot=out[at_qd], q_ddot=out[at_qdd])
        return out[at_tau], setpoint, estimate, out[at_used], reference
