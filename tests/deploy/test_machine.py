"""aat_deploy.machine.one_blas_thread: numpy's BLAS at one thread inside, what it was restored after the outermost
one, also when the body raises."""

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from aat_deploy.machine import one_blas_thread


def blas_threads() -> set[int]:
    return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def test_one_blas_thread_inside_and_restored_after():
    if not blas_threads():
        pytest.skip("numpy here has no BLAS that threadpoolctl can set")
    with threadpool_limits(limits=2, user_api="blas"):  # what a 2-core machine starts with, whatever runs this
        assert blas_threads() == {2}
        with one_blas_thread():
            assert blas_threads() == {1}
            with one_blas_thread():
                assert blas_threads() == {1}
            assert blas_threads() == {1}  # an inner one leaves the outer's limit
        assert blas_threads() == {2}

        @one_blas_thread()
        def fails():
            assert blas_threads() == {1}
            raise RuntimeError("inside")

        with pytest.raises(RuntimeError):
            fails()
        assert blas_threads() == {2}
