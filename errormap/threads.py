"""The one thread-limit helper: ``with limit_threads(1): ...`` (torch and/or BLAS), restored after.

Small array work costs far more on several threads than on one on a busy machine (measured: 81 ms vs 0.8 ms
for a 40-point network call, 1.7 s vs 2 ms for a PKM SVD). It never imports torch (torch is limited only when
already loaded); BLAS is limited through ``threadpoolctl`` when installed."""
from __future__ import annotations

import contextlib
import numbers
import sys

LIBRARIES = ("torch", "blas")


@contextlib.contextmanager
def limit_threads(n: int | None, libraries=("torch",)):
    """Run the block with at most ``n`` threads in ``libraries`` (from :data:`LIBRARIES`).

    ``n`` None or 0: unchanged. torch: ``torch.set_num_threads(n)`` if torch is loaded and
    its count differs, the old count restored after. blas: ``threadpoolctl.threadpool_limits(n,
    user_api="blas")`` (nothing when threadpoolctl is not installed).
    """
    libraries = tuple(libraries)
    unknown = sorted(set(libraries) - set(LIBRARIES))
    if unknown:
        raise ValueError(f"Expected libraries from {list(LIBRARIES)}, got {unknown}")
    if n is not None and not (isinstance(n, numbers.Integral) and n >= 0):
        raise ValueError(f"Expected a thread count ≥ 0 or None, got {n!r}")
    n = None if n is None else int(n)
    with contextlib.ExitStack() as stack:
        if n and "blas" in libraries:
            try:
                from threadpoolctl import threadpool_limits
            except ImportError:  # optional (comes with scikit-learn)
                pass
            else:
                stack.enter_context(threadpool_limits(n, user_api="blas"))
        torch = sys.modules.get("torch") if "torch" in libraries else None
        old = torch.get_num_threads() if torch is not None else None
        if not n or torch is None or n == old:
            yield
            return
        torch.set_num_threads(int(n))
        try:
            yield
        finally:
            torch.set_num_threads(old)

