"""Single-threaded BLAS and two row chunks in two threads while solving.

See :mod:`gesture_pose.core.threads`.
"""

from ..threads import in_background, row_threads, single_thread_blas, split_rows

__all__ = ["in_background", "row_threads", "single_thread_blas", "split_rows"]
