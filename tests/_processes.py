"""Two holders of a capture's views emulated in one process: two threads that sum their arrays through
a barrier, as processes joined by `jax.distributed` do with `jaxgenus.optim.summed_over_processes`."""

from __future__ import annotations

import threading

import numpy as np


def as_two_processes(run):
    """`[run(0, total), run(1, total)]`, each in its own thread, where `total(a)` returns the sum of
    the two threads' `a` (both must call it as often, in the same order, as processes would)."""
    box, meet, out = [None, None], threading.Barrier(2, timeout=600), [None, None]

    def holder(i):
        def total(a):
            box[i] = np.asarray(a)
            meet.wait()
            summed = box[0] + box[1]
            meet.wait()
            return summed
        try:
            out[i] = run(i, total)
        except BaseException as err:  # a failure in one holder must not leave the other waiting
            meet.abort()
            out[i] = err

    threads = [threading.Thread(target=holder, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for o in out:
        if isinstance(o, BaseException):
            raise o
    return out
