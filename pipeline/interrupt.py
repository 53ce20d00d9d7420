"""Interruption by SIGINT (Ctrl-C) and SIGTERM (``kill``, systemd, a batch scheduler).

While a run is under :func:`handling`, either signal raises
:class:`Interrupted` in the main thread: the run stops where it is, removes
its temporary files, stops its worker processes, writes ``run.json`` with
``"status": "interrupted"`` and exits with ``128 + signal number`` (130 for
SIGINT, 143 for SIGTERM), the shells' convention.  A second signal while the
run is cleaning up is ignored (cleaning up takes well under a second; use
SIGKILL to stop at once, which is also safe: the README's crash safety).

The few steps that must not be cut in half (renaming published files into
place and writing the manifest that describes them) run under
:func:`deferred`: a signal arriving then is held and raised when the block
ends.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """The run was asked to stop by a signal.

    Attributes
    ----------
    signum : int
        The signal received.
    exit_code : int
        ``128 + signum``: 130 for SIGINT, 143 for SIGTERM.
    """

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.exit_code = 128 + signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


class _State:
    deferring = 0
    pending: int | None = None
    received: int | None = None


_state = _State()


def received() -> int | None:
    """The signal that interrupted this run (None when there was none)."""
    return _state.received


def _handler(signum: int, frame: object) -> None:
    if _state.received is not None:
        return  # already stopping: the clean-up is short and must finish
    if _state.deferring:
        _state.pending = signum
        return
    _state.received = signum
    raise Interrupted(signum)


@contextlib.contextmanager
def handling() -> Iterator[None]:
    """Turn SIGINT and SIGTERM into :class:`Interrupted` for the block (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in SIGNALS}
    _state.deferring, _state.pending, _state.received = 0, None, None
    for s in SIGNALS:
        signal.signal(s, _handler)
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        _state.deferring, _state.pending, _state.received = 0, None, None


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM for the block; raise :class:`Interrupted` after it if one came."""
    _state.deferring += 1
    try:
        yield
    finally:
        _state.deferring -= 1
    if not _state.deferring and _state.pending is not None:
        signum, _state.pending = _state.pending, None
        _state.received = signum
        raise Interrupted(signum)


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """Hold SIGINT back for the block: processes and threads started in it never receive it.

    Worker processes are started so: a Ctrl-C reaches every process of the
    terminal's group, and only the run that owns the workers must act on it
    (it stops them).  The signal is blocked in this thread's mask, which the
    processes started here inherit through ``exec`` until their initializer
    ignores it; a Ctrl-C arriving during the block is not lost (as it was
    when the block set ``SIG_IGN``) but held (:func:`deferred`) and raised
    when the block ends, and the run stops then.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # the mask is for the processes started here; deferred() holds a signal another thread took
    with deferred():
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)
