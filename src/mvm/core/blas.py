"""BLAS on one thread around the pipeline's many small matrix products, where threads only cost.

The BLAS libraries are looked up once, at the first call (threadpoolctl scans the loaded shared
libraries: about 7 ms a time, more than a small scene's matching); libraries loaded after that
are not limited.
"""
from __future__ import annotations

import functools


@functools.cache
def _controller():
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def one_blas_thread():
    """A context manager limiting every BLAS library loaded so far to one thread."""
    return _controller().limit(limits=1, user_api="blas")
