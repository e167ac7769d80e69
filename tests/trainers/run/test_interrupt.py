"""Ctrl-C or SIGTERM asks a run to stop; a second one stops it at once."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from neuronsmae.trainers.run.interrupt import StopSignals, TrainingInterrupted


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_the_first_signal_asks_the_second_stops_at_once(
    sig: signal.Signals, capsys: pytest.CaptureFixture[str]
) -> None:
    before = signal.getsignal(sig)
    with StopSignals() as stop:
        assert stop.requested == ""
        os.kill(os.getpid(), sig)
        assert stop.requested == sig.name
        assert "send it again to stop at once" in capsys.readouterr().err
        with pytest.raises(KeyboardInterrupt, match="again"):
            os.kill(os.getpid(), sig)
    assert signal.getsignal(sig) is before  # the caller's handler is back


def test_the_interruption_says_how_to_continue() -> None:
    err = TrainingInterrupted(Path("runs/vdn_easy_s1"), 1208, "SIGINT")
    assert "1208 episodes" in str(err) and "--resume" in str(err)
    assert "runs/vdn_easy_s1" in str(err)
