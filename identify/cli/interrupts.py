"""A Ctrl-C or SIGTERM is never lost in a garbage collector's callback.

A command stops on Ctrl-C or SIGTERM by a ``KeyboardInterrupt`` raised where the signal
lands. Python cannot raise it inside a callback the garbage collector runs (a weakref's, an
object's ``__del__``): it prints ``Exception ignored in ...`` with the traceback and goes on,
so the command would not stop and its log would hold a traceback. While
:func:`interrupts_redelivered` is active such an interrupt is delivered again: the hook hands the
signal to a helper thread, which sends it to the process anew once the hook has returned, and
its handler runs in the main thread at its next bytecode, outside that callback (and again,
should it land in another); nothing is printed for it. Not from the hook itself: a handler run
inside the hook would be ignored as well.
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import sys
import threading

__all__ = ["interrupts_redelivered"]

#: The signals a ``KeyboardInterrupt`` may name (its first argument); a bare one is Ctrl-C's.
_SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}


def _signal_of(interrupt: KeyboardInterrupt) -> signal.Signals:
    name = interrupt.args[0] if interrupt.args else "SIGINT"
    return _SIGNALS.get(name, signal.SIGINT) if isinstance(name, str) else signal.SIGINT


def _send_again(requests: queue.SimpleQueue) -> None:
    """The helper thread: send the process each signal put in ``requests``, until None."""
    while (signum := requests.get()) is not None:
        os.kill(os.getpid(), signum)


@contextlib.contextmanager
def interrupts_redelivered():
    """Within the block, an interrupt raised inside a garbage collector's callback is raised
    again outside it (see the module docstring); other unraisable exceptions are reported as
    before."""
    previous = sys.unraisablehook
    requests = queue.SimpleQueue()  # put() never waits: the hook returns at once
    helper = threading.Thread(target=_send_again, args=(requests,), name="interrupt-again", daemon=True)

    def hook(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            requests.put(_signal_of(unraisable.exc_value))
            return
        previous(unraisable)

    helper.start()
    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous
        requests.put(None)
