"""Plant parameter identification from recorded open-loop tests (no ROS).

The thesis finds m_c, c_c,R and c_c,L by simulating the model (4.18) with
the force pulses of a test and minimising the RMSE between the simulated and
measured cart positions, summed per direction (4.22)-(4.26), and the pendulum
friction c_p, v_p from the decay of free swings (section 4.3.2, Appendix E),
then checks the whole model on the "Input" and "Oscillation" tests of
section 4.6. This module does all of it in one fit:

- every recording (:class:`Recording`: sample times, measured x and theta,
  force command held over each sample period) is replayed open loop on
  :class:`cartpole_sim.plant.Plant` (actuator (4.4), saturation, end stops,
  mechanics (4.18) with the friction (4.20)/(4.21)/(4.27)) from its own
  initial state;
- the residuals are the simulated minus measured cart position and pendulum
  angle, each recording normalised by the square root of its sample count,
  so its share of the cost is its mean square error, as (4.22) gives every
  direction's test the same say whatever its length;
- :func:`scipy.optimize.least_squares` (trust-region reflective, bounded,
  like the thesis's ``fmincon`` with bounds) varies any set of
  :class:`~cartpole_sim.model.CartPoleParameters` fields, all recordings
  sharing one parameter set; optionally each recording's initial state too.

:func:`load_recording` is the thin bag loader (rosbag2/MCAP, via
``rosbags``); :func:`simulate_test` synthesises a recording of a test on
the simulated plant, to rehearse the procedure or to test this module.
:class:`PulsePlayer` plays a pulse test sample by sample with a rail guard
(the node :mod:`cartpole_bringup.identify_node` puts it on ROS), and
:func:`rehearse` plays it on the simulated plant first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from cartpole_sim.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario

JOINTS = '/joint_states'
FORCE = '/cartpole/force_command'

DEFAULT_FREE = ('m_c', 'c_c_right', 'c_c_left', 'c_p', 'v_p')
"""Parameters fitted by default: the cart's (4.23) and the pendulum's (4.28)."""

DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    'm_c': (0.5, 20.0),
    'c_c_right': (0.0, 20.0),
    'c_c_left': (0.0, 20.0),
    'v_c': (0.0, 50.0),
    'c_p': (0.0, 0.1),
    'v_p': (0.0, 0.1),
    'm_p': (0.01, 5.0),
    'l': (0.05, 1.0),
}
"""Search bounds per parameter. The thesis bounded m_c, c_c,R, c_c,L to
[1, 5] (4.23); these are wider so that a rig far from the thesis's is not
cut off (the true m_c 4.75 of Table 4.1 sits next to 5). Fields not listed
get [initial / 10, initial x 10]."""

TYPICAL_SCALE: dict[str, float] = {
    'v_c': 1.0, 'c_c_right': 3.0, 'c_c_left': 3.0, 'c_p': 0.004, 'v_p': 0.001,
}
"""Scale of a parameter whose initial value is zero (the search runs on
value / scale, so every variable is of order one)."""

INITIAL_STATE_SCALE = (1.0e-3, 1.0e-2, 1.0e-2, 1.0e-1)
"""Scales of the per-recording initial state offsets [m, rad, m/s, rad/s]."""

MIN_SAMPLES = 20
"""Fewest samples of a usable recording (0.1 s at Ts = 5 ms)."""

NOT_FITTABLE = ('pendulum_ticks_per_rev', 'cart_ticks_over_travel', 'counter_bits',
                'sample_time', 'travel')
"""Fields that describe the sampling and the encoders, not the dynamics."""

_DIVERGED = 10.0
"""Residual [m or rad] used in place of a non-finite simulated sample."""


class IdentificationError(ValueError):
    """Unusable input: a bag without the topics, too few samples, a bad option."""


# -- recordings --------------------------------------------------------------------
@dataclass(frozen=True)
class Recording:
    """One open-loop test: measured positions and the force commands that drove it.

    Parameters
    ----------
    t
        Sample times [s], strictly increasing (gaps allowed: the command is
        held over them, as the device holds its last setpoint).
    x, theta
        Measured cart position [m] and pendulum angle [rad] (continuous,
        pi hanging) at ``t``, quantised as the encoders give them.
    force
        Force command [N] applied from ``t[k]`` until ``t[k + 1]``
        (zero-order hold; docs/architecture.md, one control cycle).
    label
        A name for reports (the bag's directory name).
    """

    t: np.ndarray
    x: np.ndarray
    theta: np.ndarray
    force: np.ndarray
    label: str = ''

    def __post_init__(self) -> None:
        arrays = {}
        for name in ('t', 'x', 'theta', 'force'):
            a = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            object.__setattr__(self, name, a)
            arrays[name] = a
        n = arrays['t'].size
        name = self.label or 'recording'
        if any(a.size != n for a in arrays.values()):
            raise IdentificationError(
                f'{name}: t, x, theta and force must have the same length, got '
                + ', '.join(f'{k} {a.size}' for k, a in arrays.items()))
        if n < MIN_SAMPLES:
            raise IdentificationError(
                f'{name}: {n} samples; at least {MIN_SAMPLES} are needed to fit anything')
        for key, a in arrays.items():
            if not np.all(np.isfinite(a)):
                raise IdentificationError(f'{name}: {key} has non-finite values')
        if not np.all(np.diff(arrays['t']) > 0.0):
            raise IdentificationError(f'{name}: sample times must be strictly increasing')

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def window(self, t_start: float | None = None, t_end: float | None = None) -> 'Recording':
        """The samples with t_start <= t - t[0] <= t_end (seconds from the first sample)."""
        rel = self.t - self.t[0]
        keep = np.ones(rel.size, dtype=bool)
        if t_start is not None:
            keep &= rel >= t_start - 1e-9
        if t_end is not None:
            keep &= rel <= t_end + 1e-9
        return Recording(self.t[keep], self.x[keep], self.theta[keep], self.force[keep],
                         self.label)


def estimate_initial_state(rec: Recording, window: float = 0.05) -> np.ndarray:
    """[x, theta, x_dot, theta_dot] at ``rec.t[0]`` from a quadratic fit of the first samples.

    Positions and rates at the start, least squares over ``window`` seconds
    (at least 3 samples): a rate from two quantised samples would be off by a
    whole tick per 5 ms (18 mm/s, 0.6 rad/s); the fit averages that out. A
    test started from rest gives rates close to zero.
    """
    rel = rec.t - rec.t[0]
    n = max(3, int(np.searchsorted(rel, window, side='right')))
    tt = rel[:n]
    out = np.empty(4)
    for i, y in enumerate((rec.x[:n], rec.theta[:n])):
        c = np.polyfit(tt, y, 2)
        out[i] = c[2]
        out[2 + i] = c[1]
    return out


def quiet_lead_in(rec: Recording, window: float) -> int:
    """Samples from the start up to ``window`` seconds or the first non-zero command."""
    rel = rec.t - rec.t[0]
    n = int(np.searchsorted(rel, window, side='right'))
    active = np.flatnonzero(rec.force[:n] != 0.0)
    return int(active[0]) if active.size else n


def fit_initial_state(rec: Recording, params: CartPoleParameters, *, window: float = 0.5,
                      weight_cart: float = 1.0, weight_pendulum: float | None = None,
                      integration_step: float = 0.001) -> np.ndarray:
    """[x, theta, x_dot, theta_dot] at ``rec.t[0]`` fitted to the start of the recording.

    Least squares of the simulated (:func:`simulate`, with ``params``) minus
    measured positions over the quiet lead-in (:func:`quiet_lead_in`: up to
    ``window`` s, ending at the first non-zero force command, so the fit
    sees no pulse whose response depends on the parameters being sought),
    starting from :func:`estimate_initial_state`. The model carries the
    estimate through the quantisation steps (a pendulum released from rest
    moves less than a tick in its first 10 ms), so a free swing starts with
    the right phase. With fewer than 10 quiet samples the quadratic estimate
    is returned as it is.
    """
    from scipy.optimize import least_squares

    guess = estimate_initial_state(rec)
    n = quiet_lead_in(rec, window)
    if n < 10:
        return guess
    head = Recording(rec.t[:n], rec.x[:n], rec.theta[:n], rec.force[:n], rec.label)
    w_theta = params.l if weight_pendulum is None else weight_pendulum
    w_x = weight_cart if weight_cart > 0 else 1.0
    w_theta = w_theta if w_theta > 0 else params.l
    scale = np.array(INITIAL_STATE_SCALE)
    lo = np.array([-guess[0] / scale[0], -np.inf, -np.inf, -np.inf])
    hi = np.array([(params.travel - guess[0]) / scale[0], np.inf, np.inf, np.inf])
    z0 = np.clip(np.zeros(4), lo + 1e-9, hi - 1e-9)

    def fun(z: np.ndarray) -> np.ndarray:
        xs, thetas = simulate(head, params, guess + z * scale, integration_step)
        r = np.concatenate([w_x * (xs - head.x), w_theta * (thetas - head.theta)])
        return np.nan_to_num(r, nan=_DIVERGED, posinf=_DIVERGED, neginf=-_DIVERGED)

    sol = least_squares(fun, z0, bounds=(lo, hi), method='trf', diff_step=1e-3,
                        x_scale=1.0, max_nfev=50)
    return guess + sol.x * scale


def simulate(rec: Recording, params: CartPoleParameters, initial_state: Sequence[float],
             integration_step: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """Replay a recording's force commands on the plant: simulated (x, theta) at ``rec.t``.

    The plant (:class:`~cartpole_sim.plant.Plant`: actuator (4.4),
    saturation, end stops, mechanics (4.18)) starts from ``initial_state``
    (the cart clipped into the travel, so a start measured against a stop
    does not begin inside the stop's spring) and holds ``rec.force[k]`` over
    ``[t[k], t[k + 1])``. The true (unquantised) positions are returned;
    samples after a non-finite state are NaN.
    """
    x0, theta0, x_dot0, theta_dot0 = (float(v) for v in initial_state)
    x0 = min(max(x0, 0.0), params.travel)
    plant = Plant(params, Scenario(x0=x0, theta0=theta0, x_dot0=x_dot0, theta_dot0=theta_dot0),
                  integration_step=min(integration_step, params.sample_time))
    n = rec.t.size
    xs = np.full(n, np.nan)
    thetas = np.full(n, np.nan)
    dts = np.diff(rec.t)
    force = rec.force
    for k in range(n):
        state = plant.state
        if not (math.isfinite(state[0]) and math.isfinite(state[1])):
            break
        xs[k] = state[0]
        thetas[k] = state[1]
        if k < n - 1:
            plant.step(float(force[k]), float(dts[k]))
    return xs, thetas


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean square of a - b (inf if any value is not finite)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return float(np.sqrt(np.mean(d * d))) if np.all(np.isfinite(d)) else math.inf


# -- the fit -----------------------------------------------------------------------------
@dataclass(frozen=True)
class RecordingFit:
    """The fit of one recording: errors of the simulation before and after."""

    label: str
    samples: int
    duration_s: float
    initial_state: tuple[float, float, float, float]
    """[x, theta, x_dot, theta_dot] the simulation started from (after the fit)."""
    rmse_x_before_m: float
    rmse_x_after_m: float
    rmse_theta_before_rad: float
    rmse_theta_after_rad: float


@dataclass(frozen=True)
class IdentificationResult:
    """What :func:`identify` found.

    ``values``, ``initial_values`` and ``std_errors`` are keyed by the free
    parameter names. ``std_errors`` are approximate one-sigma errors from the
    Jacobian at the solution, cov = s^2 (J^T J)^-1 with s^2 the residual
    variance; they assume independent residuals of equal variance, which
    model errors (correlated in time) violate, so read them as a lower
    bound and as a check of identifiability (a huge error or a correlation
    near +-1 means the tests do not tell the parameters apart).
    """

    params: CartPoleParameters
    free: tuple[str, ...]
    initial_values: dict[str, float]
    values: dict[str, float]
    std_errors: dict[str, float]
    correlation: list[list[float]]
    at_bound: tuple[str, ...]
    recordings: tuple[RecordingFit, ...]
    cost_before: float
    cost_after: float
    """The thesis's cost (4.22) generalised: the sum over recordings of the
    cart position RMSE [m]."""
    success: bool
    message: str
    nfev: int
    njev: int
    simulations: int
    trajectories: tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], ...] = field(
        default=(), repr=False, compare=False)
    """Per recording: simulated (x, theta) before and after the fit."""

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (no trajectories)."""
        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None
        return {
            'free': list(self.free),
            'initial': {k: num(v) for k, v in self.initial_values.items()},
            'fitted': {k: num(v) for k, v in self.values.items()},
            'std_error': {k: num(v) for k, v in self.std_errors.items()},
            'correlation': [[num(v) for v in row] for row in self.correlation],
            'at_bound': list(self.at_bound),
            'cost_before_m': num(self.cost_before),
            'cost_after_m': num(self.cost_after),
            'recordings': [{
                'label': r.label, 'samples': r.samples, 'duration_s': r.duration_s,
                'initial_state': list(r.initial_state),
                'rmse_x_before_m': num(r.rmse_x_before_m), 'rmse_x_after_m': num(r.rmse_x_after_m),
                'rmse_theta_before_rad': num(r.rmse_theta_before_rad),
                'rmse_theta_after_rad': num(r.rmse_theta_after_rad),
            } for r in self.recordings],
            'success': self.success,
            'message': self.message,
            'nfev': self.nfev,
            'njev': self.njev,
            'simulations': self.simulations,
        }


def parse_free(text: str | Sequence[str]) -> tuple[str, ...]:
    """``'m_c,c_c_right'`` (or a sequence) -> validated parameter names, in order, no repeats."""
    names = [s.strip() for s in (text.split(',') if isinstance(text, str) else text)]
    names = [s for s in names if s]
    if not names:
        raise IdentificationError('no free parameters given')
    known = [f for f in CartPoleParameters.__dataclass_fields__]
    fittable = [f for f in known if f not in NOT_FITTABLE]
    for name in names:
        if name not in known:
            raise IdentificationError(f'unknown parameter {name!r}; fittable: {fittable}')
        if name in NOT_FITTABLE:
            raise IdentificationError(
                f'{name} describes the sampling/encoders and cannot be fitted; fittable: {fittable}')
    if len(set(names)) != len(names):
        raise IdentificationError(f'free parameters repeat: {names}')
    return tuple(names)


def default_bounds(name: str, initial: float) -> tuple[float, float]:
    """Search bounds of one parameter (:data:`DEFAULT_BOUNDS`, else initial / 10 .. x 10)."""
    if name in DEFAULT_BOUNDS:
        return DEFAULT_BOUNDS[name]
    if initial > 0:
        return initial / 10.0, initial * 10.0
    if initial < 0:
        return initial * 10.0, initial / 10.0
    return 0.0, TYPICAL_SCALE.get(name, 1.0) * 10.0


def identify(recordings: Sequence[Recording], nominal: CartPoleParameters | None = None, *,
             free: Sequence[str] = DEFAULT_FREE,
             bounds: Mapping[str, tuple[float, float]] | None = None,
             weight_cart: float = 1.0, weight_pendulum: float | None = None,
             refine_initial_state: bool = False, initial_window: float = 0.5, passes: int = 2,
             integration_step: float = 0.001,
             max_nfev: int = 30, rel_step: float = 1.0e-3, tolerance: float = 1.0e-4,
             progress: Callable[[str], None] | None = None) -> IdentificationResult:
    """Fit plant parameters to open-loop tests, (4.22)-(4.26) and section 4.3.2.

    Minimises, over the free parameters p (and, with ``refine_initial_state``,
    each recording's initial state),

        sum_b (1 / n_b) sum_k [ w_x^2 (x_sim - x_meas)^2 + w_theta^2 (theta_sim - theta_meas)^2 ]

    with :func:`scipy.optimize.least_squares` (``trf``, bounded), forward
    differences with a step of ``rel_step`` of each parameter's scale, and
    every recording simulated by :func:`simulate`.

    Parameters
    ----------
    recordings
        The tests; all share one parameter set.
    nominal
        Starting values and every parameter that is not fitted (default: the
        thesis values).
    free
        Names of :class:`~cartpole_sim.model.CartPoleParameters` fields to fit.
    bounds
        Name -> (low, high), overriding :func:`default_bounds`.
    weight_cart, weight_pendulum
        w_x [1/m] and w_theta [1/rad]; w_theta defaults to the pendulum length
        l, so one radian of angle error counts as the tip's arc length in
        metres, like a cart error.
    refine_initial_state
        Each recording's initial state [x, theta, x_dot, theta_dot] comes
        from :func:`fit_initial_state` over its quiet lead-in
        (``initial_window`` s) with the starting parameters; with this flag
        it is also fitted jointly with the parameters (about twice the
        time; worth it when the lead-in is short or a swing was recorded
        already in motion).
    initial_window
        Longest lead-in [s] used by :func:`fit_initial_state`.
    passes
        Without ``refine_initial_state``: how often the initial states are
        fitted (with the parameters found so far) and the parameters fitted
        again from there; the second pass starts near the solution and
        costs a few iterations.
    integration_step
        The plant's RK4 step [s].
    max_nfev
        Most residual evaluations (about the number of iterations).
    tolerance
        ``ftol`` and ``xtol`` of the solver: stop when a step changes the cost
        or the scaled parameters by less than this fraction (1e-4: the cost
        of a fit down to the encoder quantisation only wanders below that).
    progress
        Called with a line of text after each residual evaluation.
    """
    from scipy.optimize import least_squares

    recordings = list(recordings)
    if not recordings:
        raise IdentificationError('no recordings to fit')
    nominal = nominal or CartPoleParameters()
    free = parse_free(free)
    if weight_pendulum is None:
        weight_pendulum = nominal.l
    if not (weight_cart >= 0 and weight_pendulum >= 0 and weight_cart + weight_pendulum > 0):
        raise IdentificationError('weights must be >= 0 and not both zero')
    if not 0.0 < integration_step <= nominal.sample_time:
        raise IdentificationError(
            f'integration step must be in (0, {nominal.sample_time}] s, got {integration_step}')
    bounds = dict(bounds or {})
    unknown = sorted(set(bounds) - set(free))
    if unknown:
        raise IdentificationError(f'bounds given for parameters that are not free: {unknown}')

    p0 = np.array([float(getattr(nominal, name)) for name in free])
    lo = np.empty(p0.size)
    hi = np.empty(p0.size)
    for i, name in enumerate(free):
        lo[i], hi[i] = bounds.get(name, default_bounds(name, p0[i]))
        if not lo[i] < hi[i]:
            raise IdentificationError(f'bounds of {name} must have low < high, got {lo[i]}, {hi[i]}')
    p0 = np.clip(p0, lo, hi)
    scale = np.array([abs(v) if v != 0 else TYPICAL_SCALE.get(n, 1.0) for n, v in zip(free, p0)])

    n_rec = len(recordings)
    n_glob = p0.size
    s0 = [fit_initial_state(r, nominal.replace(**dict(zip(free, p0))), window=initial_window,
                            weight_cart=weight_cart, weight_pendulum=weight_pendulum,
                            integration_step=integration_step) for r in recordings]
    n_nuis = 4 if refine_initial_state else 0
    state_scale = np.array(INITIAL_STATE_SCALE)
    z0 = np.concatenate([p0 / scale, np.zeros(n_nuis * n_rec)])
    lb = np.concatenate([lo / scale, np.full(n_nuis * n_rec, -np.inf)])
    ub = np.concatenate([hi / scale, np.full(n_nuis * n_rec, np.inf)])
    for b in range(n_rec if n_nuis else 0):  # the cart starts inside the travel
        j = n_glob + n_nuis * b
        lb[j] = -s0[b][0] / INITIAL_STATE_SCALE[0]
        ub[j] = (nominal.travel - s0[b][0]) / INITIAL_STATE_SCALE[0]
    norms = [1.0 / math.sqrt(r.t.size) for r in recordings]
    sizes = [2 * r.t.size for r in recordings]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    counter = {'sims': 0, 'nfev': 0}

    def unpack(z: np.ndarray) -> tuple[CartPoleParameters, list[np.ndarray]]:
        values = np.clip(z[:n_glob] * scale, lo, hi)
        params = nominal.replace(**{name: float(v) for name, v in zip(free, values)})
        states = []
        for b in range(n_rec):
            if n_nuis:
                dz = z[n_glob + n_nuis * b:n_glob + n_nuis * (b + 1)]
                states.append(s0[b] + dz * state_scale)
            else:
                states.append(s0[b])
        return params, states

    def rec_residual(b: int, params: CartPoleParameters, state: np.ndarray) -> np.ndarray:
        rec = recordings[b]
        counter['sims'] += 1
        xs, thetas = simulate(rec, params, state, integration_step)
        ex = np.nan_to_num(xs - rec.x, nan=_DIVERGED, posinf=_DIVERGED, neginf=-_DIVERGED)
        et = np.nan_to_num(thetas - rec.theta, nan=_DIVERGED, posinf=_DIVERGED,
                           neginf=-_DIVERGED)
        return np.concatenate([weight_cart * ex, weight_pendulum * et]) * norms[b]

    cache: dict[bytes, list[np.ndarray]] = {}

    def parts(z: np.ndarray) -> list[np.ndarray]:
        key = np.asarray(z, dtype=float).tobytes()
        if key not in cache:
            params, states = unpack(z)
            cache.clear()
            cache[key] = [rec_residual(b, params, states[b]) for b in range(n_rec)]
        return cache[key]

    def fun(z: np.ndarray) -> np.ndarray:
        r = np.concatenate(parts(z))
        counter['nfev'] += 1
        if progress is not None:
            params, _ = unpack(z)
            text = ', '.join(f'{n}={getattr(params, n):.5g}' for n in free)
            progress(f'evaluation {counter["nfev"]}: cost {0.5 * float(r @ r):.6g}  {text}')
        return r

    def jac(z: np.ndarray) -> np.ndarray:
        base = parts(z)
        r0 = np.concatenate(base)
        jm = np.zeros((r0.size, z.size))
        for j in range(z.size):
            h = rel_step * max(abs(z[j]), 1.0)
            if z[j] + h > ub[j]:
                h = -h
            zj = z.copy()
            zj[j] += h
            params, states = unpack(zj)
            if j < n_glob:
                affected = range(n_rec)
            else:
                affected = [(j - n_glob) // n_nuis]
            for b in affected:
                rb = rec_residual(b, params, states[b])
                jm[offsets[b]:offsets[b + 1], j] = (rb - base[b]) / h
        return jm

    def report(z: np.ndarray) -> tuple[CartPoleParameters, list[np.ndarray],
                                       list[tuple[np.ndarray, np.ndarray]]]:
        params, states = unpack(z)
        sims = []
        for b, rec in enumerate(recordings):
            counter['sims'] += 1
            sims.append(simulate(rec, params, states[b], integration_step))
        return params, states, sims

    _, _, before = report(z0)
    z = z0
    nfev = njev = 0
    for fit_pass in range(1 if n_nuis else max(1, int(passes))):
        if fit_pass:  # the initial states again, with the parameters found so far
            params, _ = unpack(z)
            s0[:] = [fit_initial_state(r, params, window=initial_window,
                                       weight_cart=weight_cart, weight_pendulum=weight_pendulum,
                                       integration_step=integration_step) for r in recordings]
            cache.clear()
        sol = least_squares(fun, z, jac=jac, bounds=(lb, ub), method='trf', x_scale=1.0,
                            ftol=tolerance, xtol=tolerance, gtol=1e-10, max_nfev=max_nfev)
        z = sol.x
        nfev += int(sol.nfev)
        njev += int(sol.njev or 0)
    params, states, after = report(sol.x)

    values = {name: float(getattr(params, name)) for name in free}
    std, corr = _standard_errors(sol.jac, sol.fun, n_glob, scale)
    at_bound = tuple(name for i, name in enumerate(free)
                     if np.isclose(values[name], lo[i], rtol=1e-6, atol=1e-12)
                     or np.isclose(values[name], hi[i], rtol=1e-6, atol=1e-12))
    fits = []
    for b, rec in enumerate(recordings):
        fits.append(RecordingFit(
            label=rec.label or f'recording {b + 1}', samples=int(rec.t.size),
            duration_s=rec.duration,
            initial_state=tuple(float(v) for v in states[b]),
            rmse_x_before_m=rmse(before[b][0], rec.x), rmse_x_after_m=rmse(after[b][0], rec.x),
            rmse_theta_before_rad=rmse(before[b][1], rec.theta),
            rmse_theta_after_rad=rmse(after[b][1], rec.theta)))
    return IdentificationResult(
        params=params, free=free,
        initial_values={name: float(v) for name, v in zip(free, p0)},
        values=values, std_errors=dict(zip(free, std)), correlation=corr,
        at_bound=at_bound, recordings=tuple(fits),
        cost_before=float(sum(f.rmse_x_before_m for f in fits)),
        cost_after=float(sum(f.rmse_x_after_m for f in fits)),
        success=bool(sol.success), message=str(sol.message), nfev=nfev,
        njev=njev, simulations=counter['sims'],
        trajectories=tuple((before[b][0], before[b][1], after[b][0], after[b][1])
                           for b in range(n_rec)))


def _standard_errors(jm: np.ndarray, residual: np.ndarray, n_glob: int,
                     scale: np.ndarray) -> tuple[list[float], list[list[float]]]:
    """One-sigma errors and correlations of the first ``n_glob`` variables.

    cov_z = s^2 (J^T J)^+ with s^2 = |r|^2 / (m - n) (Gauss-Newton), through
    the SVD of J; directions with singular values below 1e-10 of the largest
    are unidentifiable and give an infinite error. Variables are value /
    scale, so cov = diag(scale) cov_z diag(scale).
    """
    m, n = jm.shape
    dof = max(m - n, 1)
    s2 = float(residual @ residual) / dof
    _, sv, vt = np.linalg.svd(jm, full_matrices=False)
    keep = sv > sv[0] * 1e-10 if sv.size and sv[0] > 0 else np.zeros(sv.size, dtype=bool)
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0) ** 2, 0.0)
    cov_z = (vt.T * inv) @ vt * s2
    var = np.diag(cov_z)[:n_glob].copy()
    # A direction dropped from the pseudo-inverse leaves the variables it spans unknown.
    null = vt[~keep] if np.any(~keep) else np.zeros((0, n))
    unknown = np.any(np.abs(null[:, :n_glob]) > 1e-6, axis=0) if null.size else np.zeros(
        n_glob, dtype=bool)
    std = np.sqrt(np.maximum(var, 0.0)) * scale
    std[unknown] = math.inf
    sd = np.sqrt(np.maximum(np.diag(cov_z)[:n_glob], 0.0))
    with np.errstate(divide='ignore', invalid='ignore'):
        corr = cov_z[:n_glob, :n_glob] / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), corr, np.nan)
    return [float(v) for v in std], [[float(v) for v in row] for row in corr]


# -- synthetic tests -------------------------------------------------------------------
def pulse_forces(t: np.ndarray, pulses: Sequence[tuple[float, float, float]]) -> np.ndarray:
    """Force commands of a pulse test (section 4.3.1) at sample times ``t``.

    ``pulses`` are (start [s], length [s], force [N]); the command is the
    pulse's force for start <= t < start + length, zero elsewhere.
    """
    t = np.asarray(t, dtype=float)
    force = np.zeros(t.size)
    for start, length, value in pulses:
        force[(t >= start - 1e-9) & (t < start + length - 1e-9)] = value
    return force


def simulate_test(params: CartPoleParameters, force: Sequence[float] | np.ndarray,
                  scenario: Scenario | None = None, *, integration_step: float = 0.001,
                  label: str = 'simulated') -> Recording:
    """A recording of an open-loop test on the simulated plant (encoders quantised).

    ``force[k]`` is held over the k-th sample period (Ts = ``params.sample_time``);
    the measurements are :meth:`Plant.measure` (quantised, noisy if the
    scenario says so) at t = k Ts.
    """
    force = np.asarray(force, dtype=float)
    plant = Plant(params, scenario or Scenario(), integration_step=integration_step)
    n = force.size
    t = np.empty(n)
    x = np.empty(n)
    theta = np.empty(n)
    for k in range(n):
        m = plant.measure()
        t[k], x[k], theta[k] = m.t, m.x, m.theta
        plant.step(float(force[k]))
    return Recording(t, x, theta, force, label)


# -- playing a pulse test -------------------------------------------------------------------
@dataclass(frozen=True)
class Pulse:
    """One force pulse of a test (section 4.3.1): ``force`` [N] held for ``length`` [s]."""

    force: float
    length: float


MAX_PULSE_LENGTH = 1.0
"""Longest pulse [s]; at 15 N the cart gains about 2.5 m/s in a second, far beyond the rail."""


def parse_pulse_plan(text: str, params: CartPoleParameters | None = None) -> tuple[Pulse, ...]:
    """``'15:0.25,-12:0.25'`` -> pulses (force [N] : length [s], comma-separated).

    Forces must be non-zero and within what the amplifier gives
    (``params.force_min`` .. ``params.force_max``); lengths in (0, 1] s.
    """
    params = params or CartPoleParameters()
    pulses = []
    for item in (s.strip() for s in str(text).split(',')):
        if not item:
            continue
        force, sep, length = item.partition(':')
        try:
            if not sep:
                raise ValueError
            pulse = Pulse(float(force), float(length))
        except ValueError:
            raise IdentificationError(
                f'pulse {item!r} is not FORCE:LENGTH (e.g. 15:0.25 for 15 N over 0.25 s)') from None
        if not (math.isfinite(pulse.force) and pulse.force != 0.0
                and params.force_min <= pulse.force <= params.force_max):
            raise IdentificationError(
                f'pulse force {pulse.force} N must be non-zero and within '
                f'[{params.force_min:.4g}, {params.force_max:.4g}] N')
        if not (math.isfinite(pulse.length) and 0.0 < pulse.length <= MAX_PULSE_LENGTH):
            raise IdentificationError(
                f'pulse length {pulse.length} s must be in (0, {MAX_PULSE_LENGTH}] s')
        pulses.append(pulse)
    if not pulses:
        raise IdentificationError('the pulse plan is empty')
    return tuple(pulses)


@dataclass
class PulsePlayer:
    """Plays a pulse test sample by sample, with a rail guard (no ROS).

    Call :meth:`update` with every sample's time and measured cart position;
    it returns the force command for that sample (held until the next):

    1. zero for ``lead_in`` s (the quiet start :func:`fit_initial_state` uses);
    2. each pulse's force for its length, then zero until the cart has stood
       still (within two cart ticks) for ``settle`` s, or ``max_wait`` s
       passed; then the next pulse;
    3. zero once every pulse has settled (:attr:`done`).

    Rail guard: a pulse pushing towards a stop while the cart is within
    ``margin`` of that stop is cut to zero, and the rest of the plan is
    dropped (:attr:`reason` says why). Zero force lets the cart coast on its
    friction; it does not brake, so size the pulses with :func:`rehearse`.
    """

    pulses: tuple[Pulse, ...]
    params: CartPoleParameters = field(default_factory=CartPoleParameters)
    lead_in: float = 0.5
    settle: float = 1.0
    margin: float = 0.1
    max_wait: float = 10.0
    done: bool = field(default=False, init=False)
    reason: str = field(default='', init=False)
    """Empty while all is well; the guard's reason when it cut the plan short."""
    index: int = field(default=0, init=False)
    """The pulse being played or settled after."""
    _t0: float | None = field(default=None, init=False, repr=False)
    _phase: str = field(default='lead_in', init=False, repr=False)
    _t_phase: float = field(default=0.0, init=False, repr=False)
    _samples: int = field(default=0, init=False, repr=False)
    _anchor: tuple[float, float] = field(default=(0.0, 0.0), init=False, repr=False)

    def update(self, t: float, x: float) -> float:
        """The force command [N] for the sample at ``t`` [s] with cart position ``x`` [m]."""
        if self._t0 is None:
            self._t0 = t
            self._t_phase = t
            self._anchor = (t, x)
        if abs(x - self._anchor[1]) > 2.0 * self.params.cart_resolution:
            self._anchor = (t, x)  # the cart moved: stillness counts from here
        if self.done:
            return 0.0
        if self._phase == 'lead_in':
            if t - self._t0 < self.lead_in - 1e-9:
                return 0.0
            self._begin('pulse', t)
        if self._phase == 'settle':
            still = t - self._anchor[0] >= self.settle - 1e-9
            if not (still or t - self._t_phase >= self.max_wait - 1e-9):
                return 0.0
            if self.index + 1 >= len(self.pulses):
                self.done = True
                return 0.0
            self.index += 1
            self._begin('pulse', t)
        pulse = self.pulses[self.index]
        if self._samples >= max(1, int(round(pulse.length / self.params.sample_time))):
            self._begin('settle', t)
            return 0.0
        if (pulse.force > 0 and x > self.params.travel - self.margin) or \
                (pulse.force < 0 and x < self.margin):
            self.reason = (f'rail guard: pulse {self.index + 1} ({pulse.force:g} N) cut at '
                           f'x = {x:.3f} m, within {self.margin:g} m of the stop it pushes to')
            self.index = len(self.pulses) - 1
            self._begin('settle', t)
            return 0.0
        self._samples += 1
        return pulse.force

    def _begin(self, phase: str, t: float) -> None:
        self._phase, self._t_phase, self._samples = phase, t, 0


def rehearse(pulses: Sequence[Pulse], params: CartPoleParameters | None = None, *,
             x0: float = 0.0, theta0: float = math.pi, lead_in: float = 0.5,
             settle: float = 1.0, margin: float = 0.1, max_duration: float = 60.0,
             integration_step: float = 0.001) -> tuple[Recording, PulsePlayer]:
    """Play a pulse plan on the simulated plant: the predicted test and the player.

    The same :class:`PulsePlayer` the rig will see, driven by
    :class:`~cartpole_sim.plant.Plant` measurements; use it to size the
    pulses before trying them (where does the cart stop? does the guard
    trip?).
    """
    params = params or CartPoleParameters()
    player = PulsePlayer(tuple(pulses), params, lead_in=lead_in, settle=settle, margin=margin)
    plant = Plant(params, Scenario(x0=x0, theta0=theta0), integration_step=integration_step)
    t, x, theta, force = [], [], [], []
    n_max = int(round(max_duration / params.sample_time))
    for _ in range(n_max):
        m = plant.measure()
        f = player.update(m.t, m.x)
        t.append(m.t)
        x.append(m.x)
        theta.append(m.theta)
        force.append(f)
        if player.done:
            break
        plant.step(f)
    return Recording(np.array(t), np.array(x), np.array(theta), np.array(force),
                     'rehearsal'), player


def rehearsal_warnings(rec: Recording, player: PulsePlayer) -> list[str]:
    """Why a rehearsed pulse plan is unsafe to play on the rig ([] if it is not).

    Unsafe: the rail guard cut a pulse; the cart reached the travel's ends;
    or, once it has left the stop zones (``player.margin`` from each end),
    it came back within them (a coasting cart is not braked by anything but
    its friction).
    """
    p = player.params
    out = []
    if player.reason:
        out.append(player.reason)
    if not player.done:
        out.append(f'the plan did not finish within {rec.duration:.1f} s')
    if np.any(rec.x < 0.0) or np.any(rec.x > p.travel):
        out.append(f'the cart reaches an end stop (x from {rec.x.min():.3f} to '
                   f'{rec.x.max():.3f} m, travel {p.travel} m)')
    inside = (rec.x >= player.margin) & (rec.x <= p.travel - player.margin)
    if np.any(inside):
        first = int(np.argmax(inside))
        if not np.all(inside[first:]):
            k = first + int(np.argmin(inside[first:]))
            out.append(f'the cart coasts to x = {rec.x[k]:.3f} m at t = {rec.t[k]:.2f} s, within '
                       f'{player.margin:g} m of a stop')
    return out


# -- bags -----------------------------------------------------------------------------------
def _stamp_ns(stamp_ns: int, log_ns: int) -> int:
    return stamp_ns if stamp_ns > 0 else int(log_ns)


def sample_indices(t: np.ndarray, sample_time: float, window: int = 20) -> np.ndarray:
    """Sample numbers of samples taken every ``sample_time`` but stamped late and irregularly.

    A stamp is the true sample time plus a latency >= 0 (receipt on the host:
    serial buffering delivers lines in bursts). Counting the samples gives
    their numbers, except where samples were lost. With e_k = (t_k - t_0) / Ts
    - k, a loss raises e permanently by one, latency only for a while; the
    minimum of e over the next ``window`` samples is the latency-free part,
    and its rise since the start, rounded and never decreasing, is the number
    of samples lost so far (a loss within the last ``window`` samples goes
    unnoticed rather than a late burst at the end being taken for one).
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    k = np.arange(n)
    if n < 2:
        return k
    e = (t - t[0]) / sample_time - k
    w = max(1, min(int(window), n))
    # The last window's minimum closes the series: a burst at the very end is not a loss.
    padded = np.concatenate([e, np.full(w - 1, e[-w:].min())])
    floor = np.lib.stride_tricks.sliding_window_view(padded, w).min(axis=1)
    lost = np.maximum.accumulate(np.maximum(np.round(floor - floor[0]), 0.0)).astype(np.int64)
    return k + lost


def recording_from_messages(samples: Sequence[tuple[int, float, float]],
                            commands: Sequence[tuple[int, float]], *,
                            sample_time: float = 0.005, command_timeout: float = 0.05,
                            zero_force: bool = False, label: str = '') -> Recording:
    """A :class:`Recording` from /joint_states samples and force commands.

    ``samples`` are (time [ns], x, theta), ``commands`` (time [ns], F). The
    sample times become k Ts (:func:`sample_indices`: the device samples
    every Ts exactly, the host's receipt stamps jitter and come in bursts;
    lost samples leave gaps). ``force[k]`` is the last command
    stamped at or before sample k (a command carries the stamp of the sample
    it answers, docs/architecture.md), zero before the first command and
    once the last command is older than ``command_timeout`` (the watchdogs
    of the bridge and the device then set zero current, SPEC section 4).
    """
    name = label or 'recording'
    if not samples:
        raise IdentificationError(f'{name}: no {JOINTS} samples with cart and pendulum positions')
    if not commands and not zero_force:
        raise IdentificationError(
            f'{name}: no {FORCE} messages; an open-loop test needs its force commands '
            '(for a free swing with nothing commanding, pass --zero-force)')
    rows = np.array(sorted(set(samples)), dtype=float)  # a re-published sample counts once
    t_ns = rows[:, 0]
    grid = sample_indices(t_ns * 1e-9, sample_time)
    keep = np.concatenate([[True], np.diff(grid) > 0])
    grid, rows, t_ns = grid[keep], rows[keep], t_ns[keep]
    t = grid * sample_time
    force = np.zeros(t.size)
    if commands:
        cmd = np.array(sorted(commands), dtype=float)
        if cmd.shape[0] > 1 and cmd[0, 0] == cmd[-1, 0]:
            raise IdentificationError(
                f'{name}: all {cmd.shape[0]} {FORCE} messages carry the same time, so they '
                'cannot be placed in time (published with a zero header.stamp and recorded '
                "with log_time 'stamp'?); stamp the commands or record with log_time 'receive'")
        # A command at or before a sample's (unsnapped) time, within half a period of jitter,
        # and not older than the watchdog's hold time.
        late = t_ns + 0.5 * sample_time * 1e9
        idx = np.searchsorted(cmd[:, 0], late, side='right') - 1
        fresh = (idx >= 0) & (late - cmd[np.maximum(idx, 0), 0] <= command_timeout * 1e9)
        force = np.where(fresh, cmd[np.maximum(idx, 0), 1], 0.0)
    return Recording(t, rows[:, 1], rows[:, 2], force, label)


def load_recording(path: str | Path, *, t_start: float | None = None,
                   t_end: float | None = None, sample_time: float = 0.005,
                   command_timeout: float = 0.05, zero_force: bool = False) -> Recording:
    """Read a test from a rosbag2 bag (MCAP or sqlite3) written by the recorder.

    Uses ``/joint_states`` (names ``cart``, ``pendulum``, positions x and
    theta, ``header.stamp``) and ``/cartpole/force_command`` (``effort`` of
    ``cart``, ``header.stamp``); a zero stamp falls back to the bag's log
    time. ``t_start``/``t_end`` [s from the first sample] cut a window out.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from .analyze import parse_joint_state

    path = Path(path)
    label = path.name if path.name != 'bag' else path.parent.name
    if not path.exists():
        raise IdentificationError(f'{path}: no such bag')
    if path.is_dir() and not (path / 'metadata.yaml').is_file():
        raise IdentificationError(f'{path} is not a rosbag2 bag (no metadata.yaml)')
    samples: list[tuple[int, float, float]] = []
    commands: list[tuple[int, float]] = []
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            connections = [c for c in reader.connections if c.topic in (JOINTS, FORCE)
                           and c.msgtype == 'sensor_msgs/msg/JointState']
            messages = reader.messages(connections=connections) if connections else ()
            for connection, log_ns, raw in messages:  # (an empty list would mean all topics)
                stamp, names, position, _, effort = parse_joint_state(raw)
                when = _stamp_ns(stamp, log_ns)
                if connection.topic == JOINTS:
                    try:
                        i_x, i_t = names.index('cart'), names.index('pendulum')
                    except ValueError:
                        i_x, i_t = 0, 1
                    if position.size > max(i_x, i_t):
                        samples.append((when, float(position[i_x]), float(position[i_t])))
                else:
                    i_f = names.index('cart') if 'cart' in names else 0
                    if effort.size > i_f and math.isfinite(effort[i_f]):
                        commands.append((when, float(effort[i_f])))
    except IdentificationError:
        raise
    except Exception as error:  # rosbags raises its own types for broken bags
        raise IdentificationError(f'{path}: cannot read the bag: {error}') from None
    rec = recording_from_messages(samples, commands, sample_time=sample_time,
                                  command_timeout=command_timeout, zero_force=zero_force,
                                  label=label)
    if t_start is not None or t_end is not None:
        rec = rec.window(t_start, t_end)
    return rec
