"""Run a pure function over many cases: serially, on a local process pool, or on Dask.

The machinery behind ``cartpole bench control`` and ``cartpole bench
robustness``: each case is one offline closed-loop run, a pure function of
its (picklable) case object, so every executor gives the same results, in the
order of the cases.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Sequence


def run_parallel(function: Callable[[Any], Any], cases: Sequence[Any], *, workers: int = 1,
                 dask_address: str | None = None,
                 progress: Callable[[int, int], None] | None = None) -> list[Any]:
    """``[function(c) for c in cases]``, computed by the chosen executor.

    ``workers`` > 1 uses a local process pool of that size; ``dask_address``
    a Dask distributed scheduler (``tcp://host:8786``) instead. ``function``
    must be importable by name in the workers (a module-level function).
    ``progress(done, total)`` is called after every finished case.
    """
    results: list[Any] = [None] * len(cases)
    done = 0

    def _finish(i: int, value: Any) -> None:
        nonlocal done
        results[i] = value
        done += 1
        if progress:
            progress(done, len(cases))

    if dask_address:
        from distributed import Client, as_completed
        with Client(dask_address) as client:
            futures = {client.submit(function, c, pure=False): i for i, c in enumerate(cases)}
            for fut in as_completed(futures):
                _finish(futures[fut], fut.result())
    elif workers > 1 and len(cases) > 1:
        from concurrent.futures import as_completed as cf_completed
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(function, c): i for i, c in enumerate(cases)}
            for fut in cf_completed(futures):
                _finish(futures[fut], fut.result())
    else:
        for i, c in enumerate(cases):
            _finish(i, function(c))
    return results
