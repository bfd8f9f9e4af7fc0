"""A clock for tests of time budgets and caps: it moves only when a test says so, so that a budget stops a run at
the same step on a fast, slow or busy machine."""


class StepClock:
    """Seconds that advance by :meth:`advance` alone (a trainer's ``clock``; advance it in the step it times).

    Step times that are powers of two (``1 / 16`` s) keep sums exact, so a cap falls on a known step."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s

    def advance(self, seconds: float) -> None:
        self.now_s += seconds


class TickClock:
    """Seconds that advance by ``tick_s`` at each reading: a budget read once per step ends at a known step."""

    def __init__(self, tick_s: float) -> None:
        self.tick_s = tick_s
        self.now_s = 0.0

    def __call__(self) -> float:
        now_s = self.now_s
        self.now_s += self.tick_s
        return now_s


def wait_for(predicate, timeout_s: float = 10.0) -> bool:
    """Poll ``predicate`` until it holds or ``timeout_s`` passes; returns whether it held. A generous timeout: a test
    asserts what happens, not how fast (a loaded machine takes longer; only a failing test waits it out)."""
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return predicate()
