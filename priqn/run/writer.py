"""The run folder's background writer: a training run's disk work off the loop's critical
path (issue 61), without changing what is written or when the record says it is there.

The loop captures a checkpoint or a snapshot (copies of the tensors, arrays and generator
states it holds: milliseconds) and hands the writing of its files to the one thread of
:class:`BackgroundWriter`, then goes on training. The thread runs one job at a time, in
the order they were handed over: each job writes its files and then updates meta.json, so
every meta.json write of a running session goes through it (no two read-modify-writes of
the file at once) and meta.json's ``steps_done`` says ``N`` only once the checkpoint at
``N`` is on disk. A job's error is raised in the loop's thread, as it would have been
there: at the next hand-over, at :meth:`BackgroundWriter.check` or when the writer is
left. ``background=False`` runs every job where it is handed over (what ``priqn bench
loop`` compares with).
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Callable
from types import TracebackType


class BackgroundWriter:
    """One thread that runs the disk jobs handed to it (:meth:`submit`), one at a time, in
    order; a context manager that waits for the job in flight when it is left.

    At most one job is in flight: :meth:`submit` first waits for the one before (so the
    copies a job holds are never more than one checkpoint's), and raises its error.
    """

    def __init__(self, background: bool = True) -> None:
        self.background = background
        """Jobs run in the writer's thread (False: where they are handed over)."""
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None
        if background:
            self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="priqn-writer")
        self._in_flight: concurrent.futures.Future[None] | None = None

    def submit(self, job: Callable[[], None]) -> None:
        """Run ``job`` once the job before it is done (its error is raised here instead)."""
        self.wait()
        if self._pool is None:
            job()
        else:
            self._in_flight = self._pool.submit(job)

    def wait(self) -> None:
        """Wait for the job in flight; if it failed, raise its error here."""
        job, self._in_flight = self._in_flight, None
        if job is not None:
            job.result()

    def check(self) -> None:
        """Raise the error of a job that has failed by now (without waiting for one still
        running)."""
        if self._in_flight is not None and self._in_flight.done():
            self.wait()

    def close(self) -> None:
        """Wait for the job in flight, without raising its error, and stop the thread."""
        if self._in_flight is not None:
            concurrent.futures.wait([self._in_flight])
            self._in_flight = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)

    def __enter__(self) -> BackgroundWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Wait for the job in flight. Its error is raised when the block ends without one
        of its own; otherwise the block's error goes on (the job's is the lesser news)."""
        try:
            if exc_type is None:
                self.wait()
        finally:
            self.close()
