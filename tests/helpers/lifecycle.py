"""Helper processes run until SIGTERM, then report what they saw."""
from __future__ import annotations

import signal

import rclpy


class UntilTerm:
    """True until SIGTERM arrives; rclpy is started without its own signal handlers so it stays usable."""

    def __init__(self) -> None:
        self.running = True
        signal.signal(signal.SIGTERM, self._stop)
        rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)

    def _stop(self, *_: object) -> None:
        self.running = False

    def __bool__(self) -> bool:
        return self.running
