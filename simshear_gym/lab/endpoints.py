"""Where an MG400 controller listens: ``HOST`` or ``HOST:DASHBOARD,MOTION,FEEDBACK`` on the command line."""

from __future__ import annotations

from dataclasses import dataclass

from simshear_gym.robots.mg400.protocol import DASHBOARD_PORT, FEEDBACK_PORT, MOTION_PORT


@dataclass(frozen=True)
class ArmEndpoint:
    """An MG400's address and its three ports (dashboard, motion, feedback)."""

    host: str
    dashboard_port: int = DASHBOARD_PORT
    motion_port: int = MOTION_PORT
    feedback_port: int = FEEDBACK_PORT

    def __post_init__(self) -> None:
        if not self.host or any(c in self.host for c in " ,"):
            raise ValueError(f"ArmEndpoint.host must be a host name or IP address, got {self.host!r}")
        for name in ("dashboard_port", "motion_port", "feedback_port"):
            port = getattr(self, name)
            if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
                raise ValueError(f"ArmEndpoint.{name} must be an int in 1..65535, got {port!r}")

    @classmethod
    def parse(cls, text: str, flag: str = "--leader") -> ArmEndpoint:
        """``HOST`` (the MG400's ports 29999, 30003, 30004) or ``HOST:DASHBOARD,MOTION,FEEDBACK``."""
        host, sep, ports = str(text).partition(":")
        if not sep:
            return cls(host)
        parts = ports.split(",")
        try:
            numbers = [int(p) for p in parts]
        except ValueError:
            numbers = []
        if len(numbers) != 3:
            raise ValueError(f"{flag} {text!r}: expected HOST or HOST:DASHBOARD,MOTION,FEEDBACK (three ports, e.g. "
                             f"192.168.1.6:{DASHBOARD_PORT},{MOTION_PORT},{FEEDBACK_PORT})")
        return cls(host, *numbers)

    def __str__(self) -> str:
        return f"{self.host}:{self.dashboard_port},{self.motion_port},{self.feedback_port}"
