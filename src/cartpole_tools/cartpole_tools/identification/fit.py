"""The fit: plant parameters from open-loop tests by least squares, (4.22)-(4.26) (no ROS)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from cartpole_core.model import CartPoleParameters

from .recording import IdentificationError, Recording
from .replay import _DIVERGED, INITIAL_STATE_SCALE, fit_initial_state, rmse, simulate

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

NOT_FITTABLE = ('pendulum_ticks_per_rev', 'cart_ticks_over_travel', 'counter_bits',
                'sample_time', 'travel')
"""Fields that describe the sampling and the encoders, not the dynamics."""



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
        raise IdentificationError('--free: no free parameters given')
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
        Names of :class:`~cartpole_core.model.CartPoleParameters` fields to fit.
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

    problem = _LeastSquares(recordings, nominal, free, p0, lo, hi, scale,
                            weight_cart=weight_cart, weight_pendulum=weight_pendulum,
                            refine_initial_state=refine_initial_state,
                            initial_window=initial_window, integration_step=integration_step,
                            rel_step=rel_step, progress=progress)
    before = problem.report(problem.z0)[2]
    z = problem.z0
    nfev = njev = 0
    for fit_pass in range(1 if problem.n_nuis else max(1, int(passes))):
        if fit_pass:  # the initial states again, with the parameters found so far
            problem.refit_initial_states(z)
        sol = least_squares(problem.fun, z, jac=problem.jac, bounds=(problem.lb, problem.ub),
                            method='trf', x_scale=1.0, ftol=tolerance, xtol=tolerance,
                            gtol=1e-10, max_nfev=max_nfev)
        z = sol.x
        nfev += int(sol.nfev)
        njev += int(sol.njev or 0)
    params, states, after = problem.report(sol.x)

    values = {name: float(getattr(params, name)) for name in free}
    std, corr = _standard_errors(sol.jac, sol.fun, p0.size, scale)
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
        njev=njev, simulations=problem.counter['sims'],
        trajectories=tuple((before[b][0], before[b][1], after[b][0], after[b][1])
                           for b in range(len(recordings))))


class _LeastSquares:
    """The residuals and Jacobian that :func:`identify` hands to ``least_squares``.

    The variables z are the free parameters divided by their scales, then
    (with ``refine_initial_state``) 4 offsets of each recording's initial
    state in units of :data:`INITIAL_STATE_SCALE`. A recording's residual is
    [w_x (x_sim - x_meas), w_theta (theta_sim - theta_meas)] / sqrt(n_b);
    the Jacobian is by forward differences, simulating a recording again only
    where a variable touches it (an initial state touches one).
    """

    def __init__(self, recordings: list[Recording], nominal: CartPoleParameters,
                 free: tuple[str, ...], p0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 scale: np.ndarray, *, weight_cart: float, weight_pendulum: float,
                 refine_initial_state: bool, initial_window: float, integration_step: float,
                 rel_step: float, progress: Callable[[str], None] | None) -> None:
        self.recordings, self.nominal, self.free = recordings, nominal, free
        self.lo, self.hi, self.scale = lo, hi, scale
        self.weight_cart, self.weight_pendulum = weight_cart, weight_pendulum
        self.initial_window, self.integration_step = initial_window, integration_step
        self.rel_step, self.progress = rel_step, progress
        self.n_rec, self.n_glob = len(recordings), p0.size
        self.s0 = self._initial_states(nominal.replace(**dict(zip(free, p0))))
        self.n_nuis = n_nuis = 4 if refine_initial_state else 0
        self.state_scale = np.array(INITIAL_STATE_SCALE)
        self.z0 = np.concatenate([p0 / scale, np.zeros(n_nuis * self.n_rec)])
        self.lb = np.concatenate([lo / scale, np.full(n_nuis * self.n_rec, -np.inf)])
        self.ub = np.concatenate([hi / scale, np.full(n_nuis * self.n_rec, np.inf)])
        for b in range(self.n_rec if n_nuis else 0):  # the cart starts inside the travel
            j = self.n_glob + n_nuis * b
            self.lb[j] = -self.s0[b][0] / INITIAL_STATE_SCALE[0]
            self.ub[j] = (nominal.travel - self.s0[b][0]) / INITIAL_STATE_SCALE[0]
        self.norms = [1.0 / math.sqrt(r.t.size) for r in recordings]
        self.offsets = np.concatenate([[0], np.cumsum([2 * r.t.size for r in recordings])])
        self.counter = {'sims': 0, 'nfev': 0}
        self.cache: dict[bytes, list[np.ndarray]] = {}

    def unpack(self, z: np.ndarray) -> tuple[CartPoleParameters, list[np.ndarray]]:
        values = np.clip(z[:self.n_glob] * self.scale, self.lo, self.hi)
        params = self.nominal.replace(**{name: float(v) for name, v in zip(self.free, values)})
        states = []
        for b in range(self.n_rec):
            if self.n_nuis:
                dz = z[self.n_glob + self.n_nuis * b:self.n_glob + self.n_nuis * (b + 1)]
                states.append(self.s0[b] + dz * self.state_scale)
            else:
                states.append(self.s0[b])
        return params, states

    def _initial_states(self, params: CartPoleParameters) -> list[np.ndarray]:
        """Every recording's initial state fitted over its quiet lead-in with ``params``."""
        return [fit_initial_state(r, params, window=self.initial_window,
                                  weight_cart=self.weight_cart,
                                  weight_pendulum=self.weight_pendulum,
                                  integration_step=self.integration_step)
                for r in self.recordings]

    def refit_initial_states(self, z: np.ndarray) -> None:
        params, _ = self.unpack(z)
        self.s0[:] = self._initial_states(params)
        self.cache.clear()

    def rec_residual(self, b: int, params: CartPoleParameters, state: np.ndarray) -> np.ndarray:
        rec = self.recordings[b]
        self.counter['sims'] += 1
        xs, thetas = simulate(rec, params, state, self.integration_step)
        ex = np.nan_to_num(xs - rec.x, nan=_DIVERGED, posinf=_DIVERGED, neginf=-_DIVERGED)
        et = np.nan_to_num(thetas - rec.theta, nan=_DIVERGED, posinf=_DIVERGED,
                           neginf=-_DIVERGED)
        return np.concatenate([self.weight_cart * ex, self.weight_pendulum * et]) * self.norms[b]

    def parts(self, z: np.ndarray) -> list[np.ndarray]:
        key = np.asarray(z, dtype=float).tobytes()
        if key not in self.cache:
            params, states = self.unpack(z)
            self.cache.clear()
            self.cache[key] = [self.rec_residual(b, params, states[b]) for b in range(self.n_rec)]
        return self.cache[key]

    def fun(self, z: np.ndarray) -> np.ndarray:
        r = np.concatenate(self.parts(z))
        self.counter['nfev'] += 1
        if self.progress is not None:
            params, _ = self.unpack(z)
            text = ', '.join(f'{n}={getattr(params, n):.5g}' for n in self.free)
            cost = 0.5 * float(r @ r)
            self.progress(f'evaluation {self.counter["nfev"]}: cost {cost:.6g}  {text}')
        return r

    def jac(self, z: np.ndarray) -> np.ndarray:
        base = self.parts(z)
        r0 = np.concatenate(base)
        jm = np.zeros((r0.size, z.size))
        for j in range(z.size):
            h = self.rel_step * max(abs(z[j]), 1.0)
            if z[j] + h > self.ub[j]:
                h = -h
            zj = z.copy()
            zj[j] += h
            params, states = self.unpack(zj)
            affected = range(self.n_rec) if j < self.n_glob else [(j - self.n_glob) // self.n_nuis]
            for b in affected:
                rb = self.rec_residual(b, params, states[b])
                jm[self.offsets[b]:self.offsets[b + 1], j] = (rb - base[b]) / h
        return jm

    def report(self, z: np.ndarray) -> tuple[CartPoleParameters, list[np.ndarray],
                                             list[tuple[np.ndarray, np.ndarray]]]:
        params, states = self.unpack(z)
        sims = []
        for b, rec in enumerate(self.recordings):
            self.counter['sims'] += 1
            sims.append(simulate(rec, params, states[b], self.integration_step))
        return params, states, sims


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
