"""The run's next batches made ahead in a child process that runs only when a core would idle.

A step of the maps stage spends about 30 % of its CPU time making its batch (rendering the photo, the
targets, the runtime's flash fit) and the rest in the networks. The run trains on one core; the other is
the machine's foreground. :class:`Prefetcher` forks the run (the child shares the bank's memory: it only
reads it) and makes batches there under ``SCHED_IDLE``, the scheduler class that gets a CPU only when no
other process wants it: whatever runs in the foreground keeps its core, and the run takes its idle time.

Every step's batch is drawn from a generator of its own (:meth:`export.engine.run.Run.step_batch`), so the
batch of step ``k`` is the same whoever makes it: the trainer takes the child's when it is ready and makes
it itself when not (the child then skips ahead). A run is the same, bit for bit, with and without it
(``tests/export/test_engine.py``).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import queue
import signal
import time

#: Batches the child keeps ready at most (each about 40 MB at batch 16, 128²).
DEPTH = 2
#: ``prctl`` option: the signal a child gets when its parent dies.
_PR_SET_PDEATHSIG = 1


def _idle_priority():
    """This process from now on runs only on CPU time no other process wants (``SCHED_IDLE``; nice 19 where
    that is refused)."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        os.nice(19)


def _die_with_parent():
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def _child(make, stage, want, out):
    """Make ``make(step, stage)`` for step ``want.value`` on, skipping ahead to where the trainer is."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the run's handler only asks its own loop to stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C is the trainer's to handle
    _die_with_parent()
    _idle_priority()
    import torch

    torch.set_num_threads(1)
    step = want.value
    while True:
        step = max(step, want.value)
        t0 = time.process_time()
        item = make(step, stage)
        out.put((step, item, time.process_time() - t0))
        step += 1


class Prefetcher:
    """Batches of ``stage`` from step ``first`` on, made by ``make(step, stage)`` in a child process (see the
    module docstring). :meth:`take` returns step ``k``'s batch if the child has it, else None; :meth:`spent`
    the CPU seconds the child spent on the batches received (taken or thrown away) since its last call."""

    def __init__(self, make, stage, first, depth=DEPTH):
        ctx = multiprocessing.get_context("fork")
        self.stage = stage
        self.want = ctx.Value("q", first, lock=False)
        self.queue = ctx.Queue(depth)
        self.ready = {}
        self.cpu = self._reported = 0.0
        self.process = ctx.Process(target=_child, args=(make, stage, self.want, self.queue), daemon=True)
        self.process.start()

    def take(self, step, wait=0.0):
        """Step ``step``'s batch if made (the older ones dropped), waiting up to ``wait`` seconds for it, else
        None: the trainer makes it, and the child goes on from the next."""
        deadline = time.monotonic() + wait
        while step not in self.ready:
            try:
                k, item, cpu = self.queue.get(timeout=max(deadline - time.monotonic(), 0.0)) if wait else \
                    self.queue.get_nowait()
            except queue.Empty:
                break
            self.cpu += cpu
            if k >= step:
                self.ready[k] = item
        for k in [k for k in self.ready if k < step]:
            del self.ready[k]
        self.want.value = step + 1
        return self.ready.pop(step, None)

    def spent(self):
        """CPU seconds of the child's batches received since the last call (the run counts them)."""
        new, self._reported = self.cpu - self._reported, self.cpu
        return new

    def close(self):
        """Stop the child (it holds nothing to save)."""
        if self.process.is_alive():
            self.process.terminate()
        self.process.join(timeout=10)
        self.queue.close()
        self.queue.cancel_join_thread()
