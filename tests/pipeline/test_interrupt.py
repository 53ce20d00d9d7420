"""A Ctrl-C while worker processes start is held, not lost (pipeline/interrupt.py).

Worker processes are started with SIGINT held back so that they never see
it; before, the run itself set ``SIG_IGN`` for those milliseconds and a
Ctrl-C (or a batch scheduler's SIGINT) that landed then was dropped: the
run went on as if nothing had happened.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time

import pytest

from pipeline.interrupt import Interrupted, handling, sigint_held


def test_sigint_during_the_block_is_raised_when_it_ends():
    inside = []
    with handling():
        with pytest.raises(Interrupted) as caught:
            with sigint_held():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                inside.append("the block ran to its end")
            time.sleep(0.5)  # not reached: the signal is raised as the block ends
    assert inside == ["the block ran to its end"]
    assert caught.value.exit_code == 130


def _worker(queue) -> None:
    time.sleep(0.3)
    queue.put("alive")


def test_a_process_started_in_the_block_survives_a_ctrl_c_of_its_group():
    """A Ctrl-C reaching a worker while its interpreter starts (before any handler of its own) does not kill it."""
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    with handling(), sigint_held():
        proc = ctx.Process(target=_worker, args=(queue,))
        proc.start()
        os.kill(proc.pid, signal.SIGINT)  # what the terminal sends every process of the group
    assert queue.get(timeout=30) == "alive"
    proc.join(30)
    assert proc.exitcode == 0
