"""The QP solvers behind the ``mpc`` stabiliser's :class:`~.mpc_qp.CondensedQp`.

Each back-end is set up once with the QP's matrices (fixed sparsity); each
cycle gets the new cost vector and bounds only, warm-started from the
previous solution (osqp-python's ``update_vectors`` pattern): DAQP's own
wheel (``daqp.Model``, the last working set kept), OSQP's wheel
(``update(q, l, u)``, warm-started ADMM), and the QP solvers bundled with
CasADi (``casadi.conic``: DAQP, qpOASES, OSQP, ProxQP), which take the whole
problem at each call. ``solve()`` returns ``(w, ok, reason)``, the solution
(None if there is none) and the verdict, which the caller checks every time;
after a failed one it calls ``failed()`` (the back-end decides whether its
warm start is worth keeping). CasADi's HPIPM is not one: its interface takes
a multistage (OCP-structured) QP and refuses the dense condensed one. No ROS.
"""
from __future__ import annotations

from typing import Any, ClassVar

import daqp  # the default solver, loaded with the plugins: not read from disk at a switch
import numpy as np

SOLVERS = ('daqp', 'osqp', 'casadi_daqp', 'casadi_qpoases', 'casadi_osqp', 'casadi_proxqp')
"""The QP solvers a :class:`~.mpc_qp.CondensedQp` can use."""

Result = tuple['np.ndarray | None', bool, str]


def _stack_bounds(qp: Any, upper: np.ndarray, lower: np.ndarray) -> None:
    """This cycle's bounds of the variables, then of the rows, into ``upper`` and ``lower``."""
    nv = qp.n_vars
    upper[:nv], lower[:nv] = qp.variable_high, qp.variable_low
    upper[nv:], lower[nv:] = qp.row_high, qp.row_low


class DaqpBackend:
    """DAQP's wheel: ``daqp.Model`` set up once; each cycle ``update(f, bounds)`` and ``solve``.

    Warm start: the model keeps the last working set (``update`` without
    ``sense`` reuses it), also after a solve stopped by the time limit: the
    next cycle goes on from where it got. Simple bounds come first in DAQP's
    bound vectors.
    """

    TIME_LIMIT: ClassVar[int] = -7
    """DAQP's exit flag when ``time_limit`` stopped it."""

    def __init__(self, qp: Any) -> None:
        self.qp = qp
        self.upper = np.concatenate([qp.variable_high, qp.row_high])
        self.lower = np.concatenate([qp.variable_low, qp.row_low])
        self.sense = np.zeros(qp.n_vars + qp.n_rows, dtype=np.int32)
        self.model = daqp.Model()
        self.model.settings = {'time_limit': qp.settings.budget}  # 0: none
        flag, _ = self.model.setup(qp.h, qp.f, qp.a, self.upper, self.lower, self.sense)
        if flag < 0:
            raise ValueError(f'DAQP refused the QP (setup exit flag {flag})')
        self._cold = False

    def reset(self) -> None:
        self._cold = True

    def failed(self) -> None:
        pass  # a real failure has set _cold; a stopped solve keeps its working set

    def solve(self) -> Result:
        qp = self.qp
        _stack_bounds(qp, self.upper, self.lower)
        if self._cold:
            self.model.update(f=qp.f, bupper=self.upper, blower=self.lower, sense=self.sense)
            self._cold = False
        else:
            self.model.update(f=qp.f, bupper=self.upper, blower=self.lower)
        x, _, flag, _ = self.model.solve()
        if flag == self.TIME_LIMIT:  # the working set it reached is the next cycle's start
            return None, False, 'DAQP time limit'
        if flag <= 0:
            self._cold = True
            return None, False, f'DAQP exit flag {flag}'
        return x, True, ''


class OsqpBackend:
    """OSQP's wheel: set up once with the sparse data; each cycle ``update(q, l, u)``.

    Warm start: ADMM starts from the last primal and dual iterate (``warm_starting``).
    """

    def __init__(self, qp: Any) -> None:
        import osqp
        import scipy.sparse as sparse
        self.qp = qp
        a = sparse.vstack([sparse.eye(qp.n_vars), sparse.csc_matrix(qp.a)]).tocsc()
        self.upper = np.concatenate([qp.variable_high, qp.row_high])
        self.lower = np.concatenate([qp.variable_low, qp.row_low])
        self.solver = osqp.OSQP()
        self.solver.setup(P=sparse.triu(qp.h).tocsc(), q=qp.f, A=a, l=self.lower, u=self.upper,
                          verbose=False, eps_abs=1e-7, eps_rel=1e-7, polishing=True,
                          warm_starting=True, max_iter=4000,
                          time_limit=qp.settings.budget or 1e10)  # must be > 0
        self._solved = osqp.SolverStatus.OSQP_SOLVED if hasattr(osqp, 'SolverStatus') else 1

    def reset(self) -> None:
        pass  # ADMM's warm start is only a starting point: a stale one costs iterations

    def failed(self) -> None:
        pass

    def solve(self) -> Result:
        qp = self.qp
        _stack_bounds(qp, self.upper, self.lower)
        self.solver.update(q=qp.f, l=self.lower, u=self.upper)
        result = self.solver.solve()
        if result.info.status_val != self._solved:
            return None, False, f'OSQP: {result.info.status}'
        return result.x, True, ''


class CasadiBackend:
    """A QP solver bundled with CasADi (``casadi.conic``): the data go in at every call.

    Warm start: the previous primal and dual solution (``x0``, ``lam_x0``,
    ``lam_a0``), which the active-set solvers use as their initial guess.
    """

    PLUGINS: ClassVar[dict[str, tuple[str, dict]]] = {
        'casadi_daqp': ('daqp', {}),
        'casadi_qpoases': ('qpoases', {'printLevel': 'none', 'sparse': False,
                                       'schur': False}),
        'casadi_osqp': ('osqp', {'osqp': {'verbose': False, 'eps_abs': 1e-7, 'eps_rel': 1e-7,
                                          'polish': True, 'max_iter': 4000},
                                 'warm_start_primal': True, 'warm_start_dual': True}),
        'casadi_proxqp': ('proxqp', {'proxqp': {'eps_abs': 1e-9, 'verbose': False},
                                     'warm_start_primal': True, 'warm_start_dual': True}),
    }

    def __init__(self, qp: Any) -> None:
        import casadi
        self.qp = qp
        plugin, options = self.PLUGINS[qp.settings.solver]
        options = dict(options, error_on_fail=False, verbose=False)
        structure = {'h': casadi.Sparsity.dense(qp.n_vars, qp.n_vars),
                     'a': casadi.Sparsity.dense(qp.n_rows, qp.n_vars)}
        self.solver = casadi.conic('mpc', plugin, structure, options)
        self.h = casadi.DM(qp.h)
        self.a = casadi.DM(qp.a)
        self.reset()

    def reset(self) -> None:
        self.x0 = self.lam_x0 = self.lam_a0 = None

    def failed(self) -> None:
        self.reset()

    def solve(self) -> Result:
        qp = self.qp
        args = {'h': self.h, 'g': qp.f, 'a': self.a, 'lba': qp.row_low, 'uba': qp.row_high,
                'lbx': qp.variable_low, 'ubx': qp.variable_high}
        if self.x0 is not None:
            args.update(x0=self.x0, lam_x0=self.lam_x0, lam_a0=self.lam_a0)
        result = self.solver(**args)
        stats = self.solver.stats()
        if not stats.get('success', False):
            return None, False, f'{qp.settings.solver}: {stats.get("return_status", "failed")}'
        self.x0, self.lam_x0, self.lam_a0 = result['x'], result['lam_x'], result['lam_a']
        return np.asarray(result['x']).ravel(), True, ''


BACKENDS = {'daqp': DaqpBackend, 'osqp': OsqpBackend,
            **{name: CasadiBackend for name in CasadiBackend.PLUGINS}}
"""Back-end class by :data:`SOLVERS` name."""
