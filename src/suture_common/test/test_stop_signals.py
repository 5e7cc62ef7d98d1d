# SPDX-License-Identifier: Apache-2.0
"""StopSignals: SIGINT and SIGTERM become a flag; handlers come back, or stay ignored once stopping."""

import os
import signal

import pytest

from suture_common.stop_signals import StopSignals


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_sets_the_flag_and_later_ones_are_ignored(signum):
    before = {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS}
    try:
        with StopSignals() as stop:
            assert stop.received is None
            os.kill(os.getpid(), signum)  # handled at the next bytecode: no KeyboardInterrupt, no exit
            assert stop.received == signum
            other = signal.SIGTERM if signum == signal.SIGINT else signal.SIGINT
            os.kill(os.getpid(), other)
            assert stop.received == signum  # the first signal is the one reported
        # stopping: a Ctrl-C during interpreter shut-down must not raise KeyboardInterrupt there
        assert signal.getsignal(signum) is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGINT)
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


def test_handlers_are_restored_when_no_signal_came():
    before = {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS}
    with StopSignals() as stop:
        assert all(signal.getsignal(sig) == stop._handle for sig in StopSignals.SIGNALS)
    assert {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS} == before
