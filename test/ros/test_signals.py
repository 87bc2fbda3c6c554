"""The stop handlers of the long-running commands (ros/node/signals.py), with real signals."""

from __future__ import annotations

import os
import signal

import pytest

from sepfm_ros.ros.node.signals import DeferredStop, install_stop_handlers, restore_handlers


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_deferred_stop_waits_for_the_safe_point_and_a_second_signal_stops_at_once(sig):
    stop = DeferredStop()
    previous = install_stop_handlers(stop)
    try:
        stop.check()  # nothing requested: no-op
        os.kill(os.getpid(), sig)  # the handler runs before the next bytecode: no raise
        assert stop.requested
        with pytest.raises(KeyboardInterrupt):
            stop.check()
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), sig)
            for _ in range(1000):  # the handler runs between bytecodes
                pass
    finally:
        restore_handlers(previous)
    assert signal.getsignal(sig) is previous[sig]


def test_plain_stop_handlers_raise_at_once():
    previous = install_stop_handlers()
    try:
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):
                pass
    finally:
        restore_handlers(previous)
