"""Single-threaded BLAS while solving: see :mod:`gesture_pose.core.threads`."""

from ..threads import single_thread_blas

__all__ = ["single_thread_blas"]
